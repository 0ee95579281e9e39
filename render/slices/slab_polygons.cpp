#include "render/slices/slab_polygons.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "surface/closest_point.h"
#include "volume/core/error.h"

namespace hyb {

SurfacePolygons::SurfacePolygons(const TriangleMesh& surface) : mesh(&surface), starts(surface.polygonStarts) {
  if (starts.empty()) {
    starts.resize(surface.triangles.size() + 1);
    std::iota(starts.begin(), starts.end(), 0u);
  }
  HYB_CHECK(starts.front() == 0 && starts.back() == surface.triangles.size());
}

PixelCentres::PixelCentres(const glm::mat4& viewProj, int width, int height)
    : mViewProj(viewProj), mInverse(glm::inverse(glm::dmat4(viewProj))), mSize(width, height) {}

PixelCentres::Cover PixelCentres::cover(const glm::vec3& a, const glm::vec3& b, const glm::vec3& c, const ProxyDepth* depth) const {
  constexpr double kMargin = 1.0 / 64.0;  // pixels
  const glm::dvec3 p[3] = {glm::dvec3(a), glm::dvec3(b), glm::dvec3(c)};
  glm::dvec2 w[3];
  for (int k = 0; k < 3; ++k) {
    const glm::dvec4 q = mViewProj * glm::dvec4(p[k], 1.0);
    if (!(q.w > 0.0)) return {};  // the clipper's business
    w[k] = (glm::dvec2(q) / q.w * 0.5 + 0.5) * mSize;
    if (!std::isfinite(w[k].x) || !std::isfinite(w[k].y)) return {};
  }
  // The centres (i + 0.5, j + 0.5) of the image the bounding box may hold. A box larger than a few
  // pixels is left to the rasteriser: its float error grows with the coordinates, the margin not.
  const glm::dvec2 lo = glm::min(w[0], glm::min(w[1], w[2])), hi = glm::max(w[0], glm::max(w[1], w[2]));
  const glm::dvec2 first = glm::max(glm::ceil(lo - 0.5 - kMargin), glm::dvec2(0.0)), last = glm::min(glm::floor(hi - 0.5 + kMargin), mSize - 1.0);
  if (first.x > last.x || first.y > last.y) return {true, 0, 0, 0};
  if (glm::any(glm::greaterThan(hi - lo, glm::dvec2(double(kMaxCentres)))) || (last.x - first.x + 1) * (last.y - first.y + 1) > kMaxCentres) return {};
  auto cross = [](const glm::dvec2& u, const glm::dvec2& v) { return u.x * v.y - u.y * v.x; };
  const double area = cross(w[1] - w[0], w[2] - w[0]);
  if (area == 0.0) return {};
  const glm::dvec3 normal = glm::cross(p[1] - p[0], p[2] - p[0]);
  // The depth of the triangle's plane where the ray through window point s meets it.
  auto depthAt = [&](const glm::dvec2& s) {
    const glm::dvec2 ndc = s / mSize * 2.0 - 1.0;
    const glm::dvec4 n4 = mInverse * glm::dvec4(ndc, -1.0, 1.0), f4 = mInverse * glm::dvec4(ndc, 1.0, 1.0);
    const glm::dvec3 from = glm::dvec3(n4) / n4.w, dir = glm::dvec3(f4) / f4.w - from;
    return depth->of(from + dir * (glm::dot(normal, p[0] - from) / glm::dot(normal, dir)));
  };
  double rounding = 1.0;  // 16 float ulps of the largest magnitude the shader's depth meets
  if (depth)
    for (const glm::dvec3& v : p) rounding = std::max({rounding, glm::length(v - depth->eye), glm::length(v), std::abs(depth->of(v))});
  rounding *= 16.0 * double(std::numeric_limits<float>::epsilon());
  Cover out{true, 0, std::numeric_limits<double>::max(), std::numeric_limits<double>::lowest()};
  for (double y = first.y; y <= last.y; ++y)
    for (double x = first.x; x <= last.x; ++x) {
      const glm::dvec2 s(x + 0.5, y + 0.5);
      double inside = std::numeric_limits<double>::max();  // pixels from the nearest edge, > 0 inside
      for (int k = 0; k < 3; ++k) {
        const glm::dvec2 e = w[(k + 1) % 3] - w[k];
        inside = std::min(inside, std::copysign(1.0, area) * cross(e, s - w[k]) / glm::length(e));
      }
      if (inside < -kMargin) continue;
      if (inside <= kMargin) return {};  // the rasteriser's edge rule decides
      ++out.centres;
      if (!depth) continue;
      const double d = depthAt(s), slope = std::abs(depthAt(s + glm::dvec2(kMargin, 0.0)) - d) + std::abs(depthAt(s + glm::dvec2(0.0, kMargin)) - d);
      if (!std::isfinite(d) || !std::isfinite(slope)) return {};
      out.nearest = std::min(out.nearest, d - slope - rounding);
      out.farthest = std::max(out.farthest, d + slope + rounding);
    }
  return out;
}

bool PixelCentres::besideImage(const glm::dvec3& lo, const glm::dvec3& hi) const {
  // In front of the eye, the box projects into the hull of its corners' projections.
  glm::bvec4 beside(true);  // left, right, below, above
  for (int k = 0; k < 8; ++k) {
    const glm::dvec3 p((k & 1) ? hi.x : lo.x, (k & 2) ? hi.y : lo.y, (k & 4) ? hi.z : lo.z);
    const glm::dvec4 q = mViewProj * glm::dvec4(p, 1.0);
    if (!(q.w > 0.0)) return false;
    const glm::dvec2 w = (glm::dvec2(q) / q.w * 0.5 + 0.5) * mSize;
    beside = glm::bvec4(beside[0] && w.x < -1.0, beside[1] && w.x > mSize.x + 1.0, beside[2] && w.y < -1.0, beside[3] && w.y > mSize.y + 1.0);
  }
  return glm::any(beside);
}

// A grid of leaves says which brick holds each polygon's centroid.
BrickPolygons polygonsByBrick(const Volume& volume, const VolumeOctree& octree, const Selection& selection, const SurfacePolygons& surface,
                              const RegionBox* region) {
  const std::vector<uint32_t>& starts = surface.starts;
  const TriangleMesh& mesh = *surface.mesh;
  const glm::ivec3 cells = glm::max(volume.dims() - 1, glm::ivec3(1));
  const int leaf = octree.leafEdge();
  const glm::ivec3 grid = (cells + leaf - 1) / leaf;
  std::vector<uint32_t> brickAt(size_t(grid.x) * size_t(grid.y) * size_t(grid.z), 0);
  for (size_t b = 0; b < selection.bricks.size(); ++b) {
    const OctreeNode& n = octree.nodes()[selection.bricks[b].node];
    const glm::ivec3 lo = glm::ivec3(n.origin) / leaf, hi = glm::min((glm::ivec3(n.origin) + octree.edge(n) + leaf - 1) / leaf, grid);
    for (int z = lo.z; z < hi.z; ++z)
      for (int y = lo.y; y < hi.y; ++y)
        for (int x = lo.x; x < hi.x; ++x) brickAt[size_t(x) + size_t(grid.x) * (size_t(y) + size_t(grid.y) * size_t(z))] = uint32_t(b);
  }
  BrickPolygons out;
  out.offsets.assign(selection.bricks.size() + 1, 0);
  const size_t polygons = starts.size() - 1;
  std::vector<uint32_t> brickOf(polygons);
  for (size_t pi = 0; pi < polygons; ++pi) {
    glm::dvec3 c(0.0);
    for (uint32_t ti = starts[pi]; ti < starts[pi + 1]; ++ti)
      for (int k = 0; k < 3; ++k) c += glm::dvec3(mesh.vertices[mesh.triangles[ti][k]]);
    c /= 3.0 * double(std::max(starts[pi + 1] - starts[pi], 1u));
    // A region's pieces (cutMeshToRegion) go to its own bricks, slivers along its faces included.
    if (region) c = glm::clamp(c, region->lo, glm::max(region->lo, region->hi - 1e-6 * volume.spacing()));
    c /= volume.spacing();
    const glm::ivec3 g = glm::clamp(glm::ivec3(glm::floor(c)), glm::ivec3(0), cells - 1) / leaf;
    brickOf[pi] = brickAt[size_t(g.x) + size_t(grid.x) * (size_t(g.y) + size_t(grid.y) * size_t(g.z))];
    ++out.offsets[brickOf[pi] + 1];
  }
  for (size_t b = 0; b < selection.bricks.size(); ++b) out.offsets[b + 1] += out.offsets[b];
  out.list.resize(polygons);
  std::vector<uint32_t> next(out.offsets.begin(), out.offsets.end() - 1);
  for (size_t pi = 0; pi < polygons; ++pi) out.list[next[brickOf[pi]]++] = uint32_t(pi);
  return out;
}

void SlabPolygonList::build(std::span<const SlabSource> sources, const SlabLayout& slabs, const PixelCentres* centres) {
  const ProxyDepth& depth = slabs.depth;
  const double delta = slabs.delta;
  const bool sliced = slabs.sliced, cut = slabs.cut;
  mSurfaces.clear();
  mDelta = delta;
  mInstances.clear();
  mNext = 0;
  mPolygons.clear();
  mFirstSpan.clear();
  mSpans.clear();
  mFirst = std::numeric_limits<long long>::max();
  mLast = std::numeric_limits<long long>::min();
  mTriangles = mUnseen = mDraws = 0;
  for (const SlabSource& source : sources) {
    const SurfacePolygons& surface = *source.surface;
    const uint32_t sourceIndex = uint32_t(mSurfaces.size());
    mSurfaces.push_back(&surface);
    const TriangleMesh& mesh = *surface.mesh;
    for (uint32_t pi : source.polygons) {
      const uint32_t local = uint32_t(mPolygons.size());
      mPolygons.push_back({sourceIndex, pi});
      mFirstSpan.push_back(uint32_t(mSpans.size()));
      long long p0 = std::numeric_limits<long long>::max(), p1 = std::numeric_limits<long long>::min();
      double centroid = 0;
      for (uint32_t ti = surface.starts[pi]; ti < surface.starts[pi + 1]; ++ti) {
        const glm::uvec3 tr = mesh.triangles[ti];
        ++mTriangles;
        double dmn = 1e300, dmx = -1e300, sum = 0;
        for (int k = 0; k < 3; ++k) {
          const double d = depth.of(glm::dvec3(mesh.vertices[tr[k]]));
          dmn = std::min(dmn, d);
          dmx = std::max(dmx, d);
          sum += d;
        }
        centroid += sum / 3;
        const PixelCentres::Cover cover =
            centres ? centres->cover(mesh.vertices[tr.x], mesh.vertices[tr.y], mesh.vertices[tr.z], sliced && cut ? &depth : nullptr) : PixelCentres::Cover{};
        if ((cover.known && cover.centres == 0) || !std::isfinite(dmn) || !std::isfinite(dmx)) {  // (a corner not finite draws nothing)
          mSpans.push_back({1, 0});
          ++mUnseen;
          continue;
        }
        if (depth.shells)  // the nearest point of a triangle to the eye may lie inside it
          dmn = distanceToTriangle(depth.eye, glm::dvec3(mesh.vertices[tr.x]), glm::dvec3(mesh.vertices[tr.y]), glm::dvec3(mesh.vertices[tr.z]));
        // A brick without slices needs no slabs: its polygons are only sorted back to front.
        long long k0 = sliced ? (long long)std::floor(dmn / delta) : 0, k1 = sliced ? (long long)std::floor(dmx / delta) : 0;
        if (cover.known && sliced && cut && std::floor(cover.nearest / delta) == std::floor(cover.farthest / delta))
          k0 = k1 = (long long)std::floor(cover.nearest / delta);  // every fragment it draws is in that slab
        mSpans.push_back({int32_t(k0), int32_t(k1)});
        p0 = std::min(p0, k0);
        p1 = std::max(p1, k1);
      }
      centroid /= double(surface.starts[pi + 1] - surface.starts[pi]);
      if (!cut && sliced && p0 <= p1) {  // whole, in its centroid's slab
        p0 = p1 = (long long)std::floor(centroid / delta);
        for (size_t j = mFirstSpan.back(); j < mSpans.size(); ++j)
          if (mSpans[j][0] <= mSpans[j][1]) mSpans[j] = {int32_t(p0), int32_t(p0)};
      }
      for (long long k = p0; k <= p1; ++k)
        mInstances.push_back({sliced ? std::clamp(centroid, double(k) * delta, double(k + 1) * delta) : centroid, int32_t(k), local});
      if (sliced && p0 <= p1) {
        mFirst = std::min(mFirst, p0);
        mLast = std::max(mLast, p1);
      }
    }
  }
  if (mFirst > mLast) mFirst = 0, mLast = -1;
  // Far to near: by slab, then by depth inside a slab; ties (centroids clamped to one slab's
  // bound) in the polygons' order, so that the triangles left out change no other's order.
  std::sort(mInstances.begin(), mInstances.end(), [](const Instance& x, const Instance& y) {
    return x.slab != y.slab ? x.slab > y.slab : x.depth != y.depth ? x.depth > y.depth : x.polygon < y.polygon;
  });
}

void SlabPolygonList::emitDownTo(long long slab, std::vector<float>* stream) {
  for (; mNext < mInstances.size() && mInstances[mNext].slab >= slab; ++mNext) emit(mInstances[mNext], stream);
}

// A polygon's triangles that reach one slab, each with the depths its fragments must lie within:
// none where the triangle is in one slab, else the slab's, open at the triangle's first and last
// (a fragment the shader's float depth puts just beyond them is still drawn, in exactly one).
void SlabPolygonList::emit(const Instance& in, std::vector<float>* stream) {
  const auto [source, pi] = mPolygons[in.polygon];
  const SurfacePolygons& s = *mSurfaces[source];
  const TriangleMesh& mesh = *s.mesh;
  const bool smooth = !mesh.normals.empty();
  const float kind = 1.0f + (s.colors.empty() ? 0.0f : float(s.colors[pi]));
  size_t j = mFirstSpan[in.polygon];
  for (uint32_t ti = s.starts[pi]; ti < s.starts[pi + 1]; ++ti, ++j) {
    const auto [k0, k1] = mSpans[j];
    if (in.slab < k0 || in.slab > k1) continue;
    const glm::uvec3 tr = mesh.triangles[ti];
    const glm::vec3 a = mesh.vertices[tr.x], b = mesh.vertices[tr.y], c = mesh.vertices[tr.z];
    const glm::vec3 face = smooth ? glm::vec3(0.0f) : glm::normalize(glm::cross(b - a, c - a));
    const float lo = in.slab > k0 ? float(double(in.slab) * mDelta) : -1e30f, hi = in.slab < k1 ? float(double(in.slab + 1) * mDelta) : 1e30f;
    for (int k = 0; k < 3; ++k) putVertex(stream, mesh.vertices[tr[k]], smooth ? mesh.normals[tr[k]] : face, kind, lo, hi);
    ++mDraws;
  }
}

double distanceToTriangle(const glm::dvec3& p, const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c) {
  return glm::length(p - closestOnTriangle(p, a, b, c));
}

}  // namespace hyb
