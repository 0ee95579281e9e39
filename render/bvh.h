// Every ray–triangle crossing of a mesh, for the reference ray tracer's surface: Embree's BVH
// (Intel, Debian's libembree-dev 3.13) finds the triangles a ray crosses; each crossing is then
// measured in double precision. Embree appears only in render/bvh.cpp.
#pragma once

#include <glm/glm.hpp>

#include <optional>
#include <vector>

#include "surface/mesh.h"

struct RTCSceneTy;

namespace hyb {

/// A ray hit: distance along the (unit) ray, the shading normal (the mesh's vertex normals
/// interpolated at the hit, or the triangle's own when the mesh has none) and the mesh crossed
/// (its place among the meshes the BVH was built over).
struct Hit {
  double t;
  glm::dvec3 normal;
  uint32_t part = 0;
};

class Bvh {
 public:
  Bvh() = default;
  /// Builds over @p mesh (world millimetres, finite); the mesh must outlive the BVH.
  /// @throw RuntimeError when Embree cannot build it (out of memory).
  explicit Bvh(const TriangleMesh& mesh) : Bvh(std::vector<const TriangleMesh*>{&mesh}) {}
  /// Builds over the triangles of @p meshes (each one's hits carry its place as Hit::part).
  explicit Bvh(const std::vector<const TriangleMesh*>& meshes);
  ~Bvh();
  Bvh(const Bvh&) = delete;
  Bvh& operator=(const Bvh&) = delete;
  /// All hits with tMin < t < tMax, sorted by t; hits at the same distance (a ray through a shared
  /// edge or vertex of one mesh) are counted once. Thread-safe.
  void allHits(const glm::dvec3& origin, const glm::dvec3& dir, double tMin, double tMax, std::vector<Hit>* hits) const;
  /// The hit of allHits with the smallest t (then the lowest part), or none, its t, u and v in
  /// Embree's float precision (a few 1e-5 mm on a head): Embree's traversal leaves out what lies
  /// beyond the nearest found so far, so a ray that needs only its first few crossings (one
  /// stopped once opaque) costs less than with all of them. Thread-safe.
  std::optional<Hit> firstHit(const glm::dvec3& origin, const glm::dvec3& dir, double tMin, double tMax) const;
  bool empty() const { return mScene == nullptr; }

 private:
  std::vector<const TriangleMesh*> mMeshes;
  RTCSceneTy* mScene = nullptr;
};

}  // namespace hyb
