// Mesh types of the surface module: plain arrays in and out (meshoptimizer style).
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <vector>

#include "surface/discrete_plane.h"

namespace hyb {

/// Polygon mesh with exact vertices in doubled voxel coordinates (X = 2·voxel index), as produced by
/// Discretized Marching Cubes and the Surface Octree. Faces are counter-clockwise seen from outside
/// the solid (the side of samples ≥ the isovalue).
struct DiscreteMesh {
  std::vector<glm::ivec3> vertices;
  std::vector<uint32_t> offsets{0};  ///< face f uses indices[offsets[f] .. offsets[f+1])
  std::vector<uint32_t> indices;
  std::vector<PlaneId> planes;       ///< plane of each face

  size_t faceCount() const { return offsets.size() - 1; }
  size_t faceSize(size_t f) const { return offsets[f + 1] - offsets[f]; }
  /// Triangles a triangulation of every (simple) face gives: sum of (size − 2).
  size_t triangleCount() const {
    size_t n = 0;
    for (size_t f = 0; f < faceCount(); ++f) n += faceSize(f) - 2;
    return n;
  }
  void addFace(const uint32_t* v, size_t n, const PlaneId& plane) {
    indices.insert(indices.end(), v, v + n);
    offsets.push_back(uint32_t(indices.size()));
    planes.push_back(plane);
  }
};

/// Triangle mesh with float vertices, used for export, checks and rendering.
struct TriangleMesh {
  std::vector<glm::vec3> vertices;
  std::vector<glm::uvec3> triangles;
  /// Per-vertex shading normals (unit, outward), or empty: shade each triangle by its own plane.
  std::vector<glm::vec3> normals;
  /// When the triangles come from planar polygons (a triangulated DiscreteMesh): polygon f's
  /// triangles are [polygonStarts[f], polygonStarts[f + 1]). Empty: nothing is known of polygons.
  std::vector<uint32_t> polygonStarts;
  /// Bytes its arrays hold.
  size_t bytesUsed() const {
    return sizeof(glm::vec3) * (vertices.capacity() + normals.capacity()) + sizeof(glm::uvec3) * triangles.capacity() +
           sizeof(uint32_t) * polygonStarts.capacity();
  }
};

/// A box of samples [lo, hi] (voxel indices, inclusive) whose cells an extraction visits.
struct VoxelBlock {
  glm::ivec3 lo{0};
  glm::ivec3 hi{0};
};

}  // namespace hyb
