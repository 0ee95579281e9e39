"""hybrid-octree: CT volumes with embedded isosurfaces, rendered and meshed.

Arrays are indexed (z, y, x) and C-contiguous, as numpy, SimpleITK's GetArrayFromImage and
nibabel's (transposed) data give them. Coordinates are patient millimetres in LPS (x towards the
patient's left, y posterior, z superior), as ITK, 3D Slicer and DICOM define them: voxel (i, j, k)
lies at origin + direction @ (i*sx, j*sy, k*sz).
"""

from typing import Any, Literal, Sequence, overload

import numpy as np
import numpy.typing as npt

Vec3 = Sequence[float]

class Scene:
    def __init__(
        self,
        array: npt.NDArray[Any],
        spacing: Vec3 | None = None,
        origin: Vec3 | None = None,
        direction: npt.ArrayLike | None = None,
        iso: float | None = None,
    ) -> None:
        """A scene over a 3-D array indexed (z, y, x): uint8, int8, uint16, int16 and float32 samples
        are used in place (the scene keeps the array alive; do not modify it), uint32, int32 and
        float64 are converted as the readers convert them (into 16 bits when the values fit, else
        float32). spacing: (sx, sy, sz) mm (default 1); origin: LPS mm of voxel (0, 0, 0); direction:
        3x3 whose columns are the x, y and z axes in LPS (SimpleITK's GetDirection() reshaped to 3x3).
        iso: build that isosurface now. ValueError or TypeError name what was expected."""
    def info(self, bins: int = 24) -> dict[str, Any]:
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
        orbit: Sequence[float] = ...,
        eye: Vec3 = ...,
        center: Vec3 = ...,
        up: Vec3 = ...,
        zoom: float = ...,
        fov: float = ...,
        ortho: bool = ...,
        size: tuple[int, int] = ...,
        preset: str = ...,
        tf: npt.ArrayLike = ...,
        iso: float = ...,
        surface_color: Sequence[float] = ...,
        surface_normals: Literal["gradient", "facet"] = ...,
        shading: bool = ...,
        cut: Sequence[float] = ...,
        cut_line: bool = ...,
        voi: Sequence[float] = ...,
        renderer: Literal["slices", "raycast"] = ...,
        epsilon: float = ...,
        budget: float | str = ...,
        step: float = ...,
        classification: Literal["post", "preintegrated"] = ...,
        lod_pixels: float = ...,
        image_scale: float = ...,
        max_brick: int = ...,
        premultiplied: bool = False,
        stats: bool = False,
        **more: Any,
    ) -> Any:
        """An (H, W, 4) uint8 image, straight alpha over transparent (premultiplied on request);
        with stats=True, (image, the frame's statistics). Keywords are `hybrid-octree render`'s
        flags (--surface-color is surface_color; sequences are given as tuples), checked by the same
        code: a bad one raises ValueError with the command line's message, an unknown one TypeError.
        tf: an (N, 5) array of control points (value, r, g, b, opacity per mm). The engine is kept
        between calls (brick textures, surfaces), and the GIL is released while rendering;
        Ctrl+C (KeyboardInterrupt) stops a frame."""
    @overload
    def surface(self, iso: float, kind: Literal["octree", "dmc", "mc"] = "octree", closed: bool = False, normals: Literal[False] = False) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int64]]: ...
    @overload
    def surface(self, iso: float, kind: Literal["octree", "dmc", "mc"], closed: bool, normals: Literal[True]) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int64], npt.NDArray[np.float32]]: ...
    def surface(self, iso: float, kind: str = "octree", closed: bool = False, normals: bool = False) -> tuple[Any, ...]:
        """The isosurface as `hybrid-octree export` makes it: vertices (N, 3) float32 in patient mm
        (LPS), faces (M, 3) int64, and (normals=True) unit vertex normals (N, 3). kind: octree (the
        Surface Octree's, coplanar polygons merged), dmc (Discretized Marching Cubes) or mc (classic);
        closed caps it where it meets the volume's faces."""
    def export(self, path: str, iso: float, kind: str = "dmc", closed: bool = False, normals: bool = False) -> None:
        """Writes the isosurface as `hybrid-octree export` does (.ply, .obj, .stl or .off; LPS mm)."""

def open(path: str) -> Scene:
    """A scene from any file the command line reads: NRRD, MetaImage, NIfTI, InVesalius .inv3, a
    DICOM directory, or a scene file (.hoct, its samples loaded)."""
