#!/usr/bin/python3
"""Optional comparison of the surface issue's speed target: VTK's vtkFlyingEdges3D (single thread)
against hybrid-octree's DiscMC cells + Surface Octree build, same volume and isovalues, one run.

Needs Debian's python3-vtk9 (not a dependency of the project: `apt-get install python3-vtk9`) and a
volume VTK can read: NRRD (.nrrd/.nhdr) or MetaImage (.mhd). Run from the repository root:

    /usr/bin/python3 bench/vtk_flying_edges.py VOLUME.nhdr [--iso 400 --iso -500] [--runs 5]
"""
import argparse
import os
import re
import subprocess
import sys
import time


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("volume")
    parser.add_argument("--iso", type=float, action="append")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--hyb-bench", default="build/hyb_bench")
    args = parser.parse_args()
    isovalues = args.iso or [400.0, -500.0]
    try:
        from vtkmodules.vtkCommonCore import vtkSMPTools
        from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D
        from vtkmodules.vtkIOImage import vtkMetaImageReader, vtkNrrdReader
    except ImportError:
        sys.exit("vtk_flying_edges.py: VTK's Python modules are missing (apt-get install python3-vtk9)")
    if not os.path.exists(args.volume):
        sys.exit(f"vtk_flying_edges.py: {args.volume}: no such file")
    vtkSMPTools.SetBackend("Sequential")  # single thread, as the target says
    reader = vtkMetaImageReader() if args.volume.lower().endswith((".mhd", ".mha")) else vtkNrrdReader()
    reader.SetFileName(args.volume)
    reader.Update()
    image = reader.GetOutput()
    print(f"volume {args.volume}: {image.GetDimensions()}, VTK {__import__('vtkmodules').__version__}")
    print(f"{'iso':>8} {'VTK flying edges ms':>20} {'triangles':>10} {'hybrid-octree SO build ms':>26} {'ratio':>6}")
    for iso in isovalues:
        best = float("inf")
        triangles = 0
        for _ in range(args.runs):
            fe = vtkFlyingEdges3D()
            fe.SetInputData(image)
            fe.SetValue(0, iso)
            fe.ComputeNormalsOff()
            fe.ComputeGradientsOff()
            fe.ComputeScalarsOff()
            t0 = time.perf_counter()
            fe.Update()
            best = min(best, (time.perf_counter() - t0) * 1e3)
            triangles = fe.GetOutput().GetNumberOfPolys()
        # Ours, best of the same number of runs in one process (hyb_bench), as VTK's are.
        out = subprocess.run([args.hyb_bench, args.volume, "--iso", str(iso), "--runs", str(args.runs), "--surface-only"],
                             check=True, capture_output=True, text=True).stdout
        match = re.search(r"^\s*Surface Octree build\s+\d+\s+([0-9.]+)", out, re.M)
        ours = float(match.group(1)) if match else float("nan")
        print(f"{iso:8.1f} {best:20.1f} {triangles:10d} {ours:26.1f} {ours / best:6.2f}")


if __name__ == "__main__":
    main()
