// Simplification of an isosurface for the viewer's frames before the final one: fewer triangles, each
// still inside one block of a regular grid, so that a renderer that places every triangle in the
// brick holding it (the slice renderer's SlabPolygon lists) draws the simplified surface in the
// right order as it does the exact one. meshoptimizer (Kapoulkine) does the edge collapses.
#pragma once

#include "surface/mesh.h"
#include "volume/core/progress.h"

namespace hyb {

/// Simplifies @p mesh (grid-frame mm, welded: triangles share their vertices) block by block:
/// the triangles whose centroid lies in one cube of @p blockMm (mm per axis) are simplified
/// together, the vertices where the surface leaves the block kept, so each output triangle lies
/// inside the block its input triangles did. Collapses stop where the surface would move by more
/// than @p maxErrorMm (meshoptimizer's quadric distance). Every edge is used by as many triangles
/// as in the input (no edge of a closed surface opens, nothing is stacked or folded onto a
/// neighbour's face; a vertex may still be left between two fans, docs/surface.md):
/// where a collapse broke that, the vertices concerned are kept and the block is simplified again
/// (but a triangle and its mirror image, made by two blocks over their common border, are dropped).
/// No output triangle is flat (flatTriangle) where the input had none: where a collapse made one,
/// its vertices are kept and the block simplified again. Self-intersections are not prevented.
/// Vertices keep their input positions (a collapse moves one onto another); normals are not set
/// (the caller sets them, e.g. setGradientNormals) and the polygon structure is dropped.
/// @p progress hears of the blocks done ("simplified surface").
/// @throw ValueError if blockMm or maxErrorMm is not positive and finite.
/// At most what the simplified levels of a surface (SceneRenderer::simplifiedLevels) hold while
/// they are made, per input triangle: 62 bytes measured on the clinical study's bone
/// (docs/scale.md), with a margin.
inline constexpr uint64_t kSimplifyBytesPerTriangle = 80;

/// What simplifyWithinBlocks did beyond one pass over the blocks.
struct SimplifyStats {
  size_t blocks = 0;          ///< blocks with triangles
  size_t blocksRedone = 0;    ///< simplifications of a block after the first, summed over the rounds
  size_t mirroredPairs = 0;   ///< triangle pairs dropped as mirror images over a common border
  size_t pairsRestored = 0;   ///< dropped pairs given back to a block that stayed, its neighbour being done again
};
TriangleMesh simplifyWithinBlocks(const TriangleMesh& mesh, const glm::dvec3& blockMm, double maxErrorMm, const Progress* progress = nullptr,
                                  SimplifyStats* stats = nullptr);

}  // namespace hyb
