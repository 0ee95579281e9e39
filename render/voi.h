// Volume of interest (Levoy 1989, "Design for a real-time high-quality volume rendering
// workstation"): opacity scaled by one factor inside a box and another outside, with a smooth
// transition across the box's surface, to see into a region without removing its context.
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cmath>

namespace hyb {

/// A box [lo, hi] in its own axes (the patient's, LPS mm, for a box the user gives) with opacity
/// factors and a transition of width `ramp` mm centred on the box's surface. The renderers work in
/// the grid frame: a grid point x lies at toBox·x + offset in the box's axes (rigid; identity when
/// the grid's frame is the box's).
struct VolumeOfInterest {
  glm::dvec3 lo{0.0}, hi{0.0};
  double inside = 1.0;   ///< opacity factor deep inside (≥ 0)
  double outside = 0.1;  ///< opacity factor far outside (≥ 0)
  double ramp = 4.0;     ///< transition width, mm (≥ 0)
  glm::dmat3 toBox{1.0};   ///< grid axes to the box's (orthonormal)
  glm::dvec3 offset{0.0};  ///< the grid origin in the box's axes

  /// Signed distance from grid point @p x to the box's surface: negative inside.
  double signedDistance(const glm::dvec3& x) const {
    const glm::dvec3 q = glm::abs(toBox * x + offset - 0.5 * (lo + hi)) - 0.5 * (hi - lo);
    return glm::length(glm::max(q, glm::dvec3(0.0))) + std::min(std::max({q.x, q.y, q.z}), 0.0);
  }
  /// The opacity factor at grid point @p x: smoothstep from outside to inside over [−ramp/2, ramp/2].
  double factor(const glm::dvec3& x) const {
    const double d = signedDistance(x);
    const double t = ramp > 0.0 ? std::clamp(0.5 - d / ramp, 0.0, 1.0) : (d <= 0.0 ? 1.0 : 0.0);
    return outside + (inside - outside) * t * t * (3.0 - 2.0 * t);
  }
  /// Whether the factor is 0 all over the grid box [a, b] (its nodes then cost nothing): the gap
  /// to the box from the grid box's bounds in the box's axes, which contain it (conservative).
  bool hides(const glm::dvec3& a, const glm::dvec3& b) const {
    if (outside > 0.0) return false;
    glm::dvec3 blo(1e300), bhi(-1e300);
    for (int c = 0; c < 8; ++c) {
      const glm::dvec3 p = toBox * glm::dvec3(c & 1 ? b.x : a.x, c & 2 ? b.y : a.y, c & 4 ? b.z : a.z) + offset;
      blo = glm::min(blo, p);
      bhi = glm::max(bhi, p);
    }
    const double gap = glm::length(glm::max(glm::max(lo - bhi, blo - hi), glm::dvec3(0.0)));  // between the boxes
    return ramp > 0.0 ? gap >= 0.5 * ramp : gap > 0.0;
  }
};

}  // namespace hyb
