#include "render/camera.h"

#include <cmath>

namespace hyb {

Camera Camera::orbit(const glm::dvec3& lo, const glm::dvec3& hi, const Orbit& o) {
  const double azimuthDeg = o.azimuthDeg, elevationDeg = o.elevationDeg, fovDeg = o.lens.fovDeg;
  const bool ortho = o.lens.ortho;
  const int width = o.lens.width, height = o.lens.height;
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

bool Camera::seesBox(const glm::dvec3& lo, const glm::dvec3& hi) const {
  const glm::dvec3 f = forward();
  const glm::dvec3 r = right(), u = trueUp();
  const double aspect = double(width) / double(height);
  const double ty = ortho ? 0.5 * orthoHeight : std::tan(glm::radians(fovDeg) * 0.5), tx = ty * aspect;
  // Signed distances to the side planes, positive outside: x − tx·z (perspective) or x − tx (ortho).
  int outside[5] = {0, 0, 0, 0, 0};
  for (int c = 0; c < 8; ++c) {
    const glm::dvec3 p = glm::dvec3((c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z) - eye;
    const double x = glm::dot(p, r), y = glm::dot(p, u), z = glm::dot(p, f);
    const double sx = ortho ? tx : tx * z, sy = ortho ? ty : ty * z;
    outside[0] += x > sx;
    outside[1] += -x > sx;
    outside[2] += y > sy;
    outside[3] += -y > sy;
    outside[4] += !ortho && z <= 0.0;
  }
  for (int k = 0; k < 5; ++k)
    if (outside[k] == 8) return false;
  return true;
}

void Camera::ray(double px, double py, glm::dvec3* origin, glm::dvec3* dir) const {
  const glm::dvec3 f = forward();
  const glm::dvec3 r = right(), u = trueUp();
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
