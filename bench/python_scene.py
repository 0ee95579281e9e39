#!/usr/bin/env python3
"""The Python module's targets, measured in one run:

1. A scene's second frame against the command line's `--repeat` frame (the same flags and file):
   the best of --frames frames after the first, against the best of `render --repeat N`.
2. The memory a scene adds over a large int16 array (default 1 GiB, 1024x1024x512): the peak RSS
   (VmHWM) after Scene(array), its first frame at 256², and a surface, minus the peak before.
3. A CT of whole numbers as float64 (what nibabel's get_fdata() gives; default 1 GiB, 512³) against
   the same values as int16 and as float32: Scene(array)'s time and CPU time (user + system; each
   the best of --repeat processes, the types interleaved) and the process's peak RSS, each in its
   own process, as ratios to int16. On a shared machine the CPU time of one thread
   (OMP_NUM_THREADS=1) is the steady figure: other processes stretch the wall time, and OpenMP's
   waiting threads spin.

  PYTHONPATH=build/python /usr/bin/python3 bench/python_scene.py build/hybrid-octree [VOLUME] [--gib 1] [--convert-gib 1]
      [--repeat 3] [--parts frames,memory,conversion]
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

import hybrid_octree as ho

CT = "/usr/share/doc/invesalius-examples/examples/Cranium.inv3"


def peak_mb():
    """The process's peak RSS (VmHWM; unlike ru_maxrss, not inherited from the parent across exec)."""
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 1024.0


def frames(binary, volume, n):
    flags = dict(view="anterior", preset="ct-skin-bone", iso=400, surface_color=(0.95, 0.92, 0.85, 0.5))
    tmp = tempfile.mkdtemp()
    stats = os.path.join(tmp, "s.json")
    subprocess.run([binary, "render", volume, "--view", "anterior", "--preset", "ct-skin-bone", "--iso", "400", "--surface-color",
                    "0.95,0.92,0.85,0.5", "--repeat", str(n), "-o", os.path.join(tmp, "c.png"), "--stats", stats, "--progress", "off"],
                   check=True, capture_output=True)
    cli_ms = json.load(open(stats))["render_ms"]
    scene = ho.open(volume)
    first = scene.render(stats=True, **flags)[1]["render_ms"]
    later = min(scene.render(stats=True, **flags)[1]["render_ms"] for _ in range(n - 1))
    print(f"frames: {os.path.basename(volume)} 512², translucent bone: the scene's first frame {first:.1f} ms, "
          f"its best later frame {later:.1f} ms; the command line's best of --repeat {n}: {cli_ms:.1f} ms; ratio {later / cli_ms:.3f}")


def memory(gib):
    nz = int(512 * gib)
    before_array = peak_mb()
    a = np.empty((nz, 1024, 1024), np.int16)
    x = np.arange(1024, dtype=np.float32)
    for z in range(nz):  # a sphere of 1000 in noise-free 0, slice by slice: no temporaries of the whole array
        r2 = (x[None, :] - 512) ** 2 + (x[:, None] - 512) ** 2 + (z - nz / 2) ** 2
        a[z] = np.where(r2 < (0.4 * nz) ** 2, 1000, 0)
    before = peak_mb()
    t0 = time.monotonic()
    scene = ho.Scene(a, iso=500)
    built = time.monotonic() - t0
    after_scene = peak_mb()
    scene.render(size=(256, 256), iso=500)
    after_frame = peak_mb()
    print(f"memory: a {a.nbytes / 2**30:.2f} GiB int16 array (peak RSS {before:.0f} MB with it, {before_array:.0f} MB before it): "
          f"Scene(array, iso=500) in {built:.1f} s adds {after_scene - before:.0f} MB; with a 256² frame {after_frame - before:.0f} MB "
          f"({(after_frame - before) / (a.nbytes / 2**20):.3f} of the array's bytes; target <= 512 MB)")


def ct_slice(z, n):
    """Slice z of an n-cubed CT of whole Hounsfield units: air -1024, a head of 40 with a bone shell
    of 1000 and a texture of +-20 (integers, so that the octree's errors are not all zero)."""
    x = np.arange(n, dtype=np.float32) - n / 2
    r = np.sqrt(x[None, :] ** 2 + x[:, None] ** 2 + (z - n / 2) ** 2) / (0.45 * n)
    texture = np.round(20 * np.sin(x[None, :] / 3.0) * np.cos(x[:, None] / 5.0 + z / 7.0))
    return np.where(r < 0.9, 40 + texture, np.where(r < 1.0, 1000 + texture, -1024)).astype(np.int16)


def convert_child(dtype, gib):
    """One process: the CT in @p dtype, then Scene(array); prints JSON."""
    n = int(round((gib * 2**30 / 8) ** (1 / 3)))
    a = np.empty((n, n, n), dtype)
    for z in range(n):
        a[z] = ct_slice(z, n)
    before = peak_mb()
    cpu = lambda: sum(resource.getrusage(resource.RUSAGE_SELF)[:2])
    t0, c0 = time.monotonic(), cpu()
    scene = ho.Scene(a)
    seconds, cpu_seconds = time.monotonic() - t0, cpu() - c0
    print(json.dumps(dict(n=n, seconds=seconds, cpu=cpu_seconds, before=before, peak=peak_mb(), stored=scene.info()["stored_type"], array_mb=a.nbytes / 2**20)))


def conversion(gib, repeat):
    runs = {}
    for _ in range(repeat):
        for dtype in ("int16", "float64", "float32"):
            out = subprocess.run([sys.executable, __file__, "--child", dtype, str(gib)], check=True, capture_output=True, text=True).stdout
            r = json.loads(out)
            best = runs.setdefault(dtype, r)
            best["seconds"], best["cpu"] = min(best["seconds"], r["seconds"]), min(best["cpu"], r["cpu"])
    base = runs["int16"]
    for dtype, r in runs.items():
        print(f"conversion: {r['n']}³ CT as {dtype} ({r['array_mb']:.0f} MB, held as {r['stored']}): Scene() best of {repeat} {r['seconds']:.2f} s "
              f"({r['seconds'] / base['seconds']:.2f}× int16's), CPU {r['cpu']:.2f} s ({r['cpu'] / base['cpu']:.2f}×); "
              f"peak RSS {r['peak']:.0f} MB ({r['peak'] / base['peak']:.2f}×), of which Scene() adds {r['peak'] - r['before']:.0f} MB")


def main():
    if sys.argv[1:2] == ["--child"]:  # one measurement of conversion(), in a process of its own
        return convert_child(sys.argv[2], float(sys.argv[3]))
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("binary")
    ap.add_argument("volume", nargs="?", default=CT)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--gib", type=float, default=1.0)
    ap.add_argument("--convert-gib", type=float, default=1.0, help="the float64 array's GiB in the conversion measurement")
    ap.add_argument("--repeat", type=int, default=3, help="processes per type in the conversion measurement")
    ap.add_argument("--parts", default="frames,memory,conversion", help="the measurements to make, comma-separated")
    a = ap.parse_args()
    parts = a.parts.split(",")
    if "frames" in parts:
        frames(a.binary, a.volume, a.frames)
    if "memory" in parts:
        memory(a.gib)
    if "conversion" in parts:
        conversion(a.convert_gib, a.repeat)


if __name__ == "__main__":
    sys.exit(main())
