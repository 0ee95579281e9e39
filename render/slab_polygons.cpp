#include "render/slab_polygons.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "surface/mesh_ops.h"
#include "volume/error.h"

namespace hyb {

SurfacePolygons::SurfacePolygons(const TriangleMesh& surface) : mesh(&surface), starts(surface.polygonStarts) {
  if (starts.empty()) {
    starts.resize(surface.triangles.size() + 1);
    std::iota(starts.begin(), starts.end(), 0u);
  }
  HYB_CHECK(starts.front() == 0 && starts.back() == surface.triangles.size());
  HYB_CHECK(surface.loopStarts.empty() || (surface.loopStarts.size() == starts.size() && surface.loopStarts.back() == surface.loops.size()));
  loopStarts = surface.loopStarts;
  loops = surface.loops;
}

// A grid of leaves says which brick holds each polygon's centroid.
BrickPolygons polygonsByBrick(const Volume& volume, const VolumeOctree& octree, const Selection& selection, const SurfacePolygons& surface) {
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
    c /= 3.0 * double(std::max(starts[pi + 1] - starts[pi], 1u)) * volume.spacing();
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

void SlabPolygonList::build(const SurfacePolygons& surface, std::span<const uint32_t> polygons, const ProxyDepth& depth, double delta, bool sliced, bool cut) {
  mSurface = &surface;
  mDepth = depth;
  mDelta = delta;
  mSmooth = !surface.mesh->normals.empty();
  mInstances.clear();
  mNext = 0;
  mPolygons.clear();
  mPolygonSpans.clear();
  mFirstSpan.clear();
  mSpans.clear();
  mFirst = std::numeric_limits<long long>::max();
  mLast = std::numeric_limits<long long>::min();
  mTriangles = mDraws = 0;
  const TriangleMesh& mesh = *surface.mesh;
  for (uint32_t pi : polygons) {
    const uint32_t local = uint32_t(mPolygons.size());
    mPolygons.push_back(pi);
    mFirstSpan.push_back(uint32_t(mSpans.size()));
    long long p0 = std::numeric_limits<long long>::max(), p1 = std::numeric_limits<long long>::min();
    double centroid = 0;
    for (uint32_t ti = surface.starts[pi]; ti < surface.starts[pi + 1]; ++ti) {
      const glm::uvec3 tr = mesh.triangles[ti];
      double dmn = 1e300, dmx = -1e300, sum = 0;
      for (int k = 0; k < 3; ++k) {
        const double d = depth.of(glm::dvec3(mesh.vertices[tr[k]]));
        dmn = std::min(dmn, d);
        dmx = std::max(dmx, d);
        sum += d;
      }
      if (depth.shells)  // the nearest point of a triangle to the eye may lie inside it
        dmn = distanceToTriangle(depth.eye, glm::dvec3(mesh.vertices[tr.x]), glm::dvec3(mesh.vertices[tr.y]), glm::dvec3(mesh.vertices[tr.z]));
      // A brick without slices needs no slabs: its polygons are only sorted back to front.
      const long long k0 = sliced ? (long long)std::floor(dmn / delta) : 0, k1 = sliced ? (long long)std::floor(dmx / delta) : 0;
      mSpans.push_back({int32_t(k0), int32_t(k1)});
      p0 = std::min(p0, k0);
      p1 = std::max(p1, k1);
      centroid += sum / 3;
      ++mTriangles;
    }
    centroid /= double(surface.starts[pi + 1] - surface.starts[pi]);
    if (!cut && sliced) {  // whole, in its centroid's slab
      p0 = p1 = (long long)std::floor(centroid / delta);
      for (size_t j = mFirstSpan.back(); j < mSpans.size(); ++j) mSpans[j] = {int32_t(p0), int32_t(p0)};
    }
    mPolygonSpans.push_back({int32_t(p0), int32_t(p1)});
    for (long long k = p0; k <= p1; ++k)
      mInstances.push_back({sliced ? std::clamp(centroid, double(k) * delta, double(k + 1) * delta) : centroid, int32_t(k), local});
    if (sliced && p0 <= p1) {
      mFirst = std::min(mFirst, p0);
      mLast = std::max(mLast, p1);
    }
  }
  if (mFirst > mLast) mFirst = 0, mLast = -1;
  // Far to near: by slab, then by depth inside a slab.
  std::sort(mInstances.begin(), mInstances.end(), [](const Instance& x, const Instance& y) {
    return x.slab != y.slab ? x.slab > y.slab : x.depth > y.depth;
  });
}

void SlabPolygonList::emitDownTo(long long slab, std::vector<float>* stream) {
  for (; mNext < mInstances.size() && mInstances[mNext].slab >= slab; ++mNext) emit(mInstances[mNext], stream);
}

// A polygon's part in one slab: a convex polygon that covers several slabs is cut to the slab whole
// (one piece, fanned); otherwise each of its triangles that reaches the slab goes in, cut to it when
// the triangle covers more than one.
void SlabPolygonList::emit(const Instance& in, std::vector<float>* stream) {
  const uint32_t pi = mPolygons[in.polygon];
  const auto [p0, p1] = mPolygonSpans[in.polygon];
  const SurfacePolygons& s = *mSurface;
  const TriangleMesh& mesh = *s.mesh;
  if (p1 > p0 && !mDepth.shells && pi + 1 < s.loopStarts.size() && s.loopStarts[pi + 1] > s.loopStarts[pi]) {
    ++mDraws;
    mPiece.clear();
    const glm::uvec3 tr = mesh.triangles[s.starts[pi]];
    const glm::vec3 face = glm::normalize(glm::cross(mesh.vertices[tr.y] - mesh.vertices[tr.x], mesh.vertices[tr.z] - mesh.vertices[tr.x]));
    for (uint32_t l = s.loopStarts[pi]; l < s.loopStarts[pi + 1]; ++l)
      mPiece.emplace_back(glm::dvec3(mesh.vertices[s.loops[l]]), mSmooth ? mesh.normals[s.loops[l]] : face);
    emitClipped(in.slab, stream);
    return;
  }
  size_t j = mFirstSpan[in.polygon];
  for (uint32_t ti = s.starts[pi]; ti < s.starts[pi + 1]; ++ti, ++j) {
    const auto [k0, k1] = mSpans[j];
    if (in.slab >= k0 && in.slab <= k1) emitTriangle(ti, in.slab, k1 > k0, stream);
  }
}

// A triangle in one slab, cut to it when it covers more than one (shells: per fragment).
void SlabPolygonList::emitTriangle(uint32_t triangle, int32_t slab, bool clip, std::vector<float>* stream) {
  const TriangleMesh& mesh = *mSurface->mesh;
  const glm::uvec3 tr = mesh.triangles[triangle];
  const glm::vec3 a = mesh.vertices[tr.x], b = mesh.vertices[tr.y], c = mesh.vertices[tr.z];
  const glm::vec3 face = glm::normalize(glm::cross(b - a, c - a));
  ++mDraws;
  if (!clip || mDepth.shells) {
    const float lo = clip ? float(double(slab) * mDelta) : -1e30f, hi = clip ? float(double(slab + 1) * mDelta) : 1e30f;
    for (int k = 0; k < 3; ++k) putVertex(stream, mesh.vertices[tr[k]], mSmooth ? mesh.normals[tr[k]] : face, 1.0f, lo, hi);
    return;
  }
  mPiece.clear();
  for (int k = 0; k < 3; ++k) mPiece.emplace_back(glm::dvec3(mesh.vertices[tr[k]]), mSmooth ? mesh.normals[tr[k]] : face);
  emitClipped(slab, stream);
}

// The convex planar piece in mPiece cut to slab [slab·Δ, (slab+1)·Δ) (Sutherland and Hodgman, two
// parallel planes: it stays convex), normals interpolated along the cut edges, and triangulated
// without a flat triangle (flatTriangle: llvmpipe draws those as NaN colours, black specks). So
// distances below the float resolution of the coordinates count as none: a vertex that near a
// plane lies on it (kept, no intersection beside it), vertices that near the previous one are
// merged, and a piece with collinear vertices (the T-junctions of the Surface Octree's loops) is
// fanned from its centroid, not from a corner whose edges hold them.
void SlabPolygonList::emitClipped(int32_t slab, std::vector<float>* stream) {
  double scale = 0.0;
  for (const auto& [p, n] : mPiece) scale = std::max({scale, std::abs(p.x), std::abs(p.y), std::abs(p.z)});
  const double eps = floatResolutionMm(scale);
  const glm::dvec3 f = mDepth.forward;
  const double lo = double(slab) * mDelta, hi = double(slab + 1) * mDelta;
  for (const std::pair<double, double>& plane : {std::pair{1.0, lo}, std::pair{-1.0, -hi}}) {  // depth ≥ lo, then −depth ≥ −hi
    const double sign = plane.first, bound = plane.second;  // (not a structured binding: clang 14 cannot capture one)
    auto side = [&](const glm::dvec3& p) {
      const double d = sign * glm::dot(f, p) - bound;
      return std::abs(d) <= eps ? 0.0 : d;
    };
    mKept.clear();
    for (size_t v = 0; v < mPiece.size(); ++v) {
      const auto& [p, np] = mPiece[v];
      const auto& [q, nq] = mPiece[(v + 1) % mPiece.size()];
      const double dp = side(p), dq = side(q);
      if (dp >= 0) mKept.push_back(mPiece[v]);
      if ((dp > 0 && dq < 0) || (dp < 0 && dq > 0)) {
        const double t = dp / (dp - dq);
        mKept.emplace_back(p + (q - p) * t, np + (nq - np) * float(t));
      }
    }
    mPiece.swap(mKept);
  }
  mKept.clear();
  for (const auto& vertex : mPiece)
    if (mKept.empty() || glm::length(vertex.first - mKept.back().first) > eps) mKept.push_back(vertex);
  while (mKept.size() > 1 && glm::length(mKept.back().first - mKept.front().first) <= eps) mKept.pop_back();
  mPiece.swap(mKept);
  const size_t n = mPiece.size();
  size_t corners = 0;
  for (size_t v = 0; v < n; ++v) corners += !flatTriangle(mPiece[(v + n - 1) % n].first, mPiece[v].first, mPiece[(v + 1) % n].first);
  if (corners < 3) return;  // a segment: it covers nothing
  auto triangle = [&](const std::pair<glm::dvec3, glm::vec3>& a, const std::pair<glm::dvec3, glm::vec3>& b, const std::pair<glm::dvec3, glm::vec3>& c) {
    for (const auto& [p, nrm] : {a, b, c}) putVertex(stream, glm::vec3(p), nrm, 1.0f, -1e30f, 1e30f);
  };
  if (corners == n) {
    for (size_t v = 1; v + 1 < n; ++v) triangle(mPiece[0], mPiece[v], mPiece[v + 1]);
    return;
  }
  glm::dvec3 centre(0.0);
  glm::vec3 normal(0.0f);
  for (const auto& [p, nrm] : mPiece) centre += p, normal += nrm;
  const std::pair<glm::dvec3, glm::vec3> mid{centre / double(n), normal / float(n)};
  for (size_t v = 0; v < n; ++v) triangle(mid, mPiece[v], mPiece[(v + 1) % n]);
}

double distanceToTriangle(const glm::dvec3& p, const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c) {
  const glm::dvec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = glm::dot(ab, ap), d2 = glm::dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return glm::length(ap);
  const glm::dvec3 bp = p - b;
  const double d3 = glm::dot(ab, bp), d4 = glm::dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return glm::length(bp);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return glm::length(p - (a + ab * (d1 / (d1 - d3))));
  const glm::dvec3 cp = p - c;
  const double d5 = glm::dot(ab, cp), d6 = glm::dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return glm::length(cp);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return glm::length(p - (a + ac * (d2 / (d2 - d6))));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return glm::length(p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))));
  const double denom = 1.0 / (va + vb + vc);
  return glm::length(p - (a + ab * (vb * denom) + ac * (vc * denom)));
}

}  // namespace hyb
