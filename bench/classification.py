#!/usr/bin/python3
"""Post-classification against pre-integration, in one run: the slice renderer's frame time and
PSNR to the reference ray tracer (post-classified, 0.25 voxel) over a sweep of slice spacings, for
both `--classification` modes, volume only and with the translucent bone surface. Prints one row
per frame (mode, step, ms, dB) and, for each mode, the widest step that reaches the target PSNR and
its frame's time, with the ratios of pre-integration's to post-classification's.

From the repository root (the scene may be any volume `render` reads):

    /usr/bin/python3 bench/classification.py /usr/share/doc/invesalius-examples/examples/Cranium.inv3 [--size 512] [--target 35]
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from vtk_render import psnr_db  # noqa: E402  (VTK is imported by its main only)


def render(exe, volume, size, runs, extra, image):
    """Best of `runs` frames after an untimed first one (textures and the table kept)."""
    out = subprocess.run([exe, "render", volume, "--size", f"{size}x{size}", "--repeat", str(runs + 1), "-o", image] + extra,
                         check=True, capture_output=True, text=True).stdout
    return float(re.search(r"^render .* ([0-9.]+) ms$", out, re.M).group(1))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("volume")
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--runs", type=int, default=2, help="timed frames per measurement")
    parser.add_argument("--target", type=float, default=35.0, help="PSNR the widest step must reach, dB")
    parser.add_argument("--steps", default="0.5,0.75,1,1.25,1.5,2,2.5,3", help="slice spacings, voxels")
    parser.add_argument("--iso", type=float, default=400.0, help="the translucent surface's value")
    parser.add_argument("--hybrid-octree", default="build/hybrid-octree")
    args = parser.parse_args()
    exe = args.hybrid_octree
    steps = [float(s) for s in args.steps.split(",")]
    looks = {"volume": [], "surface": ["--iso", str(args.iso), "--surface-color", "0.95,0.92,0.85,0.5"]}
    with tempfile.TemporaryDirectory() as tmp:
        for look, extra in looks.items():
            reference = os.path.join(tmp, f"{look}_reference.png")
            subprocess.run([exe, "render", args.volume, "--size", f"{args.size}x{args.size}", "--renderer", "raycast", "-o", reference] + extra,
                           check=True, capture_output=True)
            print(f"{look}: {args.size}², against the reference (post-classified, 0.25 voxel)")
            print(f"  {'classification':<15} {'step':>5} {'ms':>8} {'dB':>6}")
            widest = {}
            # Interleaved: each step's two modes run back to back, so the machine's load meets both.
            for step in steps:
                for mode in ("post", "preintegrated"):
                    image = os.path.join(tmp, f"{look}_{mode}_{step}.png")
                    ms = render(exe, args.volume, args.size, args.runs, extra + ["--step", str(step), "--classification", mode], image)
                    db = psnr_db(exe, reference, image)
                    print(f"  {mode:<15} {step:5.2f} {ms:8.1f} {db:6.2f}", flush=True)
                    if db >= args.target and (mode not in widest or step > widest[mode][0]):
                        widest[mode] = (step, ms, db)
            for mode in ("post", "preintegrated"):
                if mode in widest:
                    step, ms, db = widest[mode]
                    print(f"  widest step at {args.target:g} dB, {mode}: {step:g} ({ms:.1f} ms, {db:.2f} dB)")
                else:
                    print(f"  widest step at {args.target:g} dB, {mode}: none of the steps")
            if len(widest) == 2:
                (sp, mp, _), (si, mi, _) = widest["post"], widest["preintegrated"]
                print(f"  pre-integration / post: step {si / sp:.2f}x, frame time {mi / mp:.2f}x")


if __name__ == "__main__":
    main()
