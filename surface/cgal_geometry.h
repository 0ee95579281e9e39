// Mesh checks with CGAL (the only translation unit that includes CGAL; STYLE 6).
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>

#include "surface/mesh.h"
#include "volume/core/progress.h"

namespace hyb {

/// Topology and geometry of a triangle mesh.
struct MeshCheck {
  bool manifold = false;          ///< every edge has one or two faces, every vertex one fan
  bool closed = false;            ///< manifold and without boundary edges
  bool selfIntersecting = false;  ///< two non-adjacent triangles intersect (exact predicates; manifold meshes only)
  bool outward = false;           ///< closed and normals point out of the enclosed volume
  size_t boundaryEdges = 0;       ///< edges with one face
  double volume = 0;              ///< enclosed volume (closed meshes), in the mesh's units³
};

/// Checks @p mesh with exact predicates. Manifold is CGAL's polygon mesh: no triangle repeats a
/// vertex, no directed edge is in two triangles, and each vertex's triangles make one fan.
/// Self-intersections are CGAL's does_self_intersect's (a triangle without area counts as one),
/// found on all cores.
/// @throw RuntimeError when CGAL fails.
MeshCheck checkMesh(const TriangleMesh& mesh);

/// The symmetric Hausdorff distance, bracketed: a point of one mesh lies @c lower from the other,
/// and no point lies farther than @c upper ≤ lower + the error bound.
struct HausdorffBracket {
  double lower = 0.0;
  double upper = 0.0;
};

/// Symmetric Hausdorff distance between @p a and @p b within @p errorBound > 0, in the meshes'
/// units: bounded-error, as Sieger et al.'s algorithm in CGAL, on all cores (closest points from
/// CGAL's AABB tree; see cgal_geometry.cpp). The work is bounded by @p maxSplits triangle
/// bisections (one closest-point query each; ~35 M a minute on two cores): past it the bracket is still
/// true but may be wider than the bound. Zero for two empty meshes, infinite when only one is
/// empty. Any triangle soup is measured as it is (non-manifold MC, degenerate triangles).
/// @p progress hears of the triangles settled ("Hausdorff distance").
/// @throw ValueError when the bound is not positive.
HausdorffBracket hausdorffDistance(const TriangleMesh& a, const TriangleMesh& b, double errorBound,
                                   uint64_t maxSplits = std::numeric_limits<uint64_t>::max(), const Progress* progress = nullptr);

/// How densely sampledHausdorffDistance samples, as the patch it must not miss and how sure.
struct SampledHausdorffOptions {
  double patchRadius = 1.0;   ///< the patch: a disc of this radius, in the meshes' units (area π r²)
  double confidence = 0.999;  ///< in (0, 1): the probability that no such patch is missed on either mesh
  uint64_t seed = 1;          ///< the samples' pseudo-random stream
};

/// The symmetric Hausdorff distance H, measured on points: what is exact and what is sampled.
struct SampledHausdorff {
  double lower = 0.0;       ///< exact: a point of one mesh lies this far from the other (the farthest of every vertex and sample), H ≥ lower
  double upper = 0.0;       ///< exact: H ≤ upper (each triangle bounded from its corners', no subdivision; may be wide)
  uint64_t samples = 0;     ///< the points measured besides the vertices, both meshes
  double patchArea = 0.0;   ///< sampled: with probability @c confidence, less than this area of either mesh lies farther than @c lower from the other
  double confidence = 0.0;  ///< the options'
};

/// Symmetric Hausdorff distance between @p a and @p b at a cost that follows the meshes' area, not
/// their shape, on all cores: every vertex's exact distance to the other mesh (where it might be
/// the farthest), each triangle's exact bound from its corners' (hausdorffDistance's, without
/// splits), and on each mesh a Poisson process of ln(2 / (1 − confidence)) / patchArea points per
/// unit area (uniform by area, independent in disjoint regions). A region of area A is then missed
/// with probability exp(−A · density), at most (1 − confidence) / 2 for A ≥ patchArea: the part of
/// a mesh farther than the largest measured distance is smaller than patchArea unless one of the
/// two sides missed a patch (see cgal_geometry.cpp). The same meshes and options give the same
/// result on any number of threads. Zero for two empty meshes, infinite when only one is empty.
/// @p progress hears of the triangles done ("Hausdorff distance").
/// @throw ValueError when the radius is not positive and finite, the confidence not in (0, 1), or a
/// vertex not finite.
SampledHausdorff sampledHausdorffDistance(const TriangleMesh& a, const TriangleMesh& b, const SampledHausdorffOptions& options,
                                          const Progress* progress = nullptr);

}  // namespace hyb
