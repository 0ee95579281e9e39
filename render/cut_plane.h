// A cutting plane (multiplanar reformat in 3D; LaMar, Duchaineau, Hamann and Joy 2000): the half of
// the scene on the eye's side of the plane is removed and the plane shows the data through the
// transfer function's colour, opaque wherever the transfer function's opacity is above zero.
#pragma once

#include <glm/glm.hpp>

#include "render/camera.h"

namespace hyb {

/// A plane through @p point with normal @p normal (world mm; any length but zero).
struct CutPlane {
  glm::dvec3 point{0.0};
  glm::dvec3 normal{0, 0, 1};

  /// Coefficients (n, w) of n·x + w, with n of unit length pointing away from the eye, so that
  /// the kept half-space is n·x + w ≥ 0 (for an orthographic camera: n·forward ≥ 0).
  glm::dvec4 keptSide(const Camera& camera) const {
    glm::dvec3 n = glm::normalize(normal);
    const double side = camera.ortho ? glm::dot(n, camera.forward()) : glm::dot(n, point - camera.eye);
    if (side < 0.0 || (side == 0.0 && glm::dot(n, camera.forward()) < 0.0)) n = -n;
    return glm::dvec4(n, -glm::dot(n, point));
  }
};

}  // namespace hyb
