// Exact arithmetic of discrete planes and node boxes in the Surface Octree's fine coordinates (12 ×
// the doubled grid: every vertex of an arrangement of discrete planes and box faces is an integer
// there), shared by the merge (surface_octree.cpp) and the reconstruction
// (surface_octree_reconstruct.cpp). Internal to hybrid_octree/.
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <cstdint>

#include "hybrid_octree/surface_octree.h"
#include "surface/discrete_plane.h"
#include "volume/core/error.h"

namespace hyb::detail {

using I64 = int64_t;
using V64 = glm::i64vec3;
constexpr int kFine = 12;  // fine units per doubled unit

// A plane n·X = d in doubled coordinates (n from the 13 orientations or an axis).
struct Plane {
  glm::ivec3 n;
  I64 d;
};

inline Plane toPlane(const GeoPlane& g) { return {orientationNormal(g.orientation), g.d}; }

inline I64 dot64(const glm::ivec3& n, const V64& p) { return I64(n.x) * p.x + I64(n.y) * p.y + I64(n.z) * p.z; }

// Sign of plane @p at the fine point p / scale.
inline int sideOf(const Plane& pl, const V64& p, I64 scale) {
  const I64 v = dot64(pl.n, p) - I64(kFine) * scale * pl.d;
  return (v > 0) - (v < 0);
}

// Exact intersection of three planes in fine coordinates; false when they do not meet in a point.
inline bool intersect3(const Plane& a, const Plane& b, const Plane& c, V64* out) {
  const glm::ivec3 bc = icross(b.n, c.n), ca = icross(c.n, a.n), ab = icross(a.n, b.n);
  const I64 det = idot(a.n, bc);
  if (det == 0) return false;
  // |det| <= 4 for the 13 orientations and the axes, so kFine / det is exact.
  static constexpr std::array<I64, 9> kScale{-kFine / 4, -kFine / 3, -kFine / 2, -kFine, 0, kFine, kFine / 2, kFine / 3, kFine / 4};
  HYB_CHECK(det >= -4 && det <= 4);
  const V64 num = V64(bc) * a.d + V64(ca) * b.d + V64(ab) * c.d;
  *out = num * kScale[size_t(det + 4)];
  return true;
}

inline I64 orient3(const V64& a, const V64& b, const V64& c, const V64& d) {
  const V64 u = b - a, v = c - a, w = d - a;
  return u.x * (v.y * w.z - v.z * w.y) - u.y * (v.x * w.z - v.z * w.x) + u.z * (v.x * w.y - v.y * w.x);
}

// Axis-aligned box [lo, hi] in doubled coordinates.
struct Box {
  glm::ivec3 lo, hi;
  std::array<Plane, 6> faces() const {
    std::array<Plane, 6> f;
    for (int a = 0; a < 3; ++a) {
      glm::ivec3 n(0);
      n[a] = 1;
      f[size_t(2 * a)] = {n, lo[a]};
      f[size_t(2 * a + 1)] = {n, hi[a]};
    }
    return f;
  }
  bool contains(const V64& p) const {
    for (int a = 0; a < 3; ++a)
      if (p[a] < I64(kFine) * lo[a] || p[a] > I64(kFine) * hi[a]) return false;
    return true;
  }
};

// The box of the node at cell @p origin with edge @p edge, cropped to the grid of @p dims samples.
inline Box nodeBox(const glm::ivec3& origin, int edge, const glm::ivec3& dims) {
  return Box{2 * origin, 2 * glm::min(origin + edge, glm::max(dims - 1, glm::ivec3(1)))};
}

}  // namespace hyb::detail
