#include "render/patient_view.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>

#include "volume/error.h"
#include "volume/parallel.h"

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

// The visible cells (the 8 samples' range is given an opacity, or spans the isovalue) are a set
// of places in the patient, whatever order the grid stores them in, and so is their convex hull,
// which is all a camera fit depends on: the first and last visible cell of every row of cells
// along x carry that hull. The octree only says where to look: rows are scanned inward from each
// end through the leaves whose range can be visible, and stop at the first visible cell.
std::vector<glm::dvec3> visiblePoints(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, std::optional<float> iso,
                                      const KnotSource* knots) {
  auto visible = [&](float lo, float hi) { return tf.maxAlpha(lo, hi) > 0.0f || (iso && lo < *iso && *iso <= hi); };
  const glm::ivec3 dims = volume.dims(), cells = glm::max(dims - 1, glm::ivec3(1));
  const int leaf = octree.leafEdge();
  // The leaves that can hold a visible cell.
  std::vector<glm::ivec3> leaves;
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const OctreeNode& n = octree.nodes()[stack.back()];
    stack.pop_back();
    if (!visible(n.minValue, n.maxValue)) continue;  // nor is any node inside it
    if (n.isLeaf()) {
      const glm::ivec3 lo = glm::ivec3(n.origin) / leaf, hi = glm::min((glm::ivec3(n.origin) + octree.edge(n) + leaf - 1) / leaf, (cells + leaf - 1) / leaf);
      for (int z = lo.z; z < hi.z; ++z)
        for (int y = lo.y; y < hi.y; ++y)
          for (int x = lo.x; x < hi.x; ++x) leaves.emplace_back(x, y, z);
      continue;
    }
    for (int slot = 0; slot < 8; ++slot)
      if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
  }
  // Per row of cells (j, k), the first and last visible cell: each leaf's, read from its samples
  // alone (a paged scene reads the blocks of the visible leaves), then the smallest and largest.
  const VolumeKnots inMemory(volume, octree);
  const KnotSource& source = knots ? *knots : inMemory;
  const size_t rowCount = size_t(cells.y) * size_t(cells.z);
  std::vector<int> first(rowCount, std::numeric_limits<int>::max()), last(rowCount, -1);
  ParallelFailure failure;
#pragma omp parallel
  {
    std::vector<float> box;
    std::vector<std::array<int, 3>> found;  // row, first, last
#pragma omp for schedule(dynamic, 16)
    for (size_t l = 0; l < leaves.size(); ++l)
      failure.run([&] {
        const glm::ivec3 lo = leaves[l] * leaf, hi = glm::min(lo + leaf, cells);  // cells [lo, hi)
        const glm::ivec3 top = glm::min(hi, dims - 1), count = top - lo + 1;          // samples [lo, top]
        box.resize(size_t(count.x) * size_t(count.y) * size_t(count.z));
        source.read(1, lo, count, box.data(), nullptr);
        auto at = [&](int i, int j, int k) {
          return box[size_t(std::min(i, top.x) - lo.x) + size_t(count.x) * (size_t(std::min(j, top.y) - lo.y) + size_t(count.y) * size_t(std::min(k, top.z) - lo.z))];
        };
        // The range of cell (i, j, k): its corners, clamped to the grid (a grid one sample thick
        // has cells of one sample along that axis).
        auto cellVisible = [&](int i, int j, int k) {
          float a = 1e30f, b = -1e30f;
          for (int c = 0; c < 8; ++c) {
            const float v = at(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1));
            a = std::min(a, v);
            b = std::max(b, v);
          }
          return visible(a, b);
        };
        for (int k = lo.z; k < hi.z; ++k)
          for (int j = lo.y; j < hi.y; ++j) {
            int f = -1, e = -1;
            for (int i = lo.x; i < hi.x && f < 0; ++i)
              if (cellVisible(i, j, k)) f = i;
            if (f < 0) continue;
            for (int i = hi.x - 1; i >= f && e < 0; --i)
              if (cellVisible(i, j, k)) e = i;
            found.push_back({j + cells.y * k, f, e});
          }
      });
#pragma omp critical
    for (const auto& [row, f, e] : found) {
      first[size_t(row)] = std::min(first[size_t(row)], f);
      last[size_t(row)] = std::max(last[size_t(row)], e);
    }
  }
  failure.rethrow();
  std::vector<glm::dvec3> points;
  for (int k = 0; k < cells.z; ++k)
    for (int j = 0; j < cells.y; ++j) {
      const size_t row = size_t(j) + size_t(cells.y) * size_t(k);
      if (last[row] < 0) continue;
      const int x0 = first[row], x1 = std::min(last[row] + 1, dims.x - 1), y1 = std::min(j + 1, dims.y - 1), z1 = std::min(k + 1, dims.z - 1);
      for (const int x : {x0, x1})
        for (const int y : {j, y1})
          for (const int z : {k, z1}) points.push_back(volume.frame().toPatient(glm::dvec3(x, y, z) * volume.spacing()));
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
