#!/usr/bin/env python3
"""The Python module's two targets, measured in one run:

1. A scene's second frame against the command line's `--repeat` frame (the same flags and file):
   the best of --frames frames after the first, against the best of `render --repeat N`.
2. The memory a scene adds over a large int16 array (default 1 GiB, 1024x1024x512): the peak RSS
   (ru_maxrss) after Scene(array), its first frame at 256², and a surface, minus the peak before.

  PYTHONPATH=build/python /usr/bin/python3 bench/python_scene.py build/hybrid-octree [VOLUME] [--gib 1]
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
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


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


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("binary")
    ap.add_argument("volume", nargs="?", default=CT)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--gib", type=float, default=1.0)
    a = ap.parse_args()
    frames(a.binary, a.volume, a.frames)
    memory(a.gib)


if __name__ == "__main__":
    sys.exit(main())
