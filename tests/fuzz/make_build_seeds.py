#!/usr/bin/env python3
"""Writes the seed corpus of fuzz_build (tests/fuzz/corpus/build/): one small valid input per kind
fuzz_build.cpp lays out, its 13-byte header first. DICOM slices are written byte by byte (explicit VR
little endian) with Rescale Slope and Intercept as 6-character DS values, so that a same-length
mutation ("1e308 ", "-1e39 ") keeps every element's length valid.
  python3 tests/fuzz/make_build_seeds.py [OUT_DIR]"""
import gzip
import io
import os
import struct
import sys
import tarfile

RAW, HEADER_FILE, DICOM, FIFO, DIRECTORY, SCENE = range(6)
INFO, ISO, RAW_FLAGS = 1, 2, 16
TYPES = ["uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"]
NAMES = ["v.raw", "v.nrrd", "v.mha", "v.nii", "v.hoct", "v.dcm", "series", "v.inv3"]
HEADER_FILES = ["v.nrrd", "v.mha", "v.nii", "v.nii.gz", "v.inv3"]


def header(kind, options=0, iso=0, dims=(1, 1, 1), type_name="uint8", big=False, header_bytes=0, choice=0, lengths=(0, 0)):
    raw = bytes([dims[0] - 1, dims[1] - 1, dims[2] - 1, TYPES.index(type_name), (header_bytes << 1) | int(big)])
    return bytes([kind, options, iso & 0xFF]) + raw + bytes([choice]) + struct.pack("<HH", *lengths)


def ball(dims, scale):
    """A blob bright at the volume's centre, so that an isovalue crosses it."""
    c = [(d - 1) / 2 for d in dims]
    return [int(scale * max(0.0, 3.0 - ((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) ** 0.5))
            for z in range(dims[2]) for y in range(dims[1]) for x in range(dims[0])]


# --- DICOM, explicit VR little endian ---------------------------------------------------------

def element(group, elem, vr, value):
    if isinstance(value, str):
        value = value.encode()
    if len(value) % 2:
        value += b"\0" if vr == "UI" else b" "
    if vr in ("OB", "OW", "SQ", "UN", "UT"):
        return struct.pack("<HH2sHI", group, elem, vr.encode(), 0, len(value)) + value
    return struct.pack("<HH2sH", group, elem, vr.encode(), len(value)) + value


def us(group, elem, v):
    return element(group, elem, "US", struct.pack("<H", v))


def dicom_slice(k, pixels, rows, columns, slope, intercept, full=True):
    """Slice k of a CT series: int16 pixels at z = 2.5 k mm; slope and intercept as written. A full
    slice has the 128-byte preamble, "DICM" and the usual identifiers; a compact one only what the
    reader needs (fewer bytes: a mutation lands on the rescale more often)."""
    assert len(slope) == 6 and len(intercept) == 6, "6-character DS values"
    sop = "1.2.3.4.5.%d" % (k + 1)
    meta = element(0x0002, 0x0010, "UI", "1.2.840.10008.1.2.1")
    if full:
        meta = element(0x0002, 0x0001, "OB", b"\0\1") + element(0x0002, 0x0002, "UI", "1.2.840.10008.5.1.4.1.1.2") + \
            element(0x0002, 0x0003, "UI", sop) + meta
        meta = element(0x0002, 0x0000, "UL", struct.pack("<I", len(meta))) + meta
    ids = element(0x0008, 0x0016, "UI", "1.2.840.10008.5.1.4.1.1.2") + element(0x0008, 0x0018, "UI", sop) + \
        element(0x0008, 0x0060, "CS", "CT") + element(0x0018, 0x0050, "DS", "2.5") + element(0x0020, 0x000D, "UI", "1.2.3.4")
    data = (ids if full else b"") + element(0x0020, 0x000E, "UI", "1.2.3.4.1") + \
        (element(0x0020, 0x0013, "IS", str(k + 1)) if full else b"") + element(0x0020, 0x0032, "DS", "0\\0\\%g" % (2.5 * k)) + \
        element(0x0020, 0x0037, "DS", "1\\0\\0\\0\\1\\0") + us(0x0028, 0x0002, 1) + element(0x0028, 0x0004, "CS", "MONOCHROME2") + \
        us(0x0028, 0x0010, rows) + us(0x0028, 0x0011, columns) + element(0x0028, 0x0030, "DS", "1\\1") + \
        us(0x0028, 0x0100, 16) + us(0x0028, 0x0101, 16) + us(0x0028, 0x0102, 15) + us(0x0028, 0x0103, 1) + \
        element(0x0028, 0x1052, "DS", intercept) + element(0x0028, 0x1053, "DS", slope) + \
        element(0x7FE0, 0x0010, "OW", struct.pack("<%dh" % len(pixels), *pixels))
    return (b"\0" * 128 + b"DICM" if full else b"") + meta + data


def dicom_series(count, rows, columns, slope, intercept, full, options=0, iso=0):
    dims = (columns, rows, count)
    values = ball(dims, 400)
    plane = rows * columns
    slices = [dicom_slice(k, values[k * plane:(k + 1) * plane], rows, columns, slope, intercept, full) for k in range(count)]
    lengths = (len(slices[0]), len(slices[1]) if count == 3 else 0)
    return header(DICOM, options, iso, choice=count - 2, lengths=lengths) + b"".join(slices)


# --- Files with headers -------------------------------------------------------------------------

def nrrd(dims, samples):
    text = "NRRD0004\ntype: short\ndimension: 3\nsizes: %d %d %d\nspace: LPS\n" \
           "space directions: (1,0,0) (0,1,0) (0,0,2)\nendian: little\nencoding: raw\n\n" % dims
    return text.encode() + struct.pack("<%dh" % len(samples), *samples)


def metaimage(dims, samples):
    text = "ObjectType = Image\nNDims = 3\nDimSize = %d %d %d\nElementType = MET_UCHAR\nElementSpacing = 1 1 2\n" \
           "TransformMatrix = 1 0 0 0 1 0 0 0 1\nOffset = 0 0 0\nElementDataFile = LOCAL\n" % dims
    return text.encode() + bytes(samples)


def nifti(dims, samples):
    """NIfTI-1, int16, qform and sform scaled by the spacing."""
    h = bytearray(348)
    struct.pack_into("<i", h, 0, 348)
    struct.pack_into("<8h", h, 40, 3, dims[0], dims[1], dims[2], 1, 1, 1, 1)
    struct.pack_into("<hh", h, 70, 4, 16)  # datatype int16, bitpix
    struct.pack_into("<8f", h, 76, 1, 1, 1, 2, 0, 0, 0, 0)  # pixdim
    struct.pack_into("<f", h, 108, 352)  # vox_offset
    struct.pack_into("<f", h, 112, 1)  # scl_slope
    struct.pack_into("<B", h, 123, 2)  # xyzt_units: mm
    struct.pack_into("<hh", h, 252, 1, 1)  # qform_code, sform_code
    struct.pack_into("<12f", h, 280, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 2, 0)  # srow_x, srow_y, srow_z
    h[344:348] = b"n+1\0"
    return bytes(h) + b"\0" * 4 + struct.pack("<%dh" % len(samples), *samples)


def inv3(dims, samples):
    plist = ("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<plist version=\"1.0\">\n<dict>\n"
             "<key>matrix</key><dict><key>dtype</key><string>int16</string><key>filename</key><string>matrix.dat</string>"
             "<key>shape</key><array><integer>%d</integer><integer>%d</integer><integer>%d</integer></array></dict>\n"
             "<key>modality</key><string>CT</string>\n"
             "<key>spacing</key><array><real>1</real><real>1</real><real>2</real></array>\n</dict>\n</plist>\n"
             % (dims[2], dims[1], dims[0])).encode()
    out = io.BytesIO()
    with gzip.GzipFile(fileobj=out, mode="wb", mtime=0) as gz, tarfile.open(fileobj=gz, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for name, data in (("proj/main.plist", plist), ("proj/matrix.dat", struct.pack("<%dh" % len(samples), *samples))):
            info = tarfile.TarInfo(name)
            info.size, info.mtime = len(data), 0
            tar.addfile(info, io.BytesIO(data))
    return out.getvalue()


def seeds(scene_seed):
    dims = (4, 3, 3)
    s16 = ball(dims, 300)
    nii_bytes = nifti(dims, s16)
    yield "raw_int16", header(RAW, ISO, 16, (4, 3, 2), "int16") + struct.pack("<24h", *ball((4, 3, 2), 300))
    yield "raw_uint8_header", header(RAW, INFO, dims=(5, 4, 3), header_bytes=8) + b"RAWHEAD!" + bytes(ball((5, 4, 3), 60))
    yield "raw_float32_big", header(RAW, 0, dims=(3, 3, 3), type_name="float32", big=True) + \
        struct.pack(">27f", *[v / 7.0 for v in ball((3, 3, 3), 70)])
    yield "nrrd", header(HEADER_FILE, ISO | 4, 16, choice=0) + nrrd(dims, s16)
    yield "mha", header(HEADER_FILE, INFO, choice=1) + metaimage(dims, ball(dims, 80))
    yield "nii", header(HEADER_FILE, ISO, 16, choice=2) + nii_bytes
    yield "nii_gz", header(HEADER_FILE, INFO, choice=3) + gzip.compress(nii_bytes, mtime=0)
    yield "inv3", header(HEADER_FILE, 0, choice=4) + inv3(dims, s16)
    # -512 = iso byte -64 x 8: the ball's HU cross it.
    yield "dicom2", dicom_series(2, 3, 4, "1.0000", "-1024 ", full=True, options=ISO, iso=-64)
    yield "dicom3", dicom_series(3, 3, 4, "1.0000", "-1024 ", full=False)
    yield "dicom3_info", dicom_series(3, 2, 2, "0.5000", "-1000 ", full=False, options=INFO)
    yield "fifo_raw_flags", header(FIFO, RAW_FLAGS, dims=(2, 2, 2), type_name="int16", choice=NAMES.index("v.raw"))
    yield "fifo_nrrd_info", header(FIFO, INFO, choice=NAMES.index("v.nrrd"))
    yield "directory_nrrd", header(DIRECTORY, 0, choice=NAMES.index("v.nrrd")) + dicom_slice(0, [0, 100, 200, 300], 2, 2, "1.0000", "0.0000")
    if scene_seed:
        yield "scene_info", header(SCENE, INFO) + scene_seed
        yield "scene_build", header(SCENE, 0) + scene_seed


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "corpus", "build")
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(here, "corpus", "scene", "sphere"), "rb") as f:  # fuzz_scene's seed: a 10^3 sphere's scene
        scene = f.read()
    for name, data in seeds(scene):
        with open(os.path.join(out, name), "wb") as f:
            f.write(data)


if __name__ == "__main__":
    main()
