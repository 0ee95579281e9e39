// Volume of interest (Levoy 1989, "Design for a real-time high-quality volume rendering
// workstation"): opacity scaled by one factor inside a box and another outside, with a smooth
// transition across the box's surface, to see into a region without removing its context.
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cmath>

namespace hyb {

/// A box [lo, hi] (world mm) with opacity factors and a transition of width `ramp` mm centred on
/// the box's surface.
struct VolumeOfInterest {
  glm::dvec3 lo{0.0}, hi{0.0};
  double inside = 1.0;   ///< opacity factor deep inside (≥ 0)
  double outside = 0.1;  ///< opacity factor far outside (≥ 0)
  double ramp = 4.0;     ///< transition width, mm (≥ 0)

  /// Signed distance from @p x to the box's surface: negative inside.
  double signedDistance(const glm::dvec3& x) const {
    const glm::dvec3 q = glm::abs(x - 0.5 * (lo + hi)) - 0.5 * (hi - lo);
    return glm::length(glm::max(q, glm::dvec3(0.0))) + std::min(std::max({q.x, q.y, q.z}), 0.0);
  }
  /// The opacity factor at @p x: smoothstep from outside to inside over [−ramp/2, ramp/2].
  double factor(const glm::dvec3& x) const {
    const double d = signedDistance(x);
    const double t = ramp > 0.0 ? std::clamp(0.5 - d / ramp, 0.0, 1.0) : (d <= 0.0 ? 1.0 : 0.0);
    return outside + (inside - outside) * t * t * (3.0 - 2.0 * t);
  }
  /// Whether the factor is 0 all over the box [a, b] (its nodes then cost nothing).
  bool hides(const glm::dvec3& a, const glm::dvec3& b) const {
    if (outside > 0.0) return false;
    const double gap = glm::length(glm::max(glm::max(lo - b, a - hi), glm::dvec3(0.0)));  // between the boxes
    return ramp > 0.0 ? gap >= 0.5 * ramp : gap > 0.0;
  }
};

}  // namespace hyb
