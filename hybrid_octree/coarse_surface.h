// The isosurface at a frame's level of detail, made out of core: the full-resolution Marching Cubes
// surface (Lorensen and Cline, SIGGRAPH '87) is streamed block by block from the samples and each
// of its vertices clustered into the cube of s voxels holding it (Rossignac and Borrel's vertex
// clustering, out of core as Lindstrom, "Out-of-core simplification of large polygonal models",
// SIGGRAPH 2000): a cluster becomes one vertex, a triangle whose corners fall in three clusters
// one triangle. The result has about 1/s² of the full surface's triangles and holds only those;
// the full surface is never made. Thin structures survive (a sheet thinner than s collapses onto
// itself rather than breaking into holes, as Marching Cubes of the knots s voxels apart would);
// the error is at most a cube's diagonal (docs/surface.md, "The surface at a frame's level of
// detail").
#pragma once

#include "hybrid_octree/knot_source.h"
#include "hybrid_octree/volume_octree.h"
#include "surface/mesh.h"
#include "volume/core/progress.h"

namespace hyb {

/// Cells a side of the blocks clusteredSurface reads and triangulates at a time.
inline constexpr int kClusterBlockCells = 32;

/// The isosurface of @p iso of @p knots' samples (spacing 1; a corner inside where its sample is
/// ≥ iso, the face-consistent loops of surface/dmc_table.h), its vertices clustered by the cubes
/// of @p s voxels ({s·c … s·c + s} per axis, c ≥ 0): each cluster's vertex is the mean of its
/// vertices weighted by the area around them, its normal the samples' gradient summed where it
/// agrees, else the principal axis of its outer products (a sheet's two faces add up), the signs
/// then made to agree from vertex to vertex, and where a triangle's corners still oppose (a
/// crease, two surfaces a cube apart) the corners on the far side of its plane drawn from a copy
/// of their vertex with the normal turned (shading is two-sided, but opposed corners would
/// interpolate through zero). Triangles of three clusters
/// are kept once per orientation (a collapsed sheet keeps both, as the full surface draws both of
/// its faces). Grid frame, mm, with per-vertex normals. @p octree (of the same grid) skips the
/// blocks of @p blockCells cells a side whose samples do not straddle @p iso. Deterministic: the
/// same mesh whatever the thread count (and the block size, but for the sums' rounding); its
/// vertices in the order of their cubes, x fastest, then the turned copies.
/// @throw IoError as KnotSource::read; what @p progress throws ("coarse surface").
TriangleMesh clusteredSurface(const KnotSource& knots, const VolumeOctree& octree, int s, float iso, const Progress* progress = nullptr,
                              int blockCells = kClusterBlockCells);

/// Marching Cubes of @p knots' knots @p s voxels apart (prefiltered from 4 on: KnotSource::read), in
/// the grid frame, mm, with the knots' gradients as normals: a first look at the isosurface of
/// @p iso in a small fraction of clusteredSurface's time (it reads 1/s³ of the samples and
/// triangulates as many cells), where a sheet thinner than s may break into holes.
/// @throw IoError as KnotSource::read.
TriangleMesh knotSurface(const KnotSource& knots, int s, float iso);

/// The coarsest cluster edge (a power of two, 1 … @p maxSpacing) whose cubes are at most
/// @p pixelMm wide along every axis, voxels being @p spacing mm: along the longest, so that on
/// anisotropic data no cube is wider than asked (a brick's texels, SelectionParams::lodPixels, go
/// by the shortest). 1 when @p pixelMm is below two of the longest voxel edges or not positive.
int clusterSpacingFor(double pixelMm, const glm::dvec3& spacing, int maxSpacing);

}  // namespace hyb
