// Mesh checks with CGAL (the only translation unit that includes CGAL; STYLE 6).
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>

#include "surface/mesh.h"
#include "volume/progress.h"

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

}  // namespace hyb
