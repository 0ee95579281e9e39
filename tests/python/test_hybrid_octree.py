"""The Python module against the command line: the same images and meshes from a numpy array as
from the same samples in a file, arrays kept without copies, and bad input refused by name.

Run by the test command (ctest) with PYTHONPATH=BUILD/python and HYB_BIN=BUILD/hybrid-octree.
"""
import os
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
    mine = tmp_path / "mine.png"
    write_png(mine, over_black(image))
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
    assert psnr_to_cli(tmp_path, image, tmp_path / "cli.png") >= 45.0
    # The same file opened by the module: the same image.
    assert psnr_to_cli(tmp_path, ho.open(str(path)).render(**kwargs), tmp_path / "cli.png") >= 45.0


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
    # Types the readers widen are converted as they convert them: int32 within 16 bits to int16.
    assert ho.Scene(blobs(np.int32)).info()["stored_type"] == "int16"
    assert ho.Scene(blobs(np.float64)).info()["stored_type"] == "float32"


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
        (lambda: ho.Scene(np.zeros((4, 4, 4), np.int16), spacing="abc"), TypeError, "spacing must be three numbers"),
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
    with pytest.raises(TypeError, match="unexpected keyword argument 'colour'"):
        scene.render(colour=1)
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
