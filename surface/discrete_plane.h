// Discrete planes of Discretized Marching Cubes: the 13 orientations and exact plane ids in doubled
// integer coordinates (X = 2 · voxel index, so edge midpoints are integer points).
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <cstddef>
#include <cstdint>

namespace hyb {

/// Exact integer dot and cross products (GLM's are floating-point only).
inline int idot(const glm::ivec3& a, const glm::ivec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline glm::ivec3 icross(const glm::ivec3& a, const glm::ivec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}

/// Number of plane orientations: 3 axis, 6 face-diagonal, 4 body-diagonal.
inline constexpr int kOrientationCount = 13;

/// Canonical normal of orientation @p o (first non-zero component positive).
inline const glm::ivec3& orientationNormal(int o) {
  static constexpr std::array<glm::ivec3, kOrientationCount> kNormals = {{
      {1, 0, 0}, {0, 1, 0}, {0, 0, 1},                                  // axis
      {1, 1, 0}, {1, -1, 0}, {1, 0, 1}, {1, 0, -1}, {0, 1, 1}, {0, 1, -1},  // face diagonals
      {1, 1, 1}, {1, 1, -1}, {1, -1, 1}, {1, -1, -1}}};                  // body diagonals
  return kNormals[size_t(o)];
}

/// Orientation of the integer direction @p n after removing its gcd, with the sign that maps the
/// canonical normal onto it; -1 when @p n is zero or not one of the 13 orientations.
int orientationOf(const glm::ivec3& n, int* sign);

/// A plane n·X = d in doubled coordinates with n = sign · orientationNormal(orientation).
/// The normal points out of the solid, so planes with opposite facing are different ids.
struct PlaneId {
  int8_t orientation = 0;
  int8_t sign = 1;
  int32_t d = 0;

  glm::ivec3 normal() const { return orientationNormal(orientation) * int(sign); }
  /// The same plane after translating everything by @p offset (doubled coordinates).
  PlaneId translated(const glm::ivec3& offset) const {
    return PlaneId{orientation, sign, d + idot(normal(), offset)};
  }
  /// Signed value n·X − d (0 on the plane, > 0 outside the solid's side).
  int64_t eval(const glm::ivec3& x) const {
    const glm::ivec3 n = normal();
    return int64_t(n.x) * x.x + int64_t(n.y) * x.y + int64_t(n.z) * x.z - d;
  }
  /// Total order and 64-bit key for hashing.
  uint64_t key() const { return (uint64_t(uint32_t(d)) << 8) | (uint64_t(orientation) << 1) | (sign > 0 ? 1u : 0u); }
  friend bool operator==(const PlaneId& a, const PlaneId& b) {
    return a.orientation == b.orientation && a.sign == b.sign && a.d == b.d;
  }
  friend bool operator<(const PlaneId& a, const PlaneId& b) { return a.key() < b.key(); }
};

}  // namespace hyb
