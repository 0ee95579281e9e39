#include "render/patient_view.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "volume/core/error.h"
#include "volume/core/parallel.h"

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

Camera fitCamera(const std::vector<glm::dvec3>& points, const ViewDirection& direction, const Camera::Lens& lens, double margin) {
  const double fovDeg = lens.fovDeg;
  const bool ortho = lens.ortho;
  const int width = lens.width, height = lens.height;
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

namespace {

// The vertices of the convex hull of @p points (ordered by y, then x; integer coordinates, so
// exactly), collinear ones left out: Andrew's monotone chain.
void convexHull2d(const std::vector<glm::i64vec2>& points, std::vector<glm::i64vec2>* hull) {
  hull->clear();
  if (points.size() < 3) {
    *hull = points;
    return;
  }
  auto cross = [](const glm::i64vec2& o, const glm::i64vec2& a, const glm::i64vec2& b) {
    return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
  };
  std::vector<glm::i64vec2>& h = *hull;
  h.resize(2 * points.size());
  size_t n = 0;
  for (size_t i = 0; i < points.size(); ++i) {  // one chain
    while (n >= 2 && cross(h[n - 2], h[n - 1], points[i]) <= 0) --n;
    h[n++] = points[i];
  }
  for (size_t i = points.size() - 1, lower = n + 1; i-- > 0;) {  // and the other, back
    while (n >= lower && cross(h[n - 2], h[n - 1], points[i]) <= 0) --n;
    h[n++] = points[i];
  }
  h.resize(n - 1);  // the first point closes the loop
}

}  // namespace

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
  const glm::ivec3 grid = (cells + leaf - 1) / leaf;
  // Which leaves can hold a visible cell.
  std::vector<char> leafVisible(size_t(grid.x) * size_t(grid.y) * size_t(grid.z), 0);
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const OctreeNode& n = octree.nodes()[stack.back()];
    stack.pop_back();
    if (!visible(n.minValue, n.maxValue)) continue;  // nor is any node inside it
    if (n.isLeaf()) {
      const glm::ivec3 lo = glm::ivec3(n.origin) / leaf, hi = glm::min((glm::ivec3(n.origin) + octree.edge(n) + leaf - 1) / leaf, grid);
      for (int z = lo.z; z < hi.z; ++z)
        for (int y = lo.y; y < hi.y; ++y)
          for (int x = lo.x; x < hi.x; ++x) leafVisible[size_t(x) + size_t(grid.x) * (size_t(y) + size_t(grid.y) * size_t(z))] = 1;
      continue;
    }
    for (int slot = 0; slot < 8; ++slot)
      if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
  }
  // Per row of cells (j, k), the first and last visible cell, found band by band (the rows of a
  // line of leaves along x) from either end, reading only the samples of the visible leaves met
  // before each row's first and last (a paged scene reads no other block).
  const VolumeKnots inMemory(volume, octree);
  const KnotSource& source = knots ? *knots : inMemory;
  const size_t rowCount = size_t(cells.y) * size_t(cells.z);
  std::vector<int> first(rowCount, -1), last(rowCount, -1);
  ParallelFailure failure;
#pragma omp parallel
  {
    std::vector<float> box;
    glm::ivec3 lo{0}, top{0}, count{0};  // the leaf read: its samples [lo, top]
    // The samples of leaf @p lx of the band whose rows start at (j0, k0).
    auto read = [&](int lx, int j0, int k0) {
      lo = glm::ivec3(lx * leaf, j0, k0);
      top = glm::min(glm::min(lo + leaf, cells), dims - 1);
      count = top - lo + 1;
      box.resize(size_t(count.x) * size_t(count.y) * size_t(count.z));
      source.read(1, lo, count, box.data(), nullptr);
    };
    // Whether the range of cell (i, j, k) of the leaf read can be visible: its corners, clamped to
    // the grid (a grid one sample thick has cells of one sample along that axis).
    auto cellVisible = [&](int i, int j, int k) {
      float a = 1e30f, b = -1e30f;
      for (int c = 0; c < 8; ++c) {
        const glm::ivec3 q = glm::min(glm::ivec3(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1)), top) - lo;
        const float v = box[size_t(q.x) + size_t(count.x) * (size_t(q.y) + size_t(count.y) * size_t(q.z))];
        a = std::min(a, v);
        b = std::max(b, v);
      }
      return visible(a, b);
    };
#pragma omp for schedule(dynamic)
    for (int band = 0; band < grid.y * grid.z; ++band)
      failure.run([&] {
        const char* leaves = &leafVisible[size_t(grid.x) * size_t(band)];
        const int j0 = band % grid.y * leaf, k0 = band / grid.y * leaf, j1 = std::min(j0 + leaf, cells.y), k1 = std::min(k0 + leaf, cells.z);
        auto row = [&](int j, int k) { return size_t(j) + size_t(cells.y) * size_t(k); };
        int open = (j1 - j0) * (k1 - k0);  // rows whose first visible cell is not found yet
        for (int lx = 0; lx < grid.x && open > 0; ++lx) {
          if (!leaves[lx]) continue;
          read(lx, j0, k0);
          for (int k = k0; k < k1; ++k)
            for (int j = j0; j < j1; ++j)
              for (int i = lo.x; first[row(j, k)] < 0 && i < std::min(lo.x + leaf, cells.x); ++i)
                if (cellVisible(i, j, k)) first[row(j, k)] = i, --open;
        }
        open = 0;  // rows with a visible cell whose last is not found yet
        for (int k = k0; k < k1; ++k)
          for (int j = j0; j < j1; ++j) open += first[row(j, k)] >= 0;
        for (int lx = grid.x - 1; lx >= 0 && open > 0; --lx) {
          if (!leaves[lx]) continue;
          read(lx, j0, k0);
          for (int k = k0; k < k1; ++k)
            for (int j = j0; j < j1; ++j)
              for (int i = std::min(lo.x + leaf, cells.x) - 1; first[row(j, k)] >= 0 && last[row(j, k)] < 0 && i >= lo.x; --i)
                if (cellVisible(i, j, k)) last[row(j, k)] = i, --open;
        }
      });
  }
  failure.rethrow();
  // The rows' end cells' corners, reduced to what carries their hull: per line of samples (y, z),
  // the least and greatest x of a corner on it; then per plane z, the vertices of the convex hull
  // of those (a vertex of the hull in space is one of its plane's). A 2048² × 1024 study gives a
  // few hundred thousand points rather than tens of millions.
  const size_t lines = size_t(dims.y) * size_t(dims.z);
  std::vector<int> xLo(lines, std::numeric_limits<int>::max()), xHi(lines, -1);
  for (int k = 0; k < cells.z; ++k)
    for (int j = 0; j < cells.y; ++j) {
      const size_t r = size_t(j) + size_t(cells.y) * size_t(k);
      if (last[r] < 0) continue;
      const int x0 = first[r], x1 = std::min(last[r] + 1, dims.x - 1), y1 = std::min(j + 1, dims.y - 1), z1 = std::min(k + 1, dims.z - 1);
      for (const int y : {j, y1})
        for (const int z : {k, z1}) {
          const size_t l = size_t(y) + size_t(dims.y) * size_t(z);
          xLo[l] = std::min(xLo[l], x0);
          xHi[l] = std::max(xHi[l], x1);
        }
    }
  std::vector<glm::dvec3> points;
  std::vector<glm::i64vec2> plane, hull;
  for (int z = 0; z < dims.z; ++z) {
    plane.clear();  // ordered by y, then x: as the monotone chain needs them
    for (int y = 0; y < dims.y; ++y) {
      const size_t l = size_t(y) + size_t(dims.y) * size_t(z);
      if (xHi[l] < 0) continue;
      plane.push_back({xLo[l], y});
      if (xHi[l] != xLo[l]) plane.push_back({xHi[l], y});
    }
    convexHull2d(plane, &hull);
    for (const glm::i64vec2& p : hull) points.push_back(volume.frame().toPatient(glm::dvec3(double(p.x), double(p.y), double(z)) * volume.spacing()));
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
