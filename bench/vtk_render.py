#!/usr/bin/python3
"""Speed against accuracy, side by side in one run on this machine: frame time and PSNR to the
reference ray tracer as curves, for each of our renderers (slices post-classified and
pre-integrated over slice spacings, the reference ray tracer over sample spacings) and each peer:
VTK's GPU ray cast mapper (volume only; with the translucent isosurface, with and without depth
peeling) and its CPU fixed-point ray caster (volume only; its automatic sample distances, then
fixed ones; and at equal quality, its frames against its own finest sample distance as ours
are against our reference), through Mesa's llvmpipe under Xvfb, on the same volume, view, transfer function and
size; with --volpack, orthographic frames of ours against Lacroute and Levoy's shear-warp
(VolPack, `hyb_volpack`, built when Debian's libvolpack1-dev is installed; VolPack has no
perspective). Prints one row per frame (name, ms, dB, ratio of the peer's frame to this one), the
targets' rows, and writes the curves as a CSV table and a plot.

Needs Debian's python3-vtk9, python3-matplotlib and xvfb (not dependencies of the project). From
the repository root:

    xvfb-run -a /usr/bin/python3 bench/vtk_render.py cranium_256x256x108_int16le.nhdr [--runs 3] [--volume-only] [--images DIR] [--csv docs/trade-vtk.csv] [--plot docs/trade-vtk.png]
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
    parser.add_argument("--rounds", type=int, default=1, help="interleaved rounds of every measurement")
    parser.add_argument("--hybrid-octree", default="build/hybrid-octree")
    parser.add_argument("--images", help="keep every image here (default: a temporary folder)")
    parser.add_argument("--steps", default="0.5,1,1.6,2,3,4", help="our slice spacings, voxels")
    parser.add_argument("--image-scales", default="0.5,0.75", help="our slices at these fractions of the image's size, magnified")
    parser.add_argument("--scaled-steps", default="1.2,1.6,2,3", help="their slice spacings, voxels")
    parser.add_argument("--ray-steps", default="0.5,1,2", help="the reference ray tracer's sample spacings, voxels")
    parser.add_argument("--vtk-distances", default="0.5,1,2,4", help="VTK's sample distances, in smallest voxel spacings")
    parser.add_argument("--own-distances", default="0.25,0.5,1,2,3,4",
                        help="the fixed-point caster's sample distances against its own finest, in smallest voxel spacings")
    parser.add_argument("--own-image-distances", default="1,1.5,2", help="and its image sample distances (1/S, as our --image-scale S)")
    parser.add_argument("--volume-only", action="store_true", help="only the volume-only curves (no surface, no GPU caster)")
    parser.add_argument("--volpack", help="hyb_volpack: add the orthographic comparison with VolPack")
    parser.add_argument("--csv", help="write the curves here")
    parser.add_argument("--plot", help="plot the curves here (PNG)")
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

    def scene(mapper, surface, name, peeling=True):
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
            renderer.SetUseDepthPeeling(1 if peeling else 0)
            renderer.SetUseDepthPeelingForVolumes(1 if peeling else 0)
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
    surface = ["--iso", "400", "--surface-color", "0.95,0.92,0.85,0.5"]
    exe = args.hybrid_octree

    # The curves: name, peer it is measured against, and its points (label, measure, look).
    def ours(name, extra):
        return lambda: ours_ms(exe, args.volume, args.runs, extra, view, os.path.join(folder, name + ".png"))

    def cpu_mapper(distance, image_distance=1.0):
        cpu = vtkFixedPointVolumeRayCastMapper()
        cpu.SetInputData(image)
        if distance:
            cpu.SetAutoAdjustSampleDistances(0)
            cpu.SetSampleDistance(distance)
            cpu.SetImageSampleDistance(image_distance)
        return cpu

    def gpu(distance):
        mapper = gpu_mapper()
        mapper.SetSampleDistance(distance)
        return mapper

    curves = []  # (curve, look, [(label, name, measure)])
    for look, extra in (("volume", []),) + ((("surface", surface),) if not args.volume_only else ()):
        for mode in ("post", "preintegrated"):
            curves.append((f"hybrid-octree slices, {mode}", look, [
                (f"--step {st}", f"ours_{look}_{mode}_{st}", ours(f"ours_{look}_{mode}_{st}", extra + ["--step", st, "--classification", mode]))
                for st in args.steps.split(",")]))
        # A frame at a fraction of its size, magnified (--image-scale), in 32-texel bricks (fewer draws).
        for scale in args.image_scales.split(","):
            curves.append((f"hybrid-octree slices, post, --image-scale {scale} --max-brick 32", look, [
                (f"--step {st}", f"ours_{look}_scale{scale}_{st}",
                 ours(f"ours_{look}_scale{scale}_{st}", extra + ["--step", st, "--image-scale", scale, "--max-brick", "32"]))
                for st in args.scaled_steps.split(",")]))
        curves.append(("hybrid-octree reference ray tracer", look, [
            (f"--step {st}", f"rays_{look}_{st}", ours(f"rays_{look}_{st}", extra + ["--renderer", "raycast", "--step", st]))
            for st in args.ray_steps.split(",")]))
    mm = min(spacing)
    distances = [float(f) * mm for f in args.vtk_distances.split(",")]
    if not args.volume_only:
        curves.append(("VTK GPU ray cast", "volume", [
            (f"sample {d:.2f} mm", f"gpu_volume_{d:.2f}", (lambda d=d: scene(gpu(d), False, f"gpu_volume_{d:.2f}"))) for d in distances]))
    curves.append(("VTK CPU fixed-point ray cast", "volume",
                   [("automatic", "cpu_volume_auto", lambda: scene(cpu_mapper(0), False, "cpu_volume_auto"))] +
                   [(f"sample {d:.2f} mm", f"cpu_volume_{d:.2f}", (lambda d=d: scene(cpu_mapper(d), False, f"cpu_volume_{d:.2f}"))) for d in distances]))
    # Equal quality, each renderer against its own converged image: the fixed-point caster's frames
    # against its frame at the finest sample distance (its reference, whose time is not used), as
    # ours are against our reference ray tracer; its sample distance and image sample distance both
    # free, as our step and image scale are.
    own = [float(f) * mm for f in args.own_distances.split(",")]
    curves.append(("VTK CPU fixed-point, against its own finest", "vtk-own", [
        (f"sample {d:.2f} mm, image 1/{i:g}", f"cpu_own_{d:.2f}_{i:g}", (lambda d=d, i=i: scene(cpu_mapper(d, i), False, f"cpu_own_{d:.2f}_{i:g}")))
        for d in own[1:] for i in (float(x) for x in args.own_image_distances.split(","))]))
    for peeling in (True, False) if not args.volume_only else ():
        tag = "peeled" if peeling else "unpeeled"
        curves.append((f"VTK GPU ray cast + surface, {'depth peeling' if peeling else 'no depth peeling'}", "surface", [
            (f"sample {d:.2f} mm", f"gpu_surface_{tag}_{d:.2f}", (lambda d=d, p=peeling, t=tag: scene(gpu(d), True, f"gpu_surface_{t}_{d:.2f}", p)))
            for d in distances]))

    if args.volpack:
        # Orthographic, as VolPack draws: our CLI's ortho height for an explicit eye (the grid's
        # diagonal, 5 % wider), given to VolPack too. Its classification is made once per transfer
        # function; a frame's time is its shading table and its render.
        ortho = ["--ortho"]
        height = 1.05 * math.sqrt(sum(e * e for e in extent))

        def volpack():
            out = subprocess.run([args.volpack, args.volume, os.path.join(folder, "volpack_ortho.png"), "--eye", view[1], "--center", view[3],
                                  "--up", view[5], "--ortho-height", f"{height:.9g}", "--repeat", str(args.runs)],
                                 check=True, capture_output=True, text=True).stdout
            t = re.search(r"classify ([0-9.]+) shade_table ([0-9.]+) render ([0-9.]+)", out)
            volpack_classify.append(float(t.group(1)))
            return float(t.group(2)) + float(t.group(3))
        volpack_classify = []
        for mode in ("post", "preintegrated"):
            curves.append((f"hybrid-octree slices, {mode}", "ortho", [
                (f"--step {st}", f"ours_ortho_{mode}_{st}", ours(f"ours_ortho_{mode}_{st}", ortho + ["--step", st, "--classification", mode]))
                for st in args.steps.split(",")]))
        curves.append(("hybrid-octree reference ray tracer", "ortho", [
            (f"--step {st}", f"rays_ortho_{st}", ours(f"rays_ortho_{st}", ortho + ["--renderer", "raycast", "--step", st]))
            for st in args.ray_steps.split(",")]))
        curves.append(("VolPack shear-warp", "ortho", [("one sample a slice", "volpack_ortho", volpack)]))
        subprocess.run([exe, "render", args.volume, "--size", "512x512", "--renderer", "raycast", "-o", os.path.join(folder, "reference_ortho.png")]
                       + view + ortho, check=True, capture_output=True)
    for name, extra in (("reference_surface", surface), ("reference_volume", [])):
        subprocess.run([exe, "render", args.volume, "--size", "512x512", "--renderer", "raycast", "-o", os.path.join(folder, name + ".png")]
                       + view + extra, check=True, capture_output=True)
    scene(cpu_mapper(own[0]), False, "reference_vtk-own")
    # Interleaved rounds, the best of each kept: the load of a shared machine drifts over a run, and
    # measuring one curve after the other would put the drift into the ratios.
    best = {}
    for _ in range(args.rounds):
        for _, _, points in curves:
            for _, name, measure in points:
                best[name] = min(best.get(name, float("inf")), measure())
    db = {}
    for _, look, points in curves:
        for _, name, _ in points:
            db[name] = psnr_db(exe, os.path.join(folder, f"reference_{look}.png"), os.path.join(folder, name + ".png"))

    # The peers' frames the targets name: the fixed-point caster's own (automatic) frame, and the
    # GPU caster with depth peeling at the sample distance closest to our default slice spacing.
    peers = {"volume": ("VTK CPU fixed-point, automatic", best["cpu_volume_auto"]),
             "vtk-own": ("VTK CPU fixed-point, automatic", best["cpu_volume_auto"])}
    if not args.volume_only:
        peers["surface"] = ("VTK GPU + depth peeling, 0.5 voxel", best[f"gpu_surface_peeled_{distances[0]:.2f}"])
    if args.volpack:
        peers["ortho"] = ("VolPack shear-warp", best["volpack_ortho"])
    print(f"volume {args.volume}, 512x512, ct-skin-bone, perspective; best of {args.runs} frames x {args.rounds} rounds, ms;"
          " PSNR against the reference ray tracer; ratio: the peer's frame / this one")
    rows = []
    for curve, look, points in curves:
        peer_name, peer_ms = peers[look]
        print(f"{look}: {curve} (peer: {peer_name}, {peer_ms:.1f} ms)")
        for label, name, _ in points:
            print(f"  {curve + ', ' + label:<58} {best[name]:8.1f} ms {db[name]:6.2f} dB  {peer_ms / best[name]:6.2f}x")
            rows.append((look, curve, label, best[name], db[name]))
    if args.volpack:
        print(f"VolPack's classification (once per transfer function): {min(volpack_classify):.1f} ms")
    def cheapest(look, prefix, target):
        ok = [(best[n], db[n], c, l) for c, lk, pts in curves if lk == look and c.startswith(prefix) for l, n, _ in pts if db[n] >= target]
        return min(ok) if ok else None
    for look, target, ratio in (("volume", 35.0, 2.0),) + ((("surface", 35.0, 20.0),) if not args.volume_only else ()):
        peer_name, peer_ms = peers[look]
        ok = cheapest(look, "hybrid-octree slices", target)
        if ok:
            ms, d, c, l = ok
            print(f"target, {look} at >= {target:g} dB: {c}, {l}: {ms:.1f} ms, {d:.2f} dB against {peer_name} {peer_ms:.1f} ms: "
                  f"{peer_ms / ms:.2f}x (target >= {ratio:g}x)")
        else:
            print(f"target, {look} at >= {target:g} dB: no frame of ours reaches it")
    # Equal quality: each side's cheapest frame within 35 dB of its own converged image.
    ours_eq, theirs_eq = cheapest("volume", "hybrid-octree slices", 35.0), cheapest("vtk-own", "VTK", 35.0)
    if ours_eq and theirs_eq:
        print(f"target, volume at >= 35 dB each against its own reference: ours {ours_eq[2]}, {ours_eq[3]}: {ours_eq[0]:.1f} ms ({ours_eq[1]:.2f} dB); "
              f"VTK fixed-point {theirs_eq[3]}: {theirs_eq[0]:.1f} ms ({theirs_eq[1]:.2f} dB): {theirs_eq[0] / ours_eq[0]:.2f}x (target >= 4x)")
    else:
        print("target, volume at >= 35 dB each against its own reference: " + ("no frame of ours reaches it" if not ours_eq else "no VTK frame reaches it"))
    if args.csv:
        with open(args.csv + ".tmp", "w") as f:
            f.write("look,renderer,setting,ms,psnr_db\n")
            for look, curve, label, ms, d in rows:
                f.write(f"{look},{curve},{label},{ms:.1f},{d:.2f}\n")
        os.replace(args.csv + ".tmp", args.csv)
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        looks = ("volume", "surface", "ortho") if args.volpack else ("volume", "surface")
        fig, axes = plt.subplots(1, len(looks), figsize=(6 * len(looks), 5))
        titles = {"volume": "volume only", "surface": "volume + translucent 400 HU surface", "ortho": "volume only, orthographic (VolPack)"}
        for ax, look in zip(axes, looks):
            for curve, lk, points in curves:
                if (lk if lk != "vtk-own" else "volume") != look:  # (VTK against its own reference beside ours)
                    continue
                pts = [(best[n], min(db[n], 60.0)) for _, n, _ in points]  # in the order of their setting
                ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=curve)
            ax.set_xscale("log")
            ax.set_xlabel("frame time, ms (log)")
            ax.set_ylabel("PSNR against the reference, dB")
            ax.set_title(titles[look])
            ax.axhline(35.0, color="grey", linewidth=0.8, linestyle=":")
            ax.grid(True, which="both", linewidth=0.3)
            ax.legend(fontsize=7)
        fig.suptitle(f"{os.path.basename(args.volume)}, 512², ct-skin-bone, this machine (2 cores, llvmpipe)")
        fig.tight_layout()
        fig.savefig(args.plot + ".tmp.png", dpi=90)
        os.replace(args.plot + ".tmp.png", args.plot)


if __name__ == "__main__":
    main()
