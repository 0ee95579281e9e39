#include "render/camera.h"

#include <cmath>

namespace hyb {

Camera Camera::orbit(const glm::dvec3& lo, const glm::dvec3& hi, double azimuthDeg, double elevationDeg, double fovDeg,
                     bool ortho, int width, int height) {
  Camera c;
  c.center = 0.5 * (lo + hi);
  const double radius = std::max(1e-6, 0.5 * glm::length(hi - lo));
  const double az = glm::radians(azimuthDeg), el = glm::radians(elevationDeg);
  const glm::dvec3 dir(std::sin(az) * std::cos(el), -std::cos(az) * std::cos(el), std::sin(el));
  const double aspect = double(width) / double(height);
  const double halfFov = glm::radians(fovDeg) * 0.5;
  const double fit = std::min(std::tan(halfFov), std::tan(halfFov) * aspect);
  const double distance = radius / std::sin(std::atan(fit)) * 1.05;
  c.eye = c.center + dir * distance;
  c.up = std::abs(el) > glm::radians(89.0) ? glm::dvec3(0, 1, 0) : glm::dvec3(0, 0, 1);
  c.fovDeg = fovDeg;
  c.ortho = ortho;
  c.orthoHeight = 2.0 * radius * 1.05 / std::min(1.0, aspect);
  c.width = width;
  c.height = height;
  return c;
}

void Camera::ray(double px, double py, glm::dvec3* origin, glm::dvec3* dir) const {
  const glm::dvec3 f = forward();
  const glm::dvec3 r = glm::normalize(glm::cross(f, up));
  const glm::dvec3 u = glm::cross(r, f);
  const double sx = (2.0 * px / width - 1.0), sy = (1.0 - 2.0 * py / height);
  const double aspect = double(width) / double(height);
  if (ortho) {
    const double h = orthoHeight * 0.5;
    *origin = eye + r * (sx * h * aspect) + u * (sy * h);
    *dir = f;
  } else {
    const double t = std::tan(glm::radians(fovDeg) * 0.5);
    *origin = eye;
    *dir = glm::normalize(f + r * (sx * t * aspect) + u * (sy * t));
  }
}

}  // namespace hyb
