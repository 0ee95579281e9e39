// The point of a triangle closest to a point (Ericson, Real-Time Collision Detection, 5.1.5), in
// float for the scan converter's nearest triangles and in double for the slab polygons' margins.
#pragma once

#include <glm/glm.hpp>

namespace hyb {

/// The point of triangle (@p a, @p b, @p c) closest to @p p: a corner, a point of an edge or of
/// the inside, found by Ericson's Voronoi regions.
template <class T>
glm::vec<3, T> closestOnTriangle(const glm::vec<3, T>& p, const glm::vec<3, T>& a, const glm::vec<3, T>& b, const glm::vec<3, T>& c) {
  const glm::vec<3, T> ab = b - a, ac = c - a, ap = p - a;
  const T d1 = glm::dot(ab, ap), d2 = glm::dot(ac, ap);
  if (d1 <= T(0) && d2 <= T(0)) return a;
  const glm::vec<3, T> bp = p - b;
  const T d3 = glm::dot(ab, bp), d4 = glm::dot(ac, bp);
  if (d3 >= T(0) && d4 <= d3) return b;
  const T vc = d1 * d4 - d3 * d2;
  if (vc <= T(0) && d1 >= T(0) && d3 <= T(0)) return a + ab * (d1 / (d1 - d3));
  const glm::vec<3, T> cp = p - c;
  const T d5 = glm::dot(ab, cp), d6 = glm::dot(ac, cp);
  if (d6 >= T(0) && d5 <= d6) return c;
  const T vb = d5 * d2 - d1 * d6;
  if (vb <= T(0) && d2 >= T(0) && d6 <= T(0)) return a + ac * (d2 / (d2 - d6));
  const T va = d3 * d6 - d5 * d4;
  if (va <= T(0) && (d4 - d3) >= T(0) && (d5 - d6) >= T(0)) return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  const T denom = T(1) / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

}  // namespace hyb
