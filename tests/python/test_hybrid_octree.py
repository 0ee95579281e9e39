"""The Python module against the command line: the same images and meshes from a numpy array as
from the same samples in a file, arrays kept without copies or held in the smallest type that holds
their values, every keyword in its Python forms, and bad input refused by name.

Run by the test command (ctest) with PYTHONPATH=BUILD/python and HYB_BIN=BUILD/hybrid-octree.
"""
import os
import pathlib
import re
import signal
import struct
import subprocess
import sys
import threading
import time
import zlib

import numpy as np
import pytest

import hybrid_octree as ho

BIN = os.environ.get("HYB_BIN", "hybrid-octree")
SURFACE = dict(iso=500, surface_color=(0.95, 0.9, 0.8, 0.5))


def blobs(dtype=np.int16):
    """Two Gaussian blobs in a 48x56x64 (z, y, x) grid, values 0..1000."""
    z, y, x = np.mgrid[0:48, 0:56, 0:64].astype(np.float64)
    v = 1000 * np.exp(-((x - 26) ** 2 + (y - 28) ** 2 + (z - 24) ** 2) / 200.0)
    v += 700 * np.exp(-((x - 44) ** 2 + (y - 24) ** 2 + (z - 20) ** 2) / 60.0)
    return np.ascontiguousarray(np.round(v).astype(dtype))


def write_nrrd(path, a, spacing, origin=(0, 0, 0), direction=np.eye(3)):
    """An attached NRRD of array a (z, y, x): sizes x y z, LPS space, raw little-endian."""
    types = {np.dtype(np.int16): "int16", np.dtype(np.uint8): "uint8", np.dtype(np.float32): "float", np.dtype(np.int32): "int32"}
    cols = [" (" + ",".join(repr(float(direction[r, c] * spacing[c])) for r in range(3)) + ")" for c in range(3)]
    header = (
        "NRRD0004\n"
        f"type: {types[a.dtype]}\ndimension: 3\nsizes: {a.shape[2]} {a.shape[1]} {a.shape[0]}\n"
        "space: left-posterior-superior\n"
        f"space directions:{''.join(cols)}\n"
        f"space origin: ({origin[0]},{origin[1]},{origin[2]})\n"
        "encoding: raw\nendian: little\n\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(a.astype(a.dtype.newbyteorder("<")).tobytes())


def write_png(path, rgba):
    """An 8-bit RGBA PNG of an (H, W, 4) uint8 array."""
    h, w, _ = rgba.shape
    raw = b"".join(b"\0" + rgba[y].tobytes() for y in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0)) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def over_black(image):
    """A straight-alpha image composited over black, opaque: what the command line's PNG holds."""
    rgb = np.round(image[..., :3].astype(np.float64) * image[..., 3:4] / 255.0)
    return np.concatenate([rgb.astype(np.uint8), np.full(image.shape[:2] + (1,), 255, np.uint8)], axis=2)


def psnr_to_cli(tmp_path, image, cli_png):
    """PSNR of @p image (straight alpha put over black, or opaque as it is) against the PNG."""
    mine = tmp_path / "mine.png"
    write_png(mine, image if (image[..., 3] == 255).all() else over_black(image))
    out = subprocess.run([BIN, "compare", str(cli_png), str(mine)], capture_output=True, text=True, check=True).stdout
    if "identical" in out:
        return float("inf")
    return float(re.search(r"PSNR ([0-9.]+) dB", out).group(1))


def cli(*args):
    return subprocess.run([BIN, *map(str, args), "--progress", "off"], capture_output=True, text=True, check=True).stdout


@pytest.fixture(scope="module")
def volume(tmp_path_factory):
    d = tmp_path_factory.mktemp("vol")
    a = blobs()
    spacing = (0.8, 0.9, 1.5)
    direction = np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], dtype=float)  # x along -y (posterior to anterior), y along +x
    origin = (-20.0, 15.0, -30.0)
    write_nrrd(d / "blobs.nrrd", a, spacing, origin, direction)
    return a, spacing, origin, direction, d / "blobs.nrrd"


@pytest.mark.parametrize("renderer", ["slices", "raycast"])
@pytest.mark.parametrize("ortho", [False, True])
def test_a_numpy_volume_renders_the_command_lines_image(tmp_path, volume, renderer, ortho):
    a, spacing, origin, direction, path = volume
    scene = ho.Scene(a, spacing=spacing, origin=origin, direction=direction)
    flags = ["--orbit", "30,15", "--size", "96x80", "--renderer", renderer, "--iso", "500", "--surface-color", "0.95,0.9,0.8,0.5"]
    kwargs = dict(orbit=(30, 15), size=(96, 80), renderer=renderer, **SURFACE)
    if ortho:
        flags.append("--ortho")
        kwargs["ortho"] = True
    cli("render", path, *flags, "-o", tmp_path / "cli.png")
    image = scene.render(**kwargs)
    assert image.shape == (80, 96, 4) and image.dtype == np.uint8
    assert image[..., 3].max() > 200  # something is drawn
    assert image[0, 0, 3] == 0  # straight alpha over transparent: the corner shows no data
    assert psnr_to_cli(tmp_path, image, tmp_path / "cli.png") >= 45.0
    # Over the command line's background (black by default) the image is its PNG, byte for byte.
    opened = ho.open(str(path))
    for s in (scene, opened):
        composited = s.render(background=(0, 0, 0), **kwargs)
        assert (composited[..., 3] == 255).all()
        assert psnr_to_cli(tmp_path, composited, tmp_path / "cli.png") == float("inf")
    cli("render", path, *flags, "--background", "0.2,0.3,0.4", "-o", tmp_path / "grey.png")
    assert psnr_to_cli(tmp_path, scene.render(background=(0.2, 0.3, 0.4), **kwargs), tmp_path / "grey.png") == float("inf")
    # The same file opened by the module: the same image.
    assert psnr_to_cli(tmp_path, opened.render(**kwargs), tmp_path / "cli.png") >= 45.0


def test_premultiplied_and_straight_alpha_agree(volume):
    a, spacing, *_ = volume
    scene = ho.Scene(a, spacing=spacing)
    straight = scene.render(size=(64, 64), **SURFACE).astype(np.float64)
    pre = scene.render(size=(64, 64), premultiplied=True, **SURFACE).astype(np.float64)
    assert np.array_equal(straight[..., 3], pre[..., 3])
    # Each rounds to 8 bits once (colour and alpha): within 1.5 of each other.
    assert np.abs(straight[..., :3] * straight[..., 3:4] / 255.0 - pre[..., :3]).max() <= 1.5


def test_statistics_and_a_transfer_function_array(volume):
    a, spacing, *_ = volume
    scene = ho.Scene(a, spacing=spacing)
    tf = np.array([[0, 1, 1, 1, 0], [300, 1, 0.5, 0.2, 0.05], [1000, 1, 1, 1, 0.3]])
    image, stats = scene.render(size=(48, 48), tf=tf, stats=True)
    assert stats["renderer"] == "slices" and stats["textured_bricks"] > 0 and stats["render_ms"] > 0
    # Red dominates where orange material is seen.
    seen = image[..., 3] > 100
    assert seen.any() and image[seen, 0].mean() > image[seen, 2].mean()
    with pytest.raises(ValueError, match="tf must be an"):
        scene.render(tf=np.zeros((3, 4)))


def read_off(path):
    lines = [l for l in open(path).read().split("\n") if l and not l.startswith("#")]
    assert lines[0].strip() == "OFF"
    nv, nf, _ = map(int, lines[1].split())
    v = np.array([list(map(float, l.split())) for l in lines[2 : 2 + nv]])
    f = np.array([list(map(int, l.split()))[1:] for l in lines[2 + nv : 2 + nv + nf]])
    return v, f


@pytest.mark.parametrize("kind", ["octree", "dmc", "mc"])
def test_the_mesh_equals_the_command_lines_export(tmp_path, volume, kind):
    a, spacing, origin, direction, path = volume
    scene = ho.Scene(a, spacing=spacing, origin=origin, direction=direction)
    vertices, faces = scene.surface(500, kind=kind)
    cli("export", path, "--iso", "500", "--surface", kind, "-o", tmp_path / "cli.off")
    v, f = read_off(tmp_path / "cli.off")
    assert vertices.shape == v.shape and faces.shape == f.shape
    assert vertices.dtype == np.float32 and faces.dtype == np.int64
    # Hausdorff 0: the same vertices (to the file's precision) and the same faces on them.
    assert np.abs(vertices - v).max() < 1e-3
    assert np.array_equal(faces, f)
    # The module writes the same file.
    scene.export(str(tmp_path / "mine.off"), 500, kind=kind)
    assert open(tmp_path / "mine.off").read() == open(tmp_path / "cli.off").read()
    # Normals on request: unit, one per vertex.
    _, _, normals = scene.surface(500, kind=kind, normals=True)
    assert normals.shape == vertices.shape
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-3)


def test_a_closed_surface_is_watertight(volume):
    a, spacing, *_ = volume
    _, faces = ho.Scene(a, spacing=spacing).surface(100, kind="octree", closed=True)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()


def test_the_array_is_kept_not_copied():
    a = blobs()
    before = sys.getrefcount(a)
    scene = ho.Scene(a)
    assert sys.getrefcount(a) == before + 1  # the scene holds the array itself
    info = scene.info()
    assert info["stored_type"] == "int16" and info["shape"] == a.shape and info["dims"] == a.shape[::-1]
    del scene
    assert sys.getrefcount(a) == before
    # Whole numbers of a wider type are held in a copy of 16 bits, and the array is not kept.
    for dtype in (np.int32, np.float64):
        wide = blobs(dtype)
        before = sys.getrefcount(wide)
        scene = ho.Scene(wide)
        assert scene.info()["stored_type"] == "int16" and sys.getrefcount(wide) == before


def test_info_says_what_the_command_line_says(volume):
    a, spacing, origin, direction, path = volume
    info = ho.Scene(a, spacing=spacing, origin=origin, direction=direction).info()
    assert info["spacing"] == pytest.approx(spacing)
    assert info["origin"] == pytest.approx(origin)
    assert np.allclose(info["direction"], direction)
    assert info["min"] == a.min() and info["max"] == a.max()
    h = ho.Scene(a).info(bins=10)["histogram"]
    assert sum(h["counts"]) == a.size and len(h["counts"]) == 10
    assert h["mean"] == pytest.approx(a.mean(), rel=1e-6) and h["p50"] == np.percentile(a, 50, method="lower")
    text = cli("info", path)
    assert info["orientation"] in text
    assert ho.open(str(path)).info()["dims"] == (64, 56, 48)


@pytest.mark.parametrize(
    "make, error, message",
    [
        (lambda: ho.Scene(np.zeros((4, 4))), ValueError, "3-D array"),
        (lambda: ho.Scene(np.zeros((4, 4, 4), np.complex64)), TypeError, "complex64 unsupported"),
        (lambda: ho.Scene(np.zeros((4, 4, 4), np.int64)), TypeError, "int64 unsupported"),
        (lambda: ho.Scene(np.full((4, 4, 4), np.nan, np.float32)), ValueError, "is nan; expected finite"),
        (lambda: ho.Scene(np.zeros((4, 4, 4), np.int16), spacing=(1, -1, 1)), ValueError, "spacing"),
        (lambda: ho.Scene(np.zeros((4, 4, 4), np.int16), spacing="abc"), ValueError, "spacing 'abc' invalid"),
        (lambda: ho.Scene(np.zeros((4, 4, 4), np.int16), spacing=1.0), TypeError, "spacing must be a sequence of numbers"),
        (lambda: ho.Scene(np.zeros((4, 4, 4), np.int16), direction="abc"), TypeError, "direction must be a 3x3 matrix of numbers"),
        (lambda: ho.Scene(np.zeros((4, 4, 4), np.int16), direction=np.eye(2)), ValueError, "direction must be a 3x3 matrix"),
        (lambda: ho.Scene([[[0]]]), TypeError, "array must be a numpy array"),
        (lambda: ho.Scene(np.zeros((4, 6, 8), np.int16).transpose()), ValueError, "C-contiguous"),
        (lambda: ho.Scene(np.zeros((4, 4, 4), np.int16), direction=np.ones((3, 3))), ValueError, "orthonormal"),
        (lambda: ho.Scene(np.zeros((4, 4, 4), ">i2")), TypeError, "big-endian"),
        (lambda: ho.open("/nonexistent.nrrd"), OSError, "nonexistent"),
    ],
)
def test_bad_arrays_are_refused_by_name(make, error, message):
    with pytest.raises(error, match=message):
        make()


def test_bad_render_arguments_get_the_command_lines_messages(volume):
    scene = ho.Scene(volume[0])
    for value in (1, None):  # an unknown keyword is reported even when None
        with pytest.raises(TypeError, match="unexpected keyword argument 'colour'"):
            scene.render(colour=value)
    with pytest.raises(ValueError, match="--orbit"):
        scene.render(orbit=(1, 2, 3))
    with pytest.raises(ValueError, match="--step"):
        scene.render(step=-1)
    with pytest.raises(ValueError, match="--renderer"):
        scene.render(renderer="gpu")
    with pytest.raises(ValueError, match="size"):
        scene.render(size=(0, 10))
    with pytest.raises(ValueError, match="kind"):
        scene.surface(500, kind="marching")
    with pytest.raises(ValueError, match="unknown extension"):
        scene.export("/tmp/mesh.xyz", 500)


def test_a_render_stops_at_ctrl_c():
    scene = ho.Scene(blobs())
    threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        scene.render(renderer="raycast", step=0.02, size=(1024, 1024))  # about a minute uninterrupted
    assert time.monotonic() - start < 10.0
    assert scene.render(size=(32, 32)).shape == (32, 32, 4)  # and the scene still renders


def test_numpy_scalars_a_kept_surface_and_two_threads():
    a = blobs()
    scene = ho.Scene(a, iso=500)
    assert scene.info()["surfaces"] == [500.0]  # built at construction, kept for frames
    one = scene.render(size=(48, 48), iso=a.max() // 2, zoom=np.float32(1.5))  # numpy scalars as flag values
    assert one.shape == (48, 48, 4)
    # Two threads on one scene take turns: each gets the frame it would get alone.
    alone = scene.render(size=(40, 40), orbit=(10, 10))
    images = [None, None]

    def draw(k):
        images[k] = scene.render(size=(40, 40), orbit=(10, 10))

    threads = [threading.Thread(target=draw, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(np.array_equal(i, alone) for i in images)


def test_a_misaligned_array_is_refused():
    buf = np.zeros(2 * 4 * 4 * 4 + 1, np.uint8)
    a = np.frombuffer(buf.data, dtype="<u2", count=64, offset=1).reshape(4, 4, 4)
    assert not a.flags.aligned
    with pytest.raises(ValueError, match="aligned"):
        ho.Scene(a)


# Converted arrays: where each range of whole numbers is held, and where fractions are.
HELD = [((0, 255), "uint8"), ((-1024, 3071), "int16"), ((0, 65535), "uint16"), ((-1, 65535), "float32"), ((0, 70000), "float32")]


@pytest.mark.parametrize("dtype", [np.float64, np.int32, np.uint32])
@pytest.mark.parametrize("values, stored", HELD + [((0, 0.5), "float32"), ((-1024.5, 0), "float32")])
def test_converted_arrays_are_held_in_the_smallest_type_holding_their_values(dtype, values, stored):
    lo, hi = values
    if np.dtype(dtype).kind in "iu" and (lo != int(lo) or hi != int(hi) or lo < np.iinfo(dtype).min):
        pytest.skip("not values of the type")
    a = np.zeros((6, 5, 4), dtype)
    a[1, 2, 3], a[4, 0, 1] = lo, hi
    info = ho.Scene(a).info()
    assert info["type"] == np.dtype(dtype).name and info["stored_type"] == stored
    assert (info["min"], info["max"]) == (min(lo, 0), hi)


def test_a_float64_ct_is_held_as_int16_and_renders_as_the_int16_one(tmp_path):
    ct = blobs() - 1024  # what nibabel's get_fdata() gives for int16 with slope 1, intercept -1024: float64
    as_read = ho.Scene(ct, spacing=(0.8, 0.9, 1.5), iso=-524)
    fdata = ho.Scene(ct.astype(np.float64), spacing=(0.8, 0.9, 1.5), iso=-524)
    assert fdata.info()["stored_type"] == "int16"
    assert fdata.info()["histogram"] == as_read.info()["histogram"]
    flags = dict(size=(64, 48), orbit=(20, 10), surface_color=(0.95, 0.9, 0.8, 0.5))
    for renderer in ("slices", "raycast"):
        assert np.array_equal(fdata.render(renderer=renderer, iso=-524, **flags), as_read.render(renderer=renderer, iso=-524, **flags))
    for mine, theirs in zip(fdata.surface(-524), as_read.surface(-524)):
        assert np.array_equal(mine, theirs)
    # 0..255 as float64 (a uint8 file's get_fdata()) is held as uint8 and renders as the uint8 array.
    small = (blobs() // 4).astype(np.uint8)
    wide = ho.Scene(small.astype(np.float64))
    assert wide.info()["stored_type"] == "uint8"
    assert np.array_equal(wide.render(size=(48, 48), orbit=(30, 10)), ho.Scene(small).render(size=(48, 48), orbit=(30, 10)))


def test_float32_whole_numbers_are_used_in_place_as_the_readers_hold_float32():
    a = blobs(np.float32)
    before = sys.getrefcount(a)
    scene = ho.Scene(a)
    assert scene.info()["stored_type"] == "float32" and sys.getrefcount(a) == before + 1


@pytest.mark.parametrize("bad, text", [(np.nan, "nan"), (np.inf, "inf"), (-np.inf, "-inf"), (1e300, "1e\\+300"), (-4e38, "-4e\\+38")])
def test_float64_values_float32_cannot_hold_are_refused_by_sample(bad, text):
    a = blobs(np.float64)
    a[1, 2, 3] = bad
    with pytest.raises(ValueError, match=f"numpy array: sample \\(3,2,1\\) is {text}; expected finite values"):
        ho.Scene(a)


# render()'s keywords: (keyword, its form (WRONG_TYPES), the flag's text, the same value in its
# Python forms, other keywords the frame needs). Every form gives the image of the text.
EYE = (31.5, -150.0, 23.5)
VOI = "10,10,10,40,40,30"
KEYWORDS = [
    ("view", "Word", "left", [np.str_("left")], {}),
    ("orbit", "Numbers", "30,10", [(30, 10), [30, 10.0], np.array([30, 10]), np.array([30, 10], np.float32), (np.int64(30), np.float64(10))], {}),
    ("eye", "Numbers", "31.5,-150,23.5", [EYE, list(EYE), np.array(EYE), (np.float32(31.5), np.int16(-150), 23.5)], {}),
    ("center", "Numbers", "31.5,27.5,20", [(31.5, 27.5, 20), np.array([31.5, 27.5, 20])], {"eye": EYE}),
    ("up", "Numbers", "0.5,0,1", [(0.5, 0, 1), [0.5, 0.0, 1.0], np.array([0.5, 0, 1])], {"eye": EYE}),
    ("zoom", "Number", "1.5", [1.5, np.float64(1.5), np.float32(1.5), np.array(1.5)], {}),
    ("fov", "Number", "40", [40, 40.0, np.int32(40), np.uint8(40), np.array(40)], {}),
    ("ortho", "Flag", True, [np.bool_(True), np.array(True)], {}),
    ("ortho_height", "Number", "30", [30, 30.0, np.float32(30), np.array(30)], {"ortho": True}),
    ("size", "Size", "64x48", [(64, 48), [64, 48], np.array([64, 48]), (np.int64(64), np.uint16(48)), "64X48"], {}),
    ("marker", "Switch", "on", [True, np.bool_(True), np.array(True)], {}),
    ("preset", "Word", "ct-bone", [np.str_("ct-bone")], {}),
    ("opacity", "Number", "0.5", [0.5, np.float32(0.5), np.array(0.5)], {}),
    ("iso", "Number", "500", [500, 500.0, np.int16(500), np.float32(500), np.array(500.0)], {}),
    ("surface_color", "Numbers", "0.9,0.5,0.2,0.5", [(0.9, 0.5, 0.2, 0.5), [0.9, 0.5, 0.2, 0.5], np.array([0.9, 0.5, 0.2, 0.5], np.float32)], {"iso": 500}),
    ("surface_normals", "Word", "facet", [np.str_("facet")], {"iso": 500}),
    ("shading", "Switch", "off", [False, np.bool_(False), np.array(False)], {}),
    ("background", "Numbers", "0.2,0.3,0.4", [(0.2, 0.3, 0.4), [0.2, 0.3, 0.4], np.array([0.2, 0.3, 0.4])], {}),
    ("cut", "Numbers", "31.5,27.5,23.5,0,1,0", [(31.5, 27.5, 23.5, 0, 1, 0), np.array([31.5, 27.5, 23.5, 0, 1, 0])], {}),
    ("cut_line", "Switch", "off", [False, np.bool_(False)], {"iso": 500, "cut": "31.5,27.5,23.5,0,1,0"}),
    ("voi", "Numbers", VOI, [(10, 10, 10, 40, 40, 30), np.array([10, 10, 10, 40, 40, 30], np.int16)], {}),
    ("voi_inside", "Number", "0.5", [0.5, np.float64(0.5)], {"voi": VOI}),
    ("voi_outside", "Number", "0.5", [0.5, np.float32(0.5)], {"voi": VOI}),
    ("voi_ramp", "Number", "2", [2, 2.0, np.int8(2)], {"voi": VOI}),
    ("primitive", "Word", "sphere:31.5,27.5,20,8:1,0,0,0.5", [np.str_("sphere:31.5,27.5,20,8:1,0,0,0.5")], {}),
    ("mesh_method", "Word", "scan-convert", [np.str_("scan-convert")], {"primitive": "sphere:31.5,27.5,20,8:1,0,0,0.5"}),
    ("mesh_filter", "Word", "none", [np.str_("none")], {"primitive": "sphere:31.5,27.5,20,8:1,0,0,0.5", "mesh_method": "scan-convert"}),
    ("renderer", "Word", "raycast", [np.str_("raycast")], {}),
    ("epsilon", "Number", "50", [50, 50.0, np.float32(50)], {}),
    ("budget", "Budget", "0.05", [0.05, np.float64(0.05), np.array(0.05)], {}),
    ("step", "Number", "1", [1, 1.0, np.float32(1), np.int64(1)], {}),
    ("classification", "Word", "preintegrated", [np.str_("preintegrated")], {}),
    ("proxy", "Word", "shells", [np.str_("shells")], {}),
    ("blend", "Switch", "off", [False, np.bool_(False)], {"epsilon": 100}),
    ("lod_pixels", "Number", "4", [4, 4.0, np.float32(4)], {}),
    ("max_brick", "Integer", "16", [16, np.int64(16), np.uint8(16), np.array(16)], {}),
    ("texel_bits", "Integer", "16", [16, np.int32(16)], {}),
    ("focus", "Numbers", "20,20,20", [(20, 20, 20), np.array([20.0, 20.0, 20.0])], {"epsilon": 5, "max_brick": 8}),
    ("image_scale", "Number", "0.5", [0.5, np.float64(0.5), np.float32(0.5)], {}),
]
# Keywords whose value here draws what their default draws (the test still checks their forms).
SAME_AS_DEFAULT = {"blend", "texel_bits", "max_brick"}


@pytest.fixture(scope="module")
def small_scene():
    return ho.Scene(blobs())


@pytest.mark.parametrize("key, form, text, forms, extra", KEYWORDS, ids=[k[0] for k in KEYWORDS])
def test_every_keyword_takes_its_python_forms(small_scene, key, form, text, forms, extra):
    base = dict(size=(48, 40), **extra)
    if key == "size":
        del base["size"]
    canonical = small_scene.render(**base, **{key: text})
    for form in forms:
        assert np.array_equal(small_scene.render(**base, **{key: form}), canonical), repr(form)
    assert np.array_equal(small_scene.render(**base, **{key: None}), small_scene.render(**base))  # None: the keyword left out
    if key not in SAME_AS_DEFAULT:
        assert not np.array_equal(canonical, small_scene.render(**base))


def test_the_stubs_declare_every_keyword_of_the_table_and_each_is_tested():
    stub = open(os.path.join(os.path.dirname(__file__), "../../apps/python/hybrid_octree.pyi")).read()
    declared = re.search(r"def render\(\n        self,\n        \*,\n(.*?)\*\*more", stub, re.S).group(1)
    names = set(re.findall(r"^\s+(\w+):", declared, re.M))
    table = {f["name"] for f in ho.frame_fields()}
    assert names == table | {"premultiplied", "stats", "meshes"}
    assert {k[0] for k in KEYWORDS} | {"tf", "camera_file", "mesh", "mesh_space"} == table


def test_meshes_as_arrays_and_as_files_draw_alike(tmp_path, small_scene):
    # A square plate across the blobs (LPS mm): as arrays, and as an OBJ in RAS read with mesh_space.
    v = np.array([[5, 5, 20], [60, 5, 20], [60, 50, 20], [5, 50, 20]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    base = dict(size=(48, 40), orbit=(20, 30))
    arrays = small_scene.render(**base, meshes=[(v, f, (1, 0, 0, 0.5))])
    assert not np.array_equal(arrays, small_scene.render(**base))
    obj = tmp_path / "plate.obj"
    obj.write_text("".join(f"v {-x} {-y} {z}\n" for x, y, z in v) + "f 1 2 3\nf 1 3 4\n")
    assert np.array_equal(small_scene.render(**base, mesh=f"{obj}:1,0,0,0.5", mesh_space="ras"), arrays)
    with pytest.raises(ValueError, match=r"^meshes\[0\]: triangle 1 uses vertex 9 \(expected indices below 4\)"):
        small_scene.render(**base, meshes=[(v, np.array([[0, 1, 2], [0, 2, 9]]), (1, 0, 0, 1))])
    nan = v.copy()
    nan[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"^meshes\[0\]: vertex 2 is not finite"):
        small_scene.render(**base, meshes=[(nan, f, (1, 0, 0, 1))])
    with pytest.raises(ValueError, match=r"^meshes\[0\]: the mesh has no triangles"):
        small_scene.render(**base, meshes=[(v, np.zeros((0, 3), int), (1, 0, 0, 1))])
    with pytest.raises(ValueError, match=r"--mesh meshes\[0\]: colour components must be in \[0, 1\]"):
        small_scene.render(**base, meshes=[(v, f, (2, 0, 0, 1))])
    with pytest.raises(TypeError, match="^meshes: expected a list"):
        small_scene.render(**base, meshes=3)
    with pytest.raises(OSError, match=r"nothing\.xyz: not a mesh file \(expected \.ply, \.obj, \.stl or \.off\)$"):
        small_scene.render(**base, mesh=str(tmp_path / "nothing.xyz"))


@pytest.mark.parametrize("field", [f for f in ho.frame_fields() if "max" in f and f["max"] < 1e30], ids=lambda f: f["name"])
def test_a_value_beyond_a_fields_range_gets_the_command_lines_message(field):
    bad = field["max"] * 2 + 1
    if field["kind"] in ("integer", "size"):
        bad = int(bad)
    text = ",".join([repr(bad)] * field["count"]) if field["kind"] == "numbers" else f"{int(bad)}x{int(bad)}" if field["kind"] == "size" else repr(bad)
    flag = "--" + field["name"].replace("_", "-")
    run = subprocess.run([BIN, "render", flag, text, "-o", "/nonexistent/x.png"], capture_output=True, text=True)
    assert run.returncode == 2
    expected = re.search(r"invalid \(expected [^\n]*\)", run.stderr).group(0)
    value = tuple([bad] * field["count"]) if field["kind"] in ("numbers", "size") else bad
    with pytest.raises(ValueError) as refused:
        ho.Scene(blobs()).render(**{field["name"]: value})
    assert flag in str(refused.value) and expected in str(refused.value)


def test_files_and_arrays_as_python_forms(tmp_path, small_scene):
    points = [[0, 1, 1, 1, 0], [300, 1, 0.5, 0.2, 0.05], [1000, 1, 1, 1, 0.3]]
    (tmp_path / "t.tf").write_text("".join(" ".join(map(str, p)) + "\n" for p in points))
    canonical = small_scene.render(size=(48, 40), tf=np.array(points))
    for tf in (points, np.array(points, np.float32), str(tmp_path / "t.tf"), tmp_path / "t.tf"):
        assert np.array_equal(small_scene.render(size=(48, 40), tf=tf), canonical)
    # A camera file (what --stats writes), as str or os.PathLike.
    path = tmp_path / "blobs.nrrd"
    write_nrrd(path, blobs(), (1, 1, 1))
    cli("render", path, "--orbit", "40,20", "--size", "48x40", "-o", tmp_path / "c.png", "--stats", tmp_path / "c.json")
    from_file = small_scene.render(camera_file=str(tmp_path / "c.json"))
    assert np.array_equal(small_scene.render(camera_file=tmp_path / "c.json"), from_file)
    assert np.array_equal(from_file, small_scene.render(size=(48, 40), orbit=(40, 20)))
    # True/False keywords of Python's own take numpy's bools.
    assert np.array_equal(small_scene.render(size=(32, 32), premultiplied=np.bool_(True)), small_scene.render(size=(32, 32), premultiplied=True))
    assert isinstance(small_scene.render(size=(32, 32), stats=np.bool_(True)), tuple)


def test_statistics_are_the_command_lines_stats(tmp_path):
    """One writer of a frame's statistics: render(stats=True) has --stats' keys and, for the same
    frame, its counts; --stats adds the command's own times only."""
    import json
    path = tmp_path / "blobs.nrrd"
    write_nrrd(path, blobs(), (1, 1, 1))
    cli("render", path, "--orbit", "40,20", "--size", "48x40", "--iso", "500", "-o", tmp_path / "c.png", "--stats", tmp_path / "c.json")
    written = json.loads((tmp_path / "c.json").read_text())
    _, stats = ho.open(str(path)).render(size=(48, 40), orbit=(40, 20), iso=500, stats=True)
    assert set(written) - set(stats) == {"build_ms", "surface_polygons_ms", "first_render_ms"}
    assert set(stats) <= set(written)
    for key in ("renderer", "nodes_selected", "textured_bricks", "texels", "slices", "surface_triangles", "slab_polygon_draws", "budget_met"):
        assert stats[key] == written[key], key
    assert stats["camera"] == written["camera"]



def test_statistics_report_the_scan_conversion(tmp_path):
    """A frame compositing scan-converted geometry reports its conversion's time and the channel's
    bytes (0 ms when it kept the channel of the frame before); a frame without it has neither
    key."""
    path = tmp_path / "blobs.nrrd"
    write_nrrd(path, blobs(), (1, 1, 1))
    scene = ho.open(str(path))
    geometry = {"primitive": "sphere:31.5,27.5,20,8:1,0,0,0.5", "mesh_method": "scan-convert"}
    _, first = scene.render(size=(24, 24), stats=True, **geometry)
    _, again = scene.render(size=(24, 24), stats=True, **geometry)
    assert first["geometry_ms"] > 0 and first["geometry_bytes"] > 0
    assert again["geometry_ms"] == 0 and again["geometry_bytes"] == first["geometry_bytes"]
    for without in ({}, {"primitive": geometry["primitive"]}):
        _, stats = scene.render(size=(24, 24), stats=True, **without)
        assert "geometry_ms" not in stats and "geometry_bytes" not in stats

def test_a_render_with_the_meshes_of_the_one_before_converts_nothing_again(tmp_path):
    """Scene.render keeps the meshes of the same files, primitives and arrays from one call to the
    next, as the viewer's frames do, and the renderer keeps their scan-converted channel: a second
    render converts nothing (geometry_ms 0) and draws the same image; a file written again (a new
    time of its last change), another primitive or other arrays are converted anew."""
    path = tmp_path / "blobs.nrrd"
    write_nrrd(path, blobs(), (1, 1, 1))
    scene = ho.open(str(path))
    # A closed octahedron about (31.5, 27.5, 20) LPS mm, 9 mm to its corners.
    corners = np.array([[9, 0, 0], [-9, 0, 0], [0, 9, 0], [0, -9, 0], [0, 0, 9], [0, 0, -9]], float) + (31.5, 27.5, 20)
    faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    obj = tmp_path / "octahedron.obj"
    obj.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in corners) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    base = dict(size=(32, 32), mesh_method="scan-convert", stats=True)

    def render(**geometry):
        image, stats = scene.render(**base, **geometry)
        return image, stats["geometry_ms"]

    for geometry in (dict(mesh=f"{obj}:1,0,0,0.6"), dict(primitive="sphere:31.5,27.5,20,8:0,1,0,0.5"),
                     dict(meshes=[(corners, faces, (0, 0, 1, 0.7))])):
        first, first_ms = render(**geometry)
        again, again_ms = render(**geometry)
        assert first_ms > 0 and again_ms == 0, geometry
        assert np.array_equal(again, first), geometry
    # The file written again: read and converted anew.
    first, _ = render(mesh=f"{obj}:1,0,0,0.6")
    changed = obj.stat().st_mtime_ns + 2_000_000_000
    os.utime(obj, ns=(changed, changed))
    image, ms = render(mesh=f"{obj}:1,0,0,0.6")
    assert ms > 0 and np.array_equal(image, first)
    assert render(mesh=f"{obj}:1,0,0,0.6")[1] == 0
    # Another primitive, and arrays holding other vertices: converted anew.
    assert render(primitive="sphere:31.5,27.5,20,7:0,1,0,0.5")[1] > 0
    assert render(meshes=[(corners * 1.01, faces, (0, 0, 1, 0.7))])[1] > 0
    assert render(meshes=[(corners * 1.01, faces, (0, 0, 1, 0.7))])[1] == 0


# Values no text of a keyword's form spells, by form.
WRONG_TYPES = {
    "Number": [(1, 2), [1.5], {}, 1 + 2j, True, np.bool_(True), np.array([1.5]), b"1", object()],
    "Integer": [16.5, np.float64(16), (16,), True, {}],
    "Numbers": [30, [[30, 10]], np.zeros((1, 2)), ("30", "10"), {30, 10}, (True, False), b"30,10"],
    "Size": [64, (64.0, 48), np.array([64.0, 48.0]), ("64", 48), {}],
    "Budget": [(1, 2), [1.5], {}, True, b"1", object()],
    "Word": [3, ("left",), b"left", True],
    "Switch": [1, 0.0, (True,), {}],
    "Flag": ["on", 1, 1.0, {}],
}
FORM = {k[0]: k[1] for k in KEYWORDS}


@pytest.mark.parametrize("key", [k[0] for k in KEYWORDS] + ["premultiplied", "stats", "tf"])
def test_a_wrong_type_raises_type_error_naming_the_keyword(small_scene, key):
    for value in WRONG_TYPES[FORM.get(key, "Flag")] if key != "tf" else [{}, 3, [["a"] * 5]]:
        with pytest.raises(TypeError, match=f"^{key} must be .*, got ") as e:
            small_scene.render(**{"size": (32, 32), key: value})
        assert "cast" not in str(e.value)


# Wrong values: the keyword, and the flags the command line gets for it.
WRONG_VALUES = [
    (dict(size="0x10"), ["--size", "0x10"]),
    (dict(size=(0, 10)), ["--size", "0x10"]),
    (dict(size=(64, 48, 2)), ["--size", "64x48x2"]),
    (dict(orbit=(1, 2, 3)), ["--orbit", "1,2,3"]),
    (dict(orbit="abc"), ["--orbit", "abc"]),
    (dict(eye=np.array([1.0, 2.0])), ["--eye", "1.0,2.0"]),
    (dict(zoom=-1), ["--zoom", "-1"]),
    (dict(zoom="big"), ["--zoom", "big"]),
    (dict(fov=np.float32(180)), ["--fov", "180.0"]),
    (dict(iso=np.nan), ["--iso", "nan"]),
    (dict(iso=1e39), ["--iso", "1e+39"]),
    (dict(surface_color=(2, 0, 0, 1)), ["--surface-color", "2,0,0,1"]),
    (dict(background=(1, 1)), ["--background", "1,1"]),
    (dict(shading="maybe"), ["--shading", "maybe"]),
    (dict(view="front"), ["--view", "front"]),
    (dict(preset="nope"), ["--preset", "nope"]),
    (dict(renderer="gpu"), ["--renderer", "gpu"]),
    (dict(cut=(0, 0, 0, 0, 0, 0)), ["--cut", "0,0,0,0,0,0"]),
    (dict(voi=(1, 1, 1, 0, 0, 0)), ["--voi", "1,1,1,0,0,0"]),
    (dict(voi_ramp=-1), ["--voi-ramp", "-1"]),
    (dict(epsilon=-1), ["--epsilon", "-1"]),
    (dict(budget="150%"), ["--budget", "150%"]),
    (dict(step=np.float64(-1)), ["--step", "-1.0"]),
    (dict(classification="pre"), ["--classification", "pre"]),
    (dict(max_brick=np.int64(12)), ["--max-brick", "12"]),
    (dict(max_brick="abc"), ["--max-brick", "abc"]),
    (dict(texel_bits=12), ["--texel-bits", "12"]),
    (dict(image_scale=2), ["--image-scale", "2"]),
    (dict(center=(1, 2, 3)), ["--center", "1,2,3"]),
]


def test_a_wrong_value_raises_the_command_lines_message(tmp_path, small_scene):
    path = tmp_path / "blobs.nrrd"
    write_nrrd(path, blobs(), (1, 1, 1))
    for kwargs, flags in WRONG_VALUES:
        run = subprocess.run([BIN, "render", str(path), *flags, "-o", str(tmp_path / "x.png"), "--progress", "off"], capture_output=True, text=True)
        assert run.returncode == 2, flags
        line = run.stderr.strip().splitlines()[-1]
        with pytest.raises(ValueError) as e:
            small_scene.render(**{"size": (32, 32), **kwargs})
        assert str(e.value) and str(e.value) in line, (kwargs, str(e.value), line)
    with pytest.raises(ValueError, match="premultiplied and background are exclusive"):
        small_scene.render(background=(0, 0, 0), premultiplied=True)
    with pytest.raises(ValueError, match="--tf and --preset are exclusive"):
        small_scene.render(tf=np.array([[0, 1, 1, 1, 0], [1000, 1, 1, 1, 1]]), preset="ct-bone")


def test_surface_export_info_scene_and_open_take_python_forms(tmp_path, volume):
    a, spacing, origin, direction, path = volume
    scene = ho.Scene(a, spacing=spacing, origin=origin, direction=direction)
    vertices, faces = scene.surface(500)
    for iso in (500.0, np.int16(500), np.float32(500), np.array(500), "500"):
        v, f = scene.surface(iso, kind=np.str_("octree"), closed=np.bool_(False))
        assert np.array_equal(v, vertices) and np.array_equal(f, faces)
    assert len(scene.surface(500, normals=np.bool_(True))) == 3
    assert len(scene.surface(5000, normals=True)) == 3  # an empty surface has its (0, 3) normals too
    scene.export(str(tmp_path / "a.off"), 500)
    scene.export(tmp_path / "b.off", np.float32(500), kind=np.str_("dmc"))
    assert open(tmp_path / "a.off").read() == open(tmp_path / "b.off").read()
    assert all(scene.info(bins=b)["histogram"]["counts"] == scene.info(bins=10)["histogram"]["counts"] for b in (np.int64(10), "10", np.array(10)))
    for forms in [dict(spacing=list(spacing), origin=np.array(origin), direction=direction.tolist()),
                  dict(spacing=",".join(map(str, spacing)), origin=",".join(map(str, origin)), direction=tuple(direction.ravel()))]:
        assert np.array_equal(ho.Scene(a, iso=np.float32(500), **forms).surface(500)[0], vertices)
    assert ho.open(pathlib.Path(path)).info()["dims"] == (64, 56, 48)
    # Wrong types: TypeError naming the argument; wrong values: ValueError.
    for call, error, message in [
        (lambda: scene.surface(None), TypeError, "^iso must be a number"),
        (lambda: scene.surface((500,)), TypeError, "^iso must be a number"),
        (lambda: scene.surface(500, closed="yes"), TypeError, "^closed must be True or False"),
        (lambda: scene.surface(500, normals=1), TypeError, "^normals must be True or False"),
        (lambda: scene.surface(500, kind=3), TypeError, "^kind must be a str"),
        (lambda: scene.export(3, 500), TypeError, "^path must be a str"),
        (lambda: scene.info(bins=2.5), TypeError, "^bins must be an integer"),
        (lambda: ho.Scene(a, iso=[500]), TypeError, "^iso must be a number"),
        (lambda: ho.Scene(a, origin={}), TypeError, "^origin must be a sequence of numbers"),
        (lambda: ho.open(3), TypeError, "^path must be a str"),
        (lambda: scene.surface("abc"), ValueError, "iso 'abc' invalid"),
        (lambda: scene.surface(np.nan), ValueError, "iso 'nan' invalid"),
        (lambda: scene.surface(1e39), ValueError, "iso must be a finite number within the float range"),
        (lambda: scene.surface(500, kind="marching"), ValueError, "surface kind 'marching' invalid"),
        (lambda: scene.info(bins=0), ValueError, "bins must be in 1..4096"),
        (lambda: scene.info(bins="2.5"), ValueError, "bins '2.5' invalid \\(expected an integer\\)"),
        (lambda: ho.Scene(a, spacing=(1, 2)), ValueError, "spacing '1,2' invalid"),
        (lambda: ho.Scene(a, origin=(0, 0, np.inf)), ValueError, "origin '0,0,inf' invalid"),
    ]:
        with pytest.raises(error, match=message) as e:
            call()
        assert "cast" not in str(e.value)


def test_the_array_is_a_view_of_the_scenes_own_samples_and_the_affine_its_frame(tmp_path):
    a = blobs()
    spacing, origin = (0.5, 0.75, 1.25), (10.0, -20.0, 30.0)
    direction = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    scene = ho.Scene(a, spacing=spacing, origin=origin, direction=direction)
    view = scene.array
    # An array given to Scene: the same memory, no copy, read-only, kept alive by the scene.
    assert view.shape == a.shape and view.dtype == np.int16
    assert np.shares_memory(view, a) and not view.flags.writeable and not view.flags.owndata
    with pytest.raises(ValueError):
        view[0, 0, 0] = 1
    # The affine maps index (x, y, z) to LPS: (0,0,0) to the origin, the far corner to the info's extent.
    m, info = scene.affine, scene.info()
    assert m.shape == (4, 4) and np.array_equal(m[3], [0, 0, 0, 1])
    np.testing.assert_allclose(m[:3, 3], info["origin"])
    far = np.array([a.shape[2] - 1, a.shape[1] - 1, a.shape[0] - 1, 1.0])
    expected = np.array(origin) + direction @ (far[:3] * np.array(spacing))
    np.testing.assert_allclose((m @ far)[:3], expected, atol=1e-9)
    # From a file: the volume read (a view of the scene's samples), equal to what was written.
    write_nrrd(tmp_path / "v.nrrd", a, spacing, origin, direction)
    opened = ho.open(tmp_path / "v.nrrd")
    assert np.array_equal(opened.array, a) and not opened.array.flags.owndata
    np.testing.assert_allclose(opened.affine, m, atol=1e-9)
    # From a scene file read paged: a copy of the same samples.
    subprocess.run([BIN, "build", str(tmp_path / "v.nrrd"), "-o", str(tmp_path / "v.hoct")], check=True, capture_output=True)
    paged = ho.open(tmp_path / "v.hoct")
    assert np.array_equal(paged.array, a)
    np.testing.assert_allclose(paged.affine, m, atol=1e-9)
    held = paged.array
    del paged
    assert held.sum() == a.sum()  # the copy outlives the scene


def dicom_element(group, element, vr, value):
    """One explicit-VR little-endian element, padded to even length as DICOM requires."""
    if isinstance(value, str):
        value = value.encode("latin1")
    if len(value) % 2:
        value += b"\0" if vr in ("UI", "OB") else b" "
    if vr in ("OB", "OW", "SQ", "UN", "UT"):
        return struct.pack("<HH2sHI", group, element, vr.encode(), 0, len(value)) + value
    return struct.pack("<HH2sH", group, element, vr.encode(), len(value)) + value


def write_ct_slice(path, position, cosines, pixels, spacing, tilt, series="1.2.826.0.1.3680043.8.498.302"):
    """A CT image as a scanner writes it: HU = stored - 1024, Image Position and Orientation."""
    ct, uid = "1.2.840.10008.5.1.4.1.1.2", "1.2.826.0.1.3680043.8.498.300." + path.name
    meta = dicom_element(2, 1, "OB", b"\0\1") + dicom_element(2, 2, "UI", ct) + dicom_element(2, 3, "UI", uid) + dicom_element(2, 0x10, "UI", "1.2.840.10008.1.2.1")
    ds = lambda *v: "\\".join(repr(float(x)) for x in v)
    rows, cols = pixels.shape
    data = b"".join([
        dicom_element(8, 0x16, "UI", ct), dicom_element(8, 0x18, "UI", uid), dicom_element(8, 0x60, "CS", "CT"),
        dicom_element(0x18, 0x1120, "DS", ds(tilt)),
        dicom_element(0x20, 0x0D, "UI", "1.2.826.0.1.3680043.8.498.301"), dicom_element(0x20, 0x0E, "UI", series),
        dicom_element(0x20, 0x32, "DS", ds(*position)), dicom_element(0x20, 0x37, "DS", ds(*cosines)),
        dicom_element(0x28, 2, "US", struct.pack("<H", 1)), dicom_element(0x28, 4, "CS", "MONOCHROME2"),
        dicom_element(0x28, 0x10, "US", struct.pack("<H", rows)), dicom_element(0x28, 0x11, "US", struct.pack("<H", cols)),
        dicom_element(0x28, 0x30, "DS", ds(spacing, spacing)), dicom_element(0x28, 0x100, "US", struct.pack("<H", 16)),
        dicom_element(0x28, 0x101, "US", struct.pack("<H", 16)), dicom_element(0x28, 0x102, "US", struct.pack("<H", 15)),
        dicom_element(0x28, 0x103, "US", struct.pack("<H", 1)), dicom_element(0x28, 0x1052, "DS", "-1024"), dicom_element(0x28, 0x1053, "DS", "1"),
        dicom_element(0x7FE0, 0x10, "OW", (pixels + 1024).astype("<i2").tobytes())])
    path.write_bytes(b"\0" * 128 + b"DICM" + dicom_element(2, 0, "UL", struct.pack("<I", len(meta))) + meta + data)


def test_a_tilted_dicom_series_lands_where_its_slices_put_it_through_array_and_affine(tmp_path):
    """A ball of bone at (5, -3, 2) mm, scanned with a 20° gantry tilt: its centroid from
    Scene.array and Scene.affine agrees with the one of the source slices, each pixel where it lies."""
    t = np.radians(20.0)
    r, c = np.array([1.0, 0.0, 0.0]), np.array([0.0, np.cos(t), np.sin(t)])
    centre, n, spacing = np.array([5.0, -3.0, 2.0]), 48, 1.0
    folder = tmp_path / "CT"
    folder.mkdir()
    truth, untilted, count = np.zeros(3), np.zeros(3), 0
    j, i = np.mgrid[0:n, 0:n].astype(np.float64)
    first, normal = np.array([-24.0, -20.0, -30.0]), np.cross(r, c)
    for k in range(36):
        p0 = first + [0.0, 0.0, 1.5 * k]  # the table advances along z, the plane is tilted
        pts = p0 + i[..., None] * spacing * r + j[..., None] * spacing * c
        hu = np.where(np.linalg.norm(pts - centre, axis=-1) < 9.0, 1000, -1000).astype(np.int16)
        write_ct_slice(folder / f"I{36 - k}", p0, (*r, *c), hu, spacing, 20.0)
        truth += pts[hu > 0].sum(axis=0)
        # Where a reading that ignores the tilt would put them: straight along the first slice's normal.
        untilted += (pts - p0 + first + np.dot(p0 - first, normal) * normal)[hu > 0].sum(axis=0)
        count += int((hu > 0).sum())
    truth /= count
    untilted /= count
    with pytest.warns(UserWarning, match="gantry tilt of 20 degrees"):
        scene = ho.open(folder)
    a, m = scene.array, scene.affine
    z, y, x = np.nonzero(a > 0)
    points = (m @ np.stack([x, y, z, np.ones_like(x)]).astype(np.float64))[:3].T
    assert np.linalg.norm(points.mean(axis=0) - truth) < 0.5
    assert np.linalg.norm(centre - truth) < 0.6  # (the slices' own centroid is the ball's: the test's check of itself)
    assert np.linalg.norm(untilted - truth) > 8.0  # what ignoring the tilt would cost


def test_open_chooses_a_dicom_series_by_uid_or_by_one_of_its_images(tmp_path):
    """A folder holding two series: the larger by default (the warning says how to choose), the
    other by series= or by naming one of its images; a series= the image is not of is refused."""
    other = "1.2.826.0.1.3680043.8.498.303"
    hu = np.full((16, 16), -1000, np.int16)
    for k in range(6):
        write_ct_slice(tmp_path / f"A{k}", (0.0, 0.0, 2.0 * k), (1, 0, 0, 0, 1, 0), hu, 1.0, 0.0)
    for k in range(4):
        write_ct_slice(tmp_path / f"B{k}", (0.0, 0.0, 2.0 * k), (1, 0, 0, 0, 1, 0), hu, 1.0, 0.0, series=other)
    with pytest.warns(UserWarning, match=r"open\(series=\.\.\.\)"):
        assert ho.open(tmp_path).info()["dims"] == (16, 16, 6)
    assert ho.open(tmp_path, series=other).info()["dims"] == (16, 16, 4)
    assert ho.open(tmp_path / "B2").info()["dims"] == (16, 16, 4)
    with pytest.raises(ValueError, match="is an image of series '1.2.826.0.1.3680043.8.498.303'"):
        ho.open(tmp_path / "B2", series="1.2.826.0.1.3680043.8.498.302")
