"""hybrid-octree: CT volumes with embedded isosurfaces, rendered and meshed.

Arrays are indexed (z, y, x) and C-contiguous, as numpy, SimpleITK's GetArrayFromImage and
nibabel's (transposed) data give them. Coordinates are patient millimetres in LPS (x towards the
patient's left, y posterior, z superior), as ITK, 3D Slicer and DICOM define them: voxel (i, j, k)
lies at origin + direction @ (i*sx, j*sy, k*sz).
"""

import os
from typing import Any, Literal, Sequence, overload

import numpy as np
import numpy.typing as npt

# The forms a keyword takes: the command line's text of the flag (a str), or the Python values that
# spell it. Numbers: a tuple, list or 1-D numpy array ("a,b,c"); Number: an int, float, numpy scalar
# or 0-d array; a size: two integers ("WxH"); Switch: True/False ("on"/"off"). A value of none of
# its forms raises TypeError naming the keyword; a value its flag refuses raises ValueError with the
# command line's message. None is a keyword left out.
Numbers = Sequence[float] | npt.NDArray[Any] | str
Vec3 = Numbers  # three of them
Number = float | np.number[Any] | npt.NDArray[Any] | str
Integer = int | np.integer[Any] | npt.NDArray[Any] | str
Switch = bool | np.bool_ | Literal["on", "off"]
Flag = bool | np.bool_
Path = str | os.PathLike[str]

class Scene:
    def __init__(
        self,
        array: npt.NDArray[Any],
        spacing: Vec3 | None = None,
        origin: Vec3 | None = None,
        direction: npt.ArrayLike | None = None,
        iso: Number | None = None,
    ) -> None:
        """A scene over a 3-D numpy array indexed (z, y, x). uint8, int8, uint16, int16 and float32
        samples are used in place (the scene keeps the array alive; do not modify it). uint32, int32
        and float64 are copied into the smallest of uint8, int16 and uint16 that holds every value
        exactly (whole numbers: a CT's float64 from nibabel's get_fdata() is held as int16), else
        float32; the array is not kept. NaN, infinity or a value beyond float32's range is refused
        (ValueError naming the sample). spacing: (sx, sy, sz) mm (default 1); origin: LPS mm of voxel
        (0, 0, 0); direction: 3x3 whose columns are the x, y and z axes in LPS (SimpleITK's
        GetDirection() reshaped to 3x3). iso: build that isosurface now. ValueError or TypeError name
        what was expected."""
    @property
    def array(self) -> npt.NDArray[Any]:
        """The samples indexed (z, y, x) in their stored type, read-only: a view without a copy of the
        scene's own samples where it holds them (an array given to Scene, a volume file, a DICOM folder
        after any resampling), a copy read from its store for a scene file read paged."""
    @property
    def affine(self) -> npt.NDArray[np.float64]:
        """4x4: voxel index (x, y, z), the array's axes reversed, to LPS mm (origin + direction @
        (x*sx, y*sy, z*sz)), the frame of ITK and of `hybrid-octree info`. nibabel's RAS affine of the
        same grid is np.diag([-1, -1, 1, 1]) @ affine."""
    def info(self, bins: Integer = 24) -> dict[str, Any]:
        """What `hybrid-octree info` prints: dims (x, y, z), shape (z, y, x), spacing, type,
        stored_type, min, max, origin, direction (rows), orientation, bytes, octree_nodes, the
        surfaces built, the text, and the histogram (counts in `bins` equal bins, min, max, mean,
        stddev, p01, p50, p99)."""
    @overload
    def render(self, *, stats: Literal[False] = ..., **options: Any) -> npt.NDArray[np.uint8]: ...
    @overload
    def render(self, *, stats: Literal[True], **options: Any) -> tuple[npt.NDArray[np.uint8], dict[str, Any]]: ...
    def render(
        self,
        *,
        view: str = ...,
        orbit: Numbers = ...,
        eye: Vec3 = ...,
        center: Vec3 = ...,
        up: Vec3 = ...,
        zoom: Number = ...,
        fov: Number = ...,
        ortho: Flag = ...,
        ortho_height: Number = ...,
        size: tuple[int, int] | npt.NDArray[np.integer[Any]] | str = ...,
        camera_file: Path = ...,
        marker: Switch = ...,
        preset: str = ...,
        tf: npt.ArrayLike | Path = ...,
        opacity: Number = ...,
        iso: Number = ...,
        surface_color: Numbers = ...,
        surface_normals: Literal["gradient", "facet"] = ...,
        shading: Switch = ...,
        background: Numbers = ...,
        cut: Numbers = ...,
        cut_line: Switch = ...,
        voi: Numbers = ...,
        voi_inside: Number = ...,
        voi_outside: Number = ...,
        voi_ramp: Number = ...,
        mesh: Path = ...,
        primitive: str = ...,
        mesh_method: Literal["polygons", "scan-convert"] = ...,
        mesh_filter: Literal["box", "box1.5", "box2", "none"] = ...,
        mesh_space: Literal["lps", "ras"] = ...,
        meshes: list[tuple[npt.ArrayLike, npt.ArrayLike, Numbers]] = ...,
        renderer: Literal["slices", "raycast"] = ...,
        epsilon: Number = ...,
        budget: Number | str = ...,
        step: Number = ...,
        classification: Literal["post", "preintegrated"] = ...,
        proxy: Literal["planes", "shells"] = ...,
        blend: Switch = ...,
        lod_pixels: Number = ...,
        max_brick: Integer = ...,
        texel_bits: Integer = ...,
        focus: Vec3 = ...,
        image_scale: Number = ...,
        premultiplied: Flag = False,
        stats: Flag = False,
        **more: Any,
    ) -> Any:
        """An (H, W, 4) uint8 image; with stats=True, (image, the frame's statistics: the keys of
        `--stats` but the command's own times). By default the
        image is straight alpha over transparent (premultiplied=True: premultiplied), so
        matplotlib's imshow shows it over white; background=(r, g, b) composites it over that colour
        as the command line's PNG does (alpha 255, the PNG's bytes). Keywords are `hybrid-octree
        render`'s flags (--surface-color is surface_color), in the forms above, checked by the same
        code: a wrong value raises ValueError with the command line's message, an unknown keyword
        or a wrong type TypeError. tf: an (N, 5) array of control points (value, r, g, b, opacity
        per mm) or a transfer-function file. mesh: mesh files "FILE[:r,g,b,a]" separated by ';';
        meshes: meshes given as arrays, each (vertices (N, 3) in patient mm (LPS), faces (M, 3)
        indices, rgba), drawn after mesh's. The engine is kept between calls (brick textures,
        surfaces), and the GIL is released while rendering; Ctrl+C (KeyboardInterrupt) stops a
        frame."""
    @overload
    def surface(self, iso: Number, kind: Literal["octree", "dmc", "mc"] = "octree", closed: Flag = False, normals: Literal[False] = False) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]: ...
    @overload
    def surface(self, iso: Number, kind: Literal["octree", "dmc", "mc"], closed: Flag, normals: Literal[True]) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int64], npt.NDArray[np.float32]]: ...
    def surface(self, iso: Number, kind: str = "octree", closed: Flag = False, normals: Flag = False) -> tuple[Any, ...]:
        """The isosurface as `hybrid-octree export` makes it: vertices (N, 3) float32 in patient mm
        (LPS), faces (M, 3) int64, and (normals=True) unit vertex normals (N, 3). kind: octree (the
        Surface Octree's, coplanar polygons merged), dmc (Discretized Marching Cubes) or mc (classic);
        closed caps it where it meets the volume's faces."""
    def export(self, path: Path, iso: Number, kind: str = "dmc", closed: Flag = False, normals: Flag = False) -> None:
        """Writes the isosurface as `hybrid-octree export` does (.ply, .obj, .stl or .off; LPS mm)."""

def open(path: Path, series: str | None = None) -> Scene:
    """A scene from any file the command line reads: NRRD, MetaImage, NIfTI, InVesalius .inv3, a
    DICOM directory, a CD's DICOMDIR or one image of a series, or a scene file (.hoct, its samples
    loaded). series: a DICOM folder's Series Instance UID (the command line's --series); None, the
    largest axial series that is not a localizer."""

def frame_fields() -> list[dict[str, Any]]:
    """render()'s keywords as the one table of a frame's settings holds them (the command line's
    flags, the viewer's fields): name, kind, min, max, default, unit, help, choices."""
