// Bounding-volume hierarchy over a triangle mesh, for exact ray-triangle hits in the ray caster.
#pragma once

#include <glm/glm.hpp>

#include <vector>

#include "surface/mesh.h"

namespace hyb {

/// A ray hit: distance along the (unit) ray and the shading normal: the mesh's vertex normals
/// interpolated at the hit, or the triangle's own when the mesh has none.
struct Hit {
  double t;
  glm::dvec3 normal;
};

class Bvh {
 public:
  Bvh() = default;
  /// Builds over @p mesh (world millimetres); the mesh must outlive the BVH.
  explicit Bvh(const TriangleMesh& mesh);
  /// All hits with tMin < t < tMax, sorted by t; hits at the same distance (a ray through a shared
  /// edge or vertex) are counted once.
  void allHits(const glm::dvec3& origin, const glm::dvec3& dir, double tMin, double tMax, std::vector<Hit>* hits) const;
  bool empty() const { return mNodes.empty(); }

 private:
  struct Node {
    glm::vec3 lo, hi;
    uint32_t first, count;  // leaf: triangles [first, first + count); inner: count = 0, children first, first + 1
  };
  const TriangleMesh* mMesh = nullptr;
  std::vector<Node> mNodes;
  std::vector<uint32_t> mTriangles;
};

}  // namespace hyb
