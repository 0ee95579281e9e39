#!/usr/bin/python3
"""Optional comparison of the renderer issue's speed targets with VTK, in one run on this machine:
VTK's GPU ray cast mapper with depth peeling (volume + translucent isosurface) and its CPU
fixed-point ray caster (volume only, automatic sample distances), both through Mesa's llvmpipe
under Xvfb, against `hybrid-octree render` on the same volume, view, transfer function and size.
Every image is also compared with the reference ray tracer (`hybrid-octree compare`), and the
fixed-point caster is met once more at its own accuracy: at the widest slice spacing whose image
is at least as close to the reference as VTK's.

Needs Debian's python3-vtk9 and xvfb (not dependencies of the project). From the repository root:

    xvfb-run -a /usr/bin/python3 bench/vtk_render.py cranium_256x256x108_int16le.nhdr [--runs 3] [--rounds 3] [--images DIR]
"""
import argparse
import math
import os
import re
import subprocess
import sys
import tempfile
import time

# The ct-skin-bone preset of render/transfer_function.cpp: value, colour, opacity per mm.
SKIN, BONE = (0.93, 0.72, 0.60), (1.0, 0.96, 0.86)
CT_SKIN_BONE = [(-700, SKIN, 0.0), (-500, SKIN, 0.08), (-300, SKIN, 0.12), (-100, SKIN, 0.0), (150, BONE, 0.0),
                (400, BONE, 0.2), (3000, BONE, 0.6)]


def best_ms(runs, f):
    best = float("inf")
    for _ in range(runs):
        t0 = time.perf_counter()
        f()
        best = min(best, (time.perf_counter() - t0) * 1e3)
    return best


def ours_ms(exe, volume, runs, extra, view, image=None):
    """Best frame of `runs` renders of one view in one process: brick textures are uploaded by the
    first frame and kept, as VTK keeps its volume texture after its untimed first frame. The image
    is kept at `image` when given."""
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([exe, "render", volume, "--size", "512x512", "--repeat", str(runs + 1), "-o", image or os.path.join(tmp, "o.png")]
                             + view + extra, check=True, capture_output=True, text=True).stdout
    return float(re.search(r"^render .* ([0-9.]+) ms$", out, re.M).group(1))


def psnr_db(exe, reference, image):
    """PSNR of `image` against `reference` as `hybrid-octree compare` measures it (inf: identical)."""
    out = subprocess.run([exe, "compare", reference, image], check=True, capture_output=True, text=True).stdout
    found = re.search(r"PSNR ([0-9.]+) dB", out)
    return float(found.group(1)) if found else float("inf")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("volume")
    parser.add_argument("--runs", type=int, default=3, help="timed frames per measurement")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds of every measurement")
    parser.add_argument("--hybrid-octree", default="build/hybrid-octree")
    parser.add_argument("--images", help="keep every image here (default: a temporary folder)")
    args = parser.parse_args()
    try:
        import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL back end)
        import vtkmodules.vtkRenderingVolumeOpenGL2  # noqa: F401
        from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
        from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D
        from vtkmodules.vtkIOImage import vtkNrrdReader, vtkPNGWriter
        from vtkmodules.vtkRenderingCore import (vtkActor, vtkColorTransferFunction, vtkPolyDataMapper, vtkRenderer,
                                                 vtkRenderWindow, vtkVolume, vtkVolumeProperty, vtkWindowToImageFilter)
        from vtkmodules.vtkRenderingVolume import vtkFixedPointVolumeRayCastMapper, vtkGPUVolumeRayCastMapper
    except ImportError:
        sys.exit("vtk_render.py: VTK's Python modules are missing (apt-get install python3-vtk9)")
    reader = vtkNrrdReader()
    reader.SetFileName(args.volume)
    reader.Update()
    image = reader.GetOutput()
    dims, spacing = image.GetDimensions(), image.GetSpacing()
    extent = [(dims[a] - 1) * spacing[a] for a in range(3)]

    # One camera for both sides: in front of the grid's +y face, 10 degrees above, 30 degrees of
    # field, passed to hybrid-octree explicitly (the shared NRRDs carry no orientation, so their
    # patient frame is the grid's).
    centre = [0.5 * e for e in extent]
    radius = 0.5 * math.sqrt(sum(e * e for e in extent))
    az, el, fov = math.radians(180), math.radians(10), 30.0
    direction = (math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el))
    distance = radius / math.sin(math.atan(math.tan(math.radians(fov) / 2))) * 1.05
    eye = [centre[a] + direction[a] * distance for a in range(3)]
    view = ["--eye", ",".join(f"{x:.9g}" for x in eye), "--center", ",".join(f"{x:.9g}" for x in centre), "--up", "0,0,1"]

    colour, opacity = vtkColorTransferFunction(), vtkPiecewiseFunction()
    for value, rgb, alpha in CT_SKIN_BONE:
        colour.AddRGBPoint(value, *rgb)
        opacity.AddPoint(value, alpha)
    prop = vtkVolumeProperty()
    prop.SetColor(colour)
    prop.SetScalarOpacity(opacity)
    prop.SetScalarOpacityUnitDistance(1.0)  # opacity per millimetre, as ours
    prop.SetInterpolationTypeToLinear()
    prop.ShadeOn()
    prop.SetAmbient(0.25)
    prop.SetDiffuse(0.75)
    prop.SetSpecular(0.0)

    # One window for every scene (a renderer each in turn): creating and destroying windows
    # repeatedly loses the X connection under Xvfb.
    window = vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetSize(512, 512)
    window.SetAlphaBitPlanes(1)
    window.SetMultiSamples(0)

    work = tempfile.TemporaryDirectory()
    folder = args.images or work.name
    os.makedirs(folder, exist_ok=True)

    def keep_window(name):
        grab = vtkWindowToImageFilter()
        grab.SetInput(window)
        grab.ReadFrontBufferOff()
        grab.Update()
        writer = vtkPNGWriter()
        writer.SetFileName(os.path.join(folder, name + ".png"))
        writer.SetInputConnection(grab.GetOutputPort())
        writer.Write()

    def scene(mapper, surface, name):
        renderer = vtkRenderer()
        window.AddRenderer(renderer)
        volume = vtkVolume()
        volume.SetMapper(mapper)
        volume.SetProperty(prop)
        renderer.AddVolume(volume)
        if surface:
            fe = vtkFlyingEdges3D()
            fe.SetInputData(image)
            fe.SetValue(0, 400.0)
            fe.Update()
            polys = vtkPolyDataMapper()
            polys.SetInputConnection(fe.GetOutputPort())
            polys.ScalarVisibilityOff()
            actor = vtkActor()
            actor.SetMapper(polys)
            actor.GetProperty().SetColor(0.95, 0.92, 0.85)
            actor.GetProperty().SetOpacity(0.5)
            renderer.AddActor(actor)
            renderer.SetUseDepthPeeling(1)
            renderer.SetUseDepthPeelingForVolumes(1)
            renderer.SetMaximumNumberOfPeels(8)
            renderer.SetOcclusionRatio(0.0)
        camera = renderer.GetActiveCamera()
        camera.SetPosition(*eye)
        camera.SetFocalPoint(*centre)
        camera.SetViewUp(0, 0, 1)
        camera.SetViewAngle(fov)
        renderer.ResetCameraClippingRange()
        window.Render()  # first frame: uploads and shader builds, not timed

        def frame():
            camera.Azimuth(0.0)
            camera.Modified()
            window.Render()
        ms = best_ms(args.runs, frame)
        keep_window(name)
        window.RemoveRenderer(renderer)
        return ms

    def gpu_mapper():
        gpu = vtkGPUVolumeRayCastMapper()
        gpu.SetInputData(image)
        gpu.SetAutoAdjustSampleDistances(0)
        gpu.SetSampleDistance(0.5 * min(spacing))  # as our default slice spacing
        return gpu
    cpu = vtkFixedPointVolumeRayCastMapper()
    cpu.SetInputData(image)  # automatic sample distances (its default)
    surface = ["--iso", "400", "--surface-color", "0.95,0.92,0.85,0.5"]
    exe = args.hybrid_octree

    def ours(name, extra):
        return lambda: ours_ms(exe, args.volume, args.runs, extra, view, os.path.join(folder, name + ".png"))

    # At the accuracy floor the targets allow (PSNR >= 35 dB against the reference ray tracer;
    # docs/renderer.md measures the slice spacing that keeps it).
    measures = {
        "gpu_surface": lambda: scene(gpu_mapper(), True, "gpu_surface"),
        "gpu_volume": lambda: scene(gpu_mapper(), False, "gpu_volume"),
        "cpu_volume": lambda: scene(cpu, False, "cpu_volume"),
        "ours_surface": ours("ours_surface", surface),
        "ours_volume": ours("ours_volume", []),
        "ours_surface_floor": ours("ours_surface_floor", surface + ["--step", "3"]),
        "ours_volume_floor": ours("ours_volume_floor", ["--step", "1.6"]),
    }
    # Accuracy: every image against the reference ray tracer of each scene. The fixed-point caster
    # is then also met at its own accuracy: the widest slice spacing whose image is at least as
    # close to the reference as VTK's.
    for name, extra in (("reference_surface", surface), ("reference_volume", [])):
        subprocess.run([exe, "render", args.volume, "--size", "512x512", "--renderer", "raycast", "-o", os.path.join(folder, name + ".png")]
                       + view + extra, check=True, capture_output=True)
    measures["cpu_volume"]()
    cpu_psnr = psnr_db(exe, os.path.join(folder, "reference_volume.png"), os.path.join(folder, "cpu_volume.png"))
    matched = "1.6"
    for step in ("2", "3", "4"):
        ours_ms(exe, args.volume, 0, ["--step", step], view, os.path.join(folder, "ours_volume_step.png"))
        if psnr_db(exe, os.path.join(folder, "reference_volume.png"), os.path.join(folder, "ours_volume_step.png")) >= cpu_psnr:
            matched = step
    measures["ours_volume_matched"] = ours("ours_volume_matched", ["--step", matched])
    # Interleaved rounds, the best of each kept: the load of a shared machine drifts over a run, and
    # measuring one side after the other would put the drift into the ratios.
    best = {name: float("inf") for name in measures}
    for _ in range(args.rounds):
        for name, measure in measures.items():
            best[name] = min(best[name], measure())
    gpu_surface, gpu_volume, cpu_volume = best["gpu_surface"], best["gpu_volume"], best["cpu_volume"]
    ours_surface, ours_volume = best["ours_surface"], best["ours_volume"]
    ours_surface_floor, ours_volume_floor = best["ours_surface_floor"], best["ours_volume_floor"]
    ours_volume_matched = best["ours_volume_matched"]

    def acc(name):
        reference = os.path.join(folder, "reference_" + ("surface" if "surface" in name else "volume") + ".png")
        return f"{psnr_db(exe, reference, os.path.join(folder, name + '.png')):6.2f} dB"
    print(f"volume {args.volume}, 512x512, ct-skin-bone, perspective; best of {args.runs} frames x {args.rounds} rounds, ms;"
          " PSNR against the reference ray tracer")
    print(f"  VTK GPU ray cast + translucent surface, depth peeling   {gpu_surface:8.1f}  {acc('gpu_surface')}")
    print(f"  VTK GPU ray cast, volume only                           {gpu_volume:8.1f}  {acc('gpu_volume')}")
    print(f"  VTK CPU fixed-point ray cast, volume only               {cpu_volume:8.1f}  {acc('cpu_volume')}")
    print(f"  hybrid-octree slices + translucent surface              {ours_surface:8.1f}  {acc('ours_surface')}   "
          f"VTK/ours {gpu_surface / ours_surface:5.2f} (target >= 10)")
    print(f"  hybrid-octree slices, volume only                       {ours_volume:8.1f}  {acc('ours_volume')}   "
          f"VTK CPU/ours {cpu_volume / ours_volume:5.2f} (target >= 1)")
    print(f"  hybrid-octree, + surface, --step 3                      {ours_surface_floor:8.1f}  {acc('ours_surface_floor')}   "
          f"VTK/ours {gpu_surface / ours_surface_floor:5.2f} (target >= 10)")
    print(f"  hybrid-octree, volume only, --step 1.6                  {ours_volume_floor:8.1f}  {acc('ours_volume_floor')}   "
          f"VTK CPU/ours {cpu_volume / ours_volume_floor:5.2f} (target >= 1)")
    print(f"  hybrid-octree, volume only, --step {matched:<4} (as accurate) {ours_volume_matched:8.1f}  {acc('ours_volume_matched')}   "
          f"VTK CPU/ours {cpu_volume / ours_volume_matched:5.2f} (target >= 1)")


if __name__ == "__main__":
    main()
