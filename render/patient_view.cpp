#include "render/patient_view.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "volume/error.h"

namespace hyb {

namespace {

constexpr const char* kViewNames[] = {"anterior", "posterior", "left", "right", "superior", "inferior"};

// LPS directions.
constexpr glm::dvec3 kLeft(1, 0, 0), kPosterior(0, 1, 0), kSuperior(0, 0, 1);

}  // namespace

bool parseAnatomicalView(const std::string& name, AnatomicalView* view) {
  for (int v = 0; v < 6; ++v)
    if (name == kViewNames[v]) {
      *view = AnatomicalView(v);
      return true;
    }
  return false;
}

const char* anatomicalViewNames() { return "anterior|posterior|left|right|superior|inferior"; }

ViewDirection viewDirection(AnatomicalView view) {
  switch (view) {
    case AnatomicalView::Anterior: return {-kPosterior, kSuperior};
    case AnatomicalView::Posterior: return {kPosterior, kSuperior};
    case AnatomicalView::Left: return {kLeft, kSuperior};
    case AnatomicalView::Right: return {-kLeft, kSuperior};
    case AnatomicalView::Superior: return {kSuperior, -kPosterior};
    case AnatomicalView::Inferior: return {-kSuperior, -kPosterior};
  }
  return {};
}

ViewDirection orbitDirection(double azimuthDeg, double elevationDeg) {
  const double az = glm::radians(azimuthDeg), el = glm::radians(elevationDeg);
  const glm::dvec3 horizontal = std::sin(az) * kLeft - std::cos(az) * kPosterior;  // anterior at 0, left at 90
  ViewDirection d;
  d.toEye = std::cos(el) * horizontal + std::sin(el) * kSuperior;
  // Near a pole superior projects to a point; up then follows the limit it tends to.
  d.up = std::abs(el) > glm::radians(89.0) ? (el > 0 ? -horizontal : horizontal) : kSuperior;
  return d;
}

Camera fitCamera(const std::vector<glm::dvec3>& points, const ViewDirection& direction, double fovDeg, bool ortho, int width, int height,
                 double margin) {
  HYB_CHECK(!points.empty() && width > 0 && height > 0 && margin >= 0.0 && margin < 1.0);
  const glm::dvec3 f = -glm::normalize(direction.toEye);
  const glm::dvec3 r = glm::normalize(glm::cross(f, direction.up)), u = glm::cross(r, f);
  const double aspect = double(width) / double(height);
  glm::dvec3 lo(1e300), hi(-1e300);  // in (r, u, f)
  for (const glm::dvec3& p : points) {
    const glm::dvec3 q(glm::dot(p, r), glm::dot(p, u), glm::dot(p, f));
    lo = glm::min(lo, q);
    hi = glm::max(hi, q);
  }
  const double radius = std::max(1e-6, 0.5 * glm::length(hi - lo));
  Camera c;
  c.up = u;
  c.fovDeg = fovDeg;
  c.ortho = ortho;
  c.width = width;
  c.height = height;
  glm::dvec3 centre = 0.5 * (lo + hi);  // in (r, u, f)
  const double fill = 1.0 - margin;
  if (ortho) {
    c.orthoHeight = std::max({hi.y - lo.y, (hi.x - lo.x) / aspect, 1e-6}) / fill;
    c.center = centre.x * r + centre.y * u + centre.z * f;
    c.eye = c.center - f * (0.5 * (hi.z - lo.z) + radius);
    return c;
  }
  // The distance from the centre's plane that puts every point inside the frustum (tangents ty,
  // tx shrunk by the margin), then the centre moved across so the points' projection is centred.
  const double ty = std::tan(glm::radians(fovDeg) * 0.5) * fill, tx = ty * aspect;
  double distance = 0.0;
  for (int pass = 0; pass < 4; ++pass) {
    distance = 0.0;
    for (const glm::dvec3& p : points) {
      const glm::dvec3 q = glm::dvec3(glm::dot(p, r), glm::dot(p, u), glm::dot(p, f)) - centre;
      distance = std::max({distance, std::abs(q.x) / tx - q.z, std::abs(q.y) / ty - q.z});
    }
    double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;  // the projection's bounds, tangents
    for (const glm::dvec3& p : points) {
      const glm::dvec3 q = glm::dvec3(glm::dot(p, r), glm::dot(p, u), glm::dot(p, f)) - centre;
      const double depth = std::max(q.z + distance, 1e-9);
      x0 = std::min(x0, q.x / depth), x1 = std::max(x1, q.x / depth);
      y0 = std::min(y0, q.y / depth), y1 = std::max(y1, q.y / depth);
    }
    centre.x += 0.5 * (x0 + x1) * distance;
    centre.y += 0.5 * (y0 + y1) * distance;
  }
  c.center = centre.x * r + centre.y * u + centre.z * f;
  c.eye = c.center - f * std::max(distance, 1e-6);
  return c;
}

void zoomCamera(Camera* camera, double zoom) {
  HYB_CHECK(zoom > 0.0 && std::isfinite(zoom));
  if (camera->ortho) {
    camera->orthoHeight /= zoom;
    return;
  }
  camera->fovDeg = glm::degrees(2.0 * std::atan(std::tan(glm::radians(camera->fovDeg) * 0.5) / zoom));
}

std::vector<glm::dvec3> visiblePoints(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, std::optional<float> iso) {
  std::vector<glm::dvec3> points;
  const glm::dvec3 spacing = volume.spacing();
  auto visible = [&](const OctreeNode& n) {
    return tf.maxAlpha(n.minValue, n.maxValue) > 0.0f || (iso && n.minValue < *iso && *iso <= n.maxValue);
  };
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const uint32_t i = stack.back();
    stack.pop_back();
    const OctreeNode& n = octree.nodes()[i];
    if (!visible(n)) continue;  // nor is any node inside it
    if (n.isLeaf()) {
      glm::ivec3 lo, hi;
      octree.voxelBox(n, &lo, &hi);
      for (int c = 0; c < 8; ++c)
        points.push_back(volume.frame().toPatient(glm::dvec3(c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z) * spacing));
      continue;
    }
    for (int slot = 0; slot < 8; ++slot)
      if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
  }
  return points;
}

Camera toGridCamera(const Camera& patientCamera, const PatientFrame& frame) {
  Camera c = patientCamera;
  c.eye = frame.toGrid(patientCamera.eye);
  c.center = frame.toGrid(patientCamera.center);
  c.up = frame.vectorToGrid(patientCamera.up);
  c.mirrored = patientCamera.mirrored != frame.mirrored();
  return c;
}

}  // namespace hyb
