// Mesh checks with CGAL (the only translation unit that includes CGAL; STYLE 6).
#pragma once

#include <cstddef>

#include "surface/mesh.h"

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

/// Checks @p mesh with exact predicates.
/// @throw RuntimeError when CGAL fails.
MeshCheck checkMesh(const TriangleMesh& mesh);

/// Symmetric Hausdorff distance between @p a and @p b, within @p errorBound (CGAL's bounded-error
/// algorithm), in the meshes' units. Zero for two empty meshes, infinite when only one is empty.
/// Non-manifold soups (classic MC) are measured as they are.
double hausdorffDistance(const TriangleMesh& a, const TriangleMesh& b, double errorBound);

}  // namespace hyb
