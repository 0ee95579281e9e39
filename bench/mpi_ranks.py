#!/usr/bin/env python3
"""Sort-last frames across MPI ranks: per-rank render, wait and compositing times, the balance and
each rank's peak RSS for 1, 2 and 4 ranks, against the single process, in one run.

  bench/mpi_ranks.py BUILD/hybrid-octree SCENE [--ranks 1,2,4] [--size 512x512] [--iso V] [--repeat 3]
                     [--renderer slices|raycast] [--extra "FLAGS"]

Prints one row per rank count (the frame on rank 0: render, wait, composite, the whole frame) and
one per rank; the ratios are to the single process's frame measured in the same run. The frames
are checked against the single process's image (PSNR). Needs an MPI build (-DHYB_MPI=ON).
"""
import argparse
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile


def run(cmd, env=None):
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if p.returncode != 0:
        sys.exit(f"failed ({p.returncode}): {' '.join(cmd)}\n{p.stdout}\n{p.stderr}")
    return p.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("binary")
    ap.add_argument("scene")
    ap.add_argument("--ranks", default="1,2,4")
    ap.add_argument("--size", default="512x512")
    ap.add_argument("--iso", type=float)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--renderer", default="slices")
    ap.add_argument("--extra", default="", help="more render flags")
    a = ap.parse_args()
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMPI_MCA_rmaps_base_oversubscribe="1",
               OMPI_MCA_btl="self,vader",
               OMPI_MCA_hwloc_base_binding_policy="none", OMPI_MCA_btl_vader_single_copy_mechanism="none")  # each rank may use every core (llvmpipe and OpenMP threads)
    flags = ["--size", a.size, "--repeat", str(a.repeat), "--renderer", a.renderer, "--progress", "off"] + shlex.split(a.extra)
    if a.iso is not None:
        flags += ["--iso", str(a.iso), "--surface-color", "0.95,0.92,0.85,0.5"]
    tmp = tempfile.mkdtemp()
    one = os.path.join(tmp, "one.png")
    out = run([a.binary, "render", a.scene, "-o", one, "--stats", os.path.join(tmp, "one.json")] + flags, env)
    base = json.load(open(os.path.join(tmp, "one.json")))["render_ms"]
    print(f"# {os.path.basename(a.scene)}, {a.size}, {a.renderer}{', iso %g translucent' % a.iso if a.iso is not None else ', volume only'}, "
          f"best of {a.repeat}; one process (no MPI): {base:.1f} ms")
    print("| ranks | frame ms | vs one process | select ms (rank 0) | render ms (min-max) | slowest / mean | wait ms (rank 0) | "
          "composite ms (max) | peak RSS MB (max) | PSNR to one process |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for n in [int(x) for x in a.ranks.split(",")]:
        png, js = os.path.join(tmp, f"r{n}.png"), os.path.join(tmp, f"r{n}.json")
        run(["mpirun", "-np", str(n), a.binary, "render", a.scene, "-o", png, "--stats", js] + flags, env)
        s = json.load(open(js))
        ranks = s["ranks"]
        cmp = run([a.binary, "compare", one, png])
        m = re.search(r"PSNR ([0-9.]+) dB", cmp)
        psnr = "identical" if "identical" in cmp else f"{m.group(1)} dB"
        r = [x["render_ms"] for x in ranks]
        print(f"| {n} | {s['render_ms']:.1f} | {base / s['render_ms']:.2f}x | {s['select_ms']:.1f} | {min(r):.1f}-{max(r):.1f} | {max(r) / (sum(r) / n):.2f} | "
              f"{ranks[0]['wait_ms']:.1f} | {max(x['composite_ms'] for x in ranks):.1f} | {max(x['peak_rss_mb'] for x in ranks):.0f} | {psnr} |")
        rows.append((n, ranks))
    for n, ranks in rows:
        for x in ranks:
            print(f"  {n} ranks, rank {x['rank']}: {x['bricks']:.0f} bricks, {x['texels']:.0f} texels, {x['blocks_read']:.0f} blocks read, "
                  f"render {x['render_ms']:.1f} ms, wait {x['wait_ms']:.1f} ms, composite {x['composite_ms']:.1f} ms, peak RSS {x['peak_rss_mb']:.0f} MB")


if __name__ == "__main__":
    main()
