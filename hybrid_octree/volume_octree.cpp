// Volume Octree construction: Boada, Navazo and Scopigno, "Multiresolution volume visualization
// with a texture-based octree", The Visual Computer 17(3), 2001; nodal-error lists as docs/volume-octree.md specifies.
#include "hybrid_octree/volume_octree.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <optional>

#include <omp.h>

#include "volume/core/error.h"
#include "volume/sample_window.h"

namespace hyb {

namespace {

int ceilLog2(int v) {
  int l = 0;
  while ((1 << l) < v) ++l;
  return l;
}

// Shape of the tree implied by the grid and the leaf edge.
struct Geometry {
  glm::ivec3 dims{0};
  int depth = 0;      // L
  int leafEdge = 1;   // cells, ≤ 2^L
  int leafLevel = 0;  // level of the leaves
  std::vector<glm::ivec3> grid;  // grid[k]: nodes per axis at level k (all of them exist)

  int edgeAt(int level) const { return 1 << (depth - level); }
  size_t countAt(int level) const { return size_t(grid[level].x) * grid[level].y * grid[level].z; }
  size_t dense(int level, const glm::ivec3& i) const {
    return size_t(i.x) + size_t(grid[level].x) * (size_t(i.y) + size_t(grid[level].y) * size_t(i.z));
  }
  glm::ivec3 unravel(int level, size_t d) const {
    const glm::ivec3& g = grid[level];
    return glm::ivec3(int(d % g.x), int((d / g.x) % g.y), int(d / (size_t(g.x) * g.y)));
  }
};

Geometry geometryFor(const glm::ivec3& dims, int leafEdge) {
  Geometry g;
  g.dims = dims;
  const glm::ivec3 cells = glm::max(dims - 1, glm::ivec3(1));
  g.depth = ceilLog2(std::max({cells.x, cells.y, cells.z}));
  g.leafEdge = std::min(leafEdge, 1 << g.depth);
  g.leafLevel = g.depth - ceilLog2(g.leafEdge);
  for (int k = 0; k <= g.leafLevel; ++k) {
    const int e = g.edgeAt(k);
    g.grid.push_back((cells + e - 1) / e);
  }
  return g;
}

// Breadth-first node array with the structural fields set, and each node's dense index.
struct Skeleton {
  std::vector<OctreeNode> nodes;
  std::vector<uint32_t> dense;
  size_t errorCount = 0;
};

// Calls @p f(slot, child's grid index) for each child a node of @p level at @p origin has in the
// grid g implies (every node whose cells overlap the grid exists).
template <class F>
void forEachChild(const Geometry& g, int level, const glm::ivec3& origin, F&& f) {
  const glm::ivec3 idx = origin / g.edgeAt(level);
  for (int slot = 0; slot < 8; ++slot) {
    const glm::ivec3 c = idx * 2 + childOffset(slot, 1);
    if (!glm::any(glm::greaterThanEqual(c, g.grid[size_t(level) + 1]))) f(slot, c);
  }
}

Skeleton buildSkeleton(const Geometry& g) {
  Skeleton s;
  size_t total = 0;
  for (int k = 0; k <= g.leafLevel; ++k) total += g.countAt(k);
  if (total > std::numeric_limits<uint32_t>::max()) HYB_THROW(ValueError, "octree would need ", total, " nodes");
  s.nodes.reserve(total);
  s.dense.reserve(total);
  s.nodes.push_back(OctreeNode{});
  s.dense.push_back(0);
  for (size_t i = 0; i < s.nodes.size(); ++i) {
    OctreeNode& n = s.nodes[i];
    n.errorOffset = uint32_t(s.errorCount);
    s.errorCount += size_t(g.depth - n.level + 1);
    if (n.level == g.leafLevel) continue;
    const int childLevel = n.level + 1;
    uint8_t mask = 0;
    const uint32_t first = uint32_t(s.nodes.size());
    const glm::ivec3 origin(n.origin);
    forEachChild(g, n.level, origin, [&](int slot, const glm::ivec3& c) {
      mask |= uint8_t(1u << slot);
      OctreeNode child;
      child.level = uint8_t(childLevel);
      child.origin = glm::u16vec3(origin + childOffset(slot, g.edgeAt(childLevel)));
      s.nodes.push_back(child);  // may reallocate: `n` is not used after this loop
      s.dense.push_back(uint32_t(g.dense(childLevel, c)));
    });
    s.nodes[i].childMask = mask;
    s.nodes[i].firstChild = mask ? first : 0;
  }
  return s;
}

// Per-level arrays in dense order, filled bottom-up before flattening.
struct LevelData {
  std::vector<float> minV, maxV;
  std::vector<float> err;  // countAt(k) × (depth − k + 1)
};

// The error loops are max-reductions; `omp simd` lets the compiler vectorize them (a plain float
// max-reduction is not vectorized without -ffast-math, which would also drop our finiteness checks).

// Largest |s[x] − (a + slope·x)| over x in [0, n).
float maxLinearResidual(const float* s, int n, float a, float slope) {
  float m = 0.0f;
#pragma omp simd reduction(max : m)
  for (int x = 0; x < n; ++x) m = std::max(m, std::fabs(s[x] - (a + slope * float(x))));
  return m;
}

// Largest |s[x] − (a[x] + (b[x] − a[x])·w)| over x in [0, n).
float maxLerpResidual(const float* s, const float* a, const float* b, float w, int n) {
  float m = 0.0f;
#pragma omp simd reduction(max : m)
  for (int x = 0; x < n; ++x) m = std::max(m, std::fabs(s[x] - (a[x] + (b[x] - a[x]) * w)));
  return m;
}

// Knots of the sub-grid of spacing e along one axis of a node, local coordinates 0…lim (lim: last real
// sample): min(j·e, lim). For each sample t, the knots around it and its interpolation weight.
struct AxisKnots {
  std::vector<int> left, right;
  std::vector<float> w;
  std::vector<int> knots;

  void reset(int e, int lim) {
    left.resize(size_t(lim) + 1);
    right.resize(left.size());
    w.resize(left.size());
    knots.clear();
    for (int j = 0;; j += e) {
      knots.push_back(std::min(j, lim));
      if (j >= lim) break;
    }
    for (int t = 0; t <= lim; ++t) {
      const int l = std::min(t / e * e, lim), r = std::min(l + e, lim);
      left[size_t(t)] = l;
      right[size_t(t)] = r;
      w[size_t(t)] = r > l ? float(t - l) / float(r - l) : 0.0f;
    }
  }
};

// The leaves of one row (those whose origin has z = row · leaf edge): min/max over their samples
// and ε_p for every sub-level, computed inside a cached block; the window holds their planes. The
// trilinear approximation of spacing e is evaluated separably (x, then y, then z).
void buildLeafRow(const SampleWindow& v, const Geometry& g, const KnotPyramid& knots, int row, LevelData* out) {
  const int E = g.leafEdge, B = E + 1, levels = g.depth - g.leafLevel + 1;
  const glm::ivec3 grid = g.grid[size_t(g.leafLevel)];
  const size_t begin = size_t(row) * size_t(grid.x) * size_t(grid.y), end = begin + size_t(grid.x) * size_t(grid.y);
  const glm::ivec3 dims = v.dims();
#pragma omp parallel
  {
    std::vector<float> block(size_t(B) * B * B), ax(block.size()), by(block.size()), filtered(block.size());
    AxisKnots kx, ky, kz;
    auto at = [B](std::vector<float>& a, int x, int y, int z) -> float& { return a[size_t(x) + size_t(B) * (y + size_t(B) * z)]; };
#pragma omp for schedule(dynamic, 8)
    for (size_t li = begin; li < end; ++li) {
      const glm::ivec3 o = g.unravel(g.leafLevel, li) * E;
      const glm::ivec3 lim = glm::min(glm::ivec3(E), dims - 1 - o);  // last local index of a real sample
      float lo = std::numeric_limits<float>::max(), hi = -lo;
      for (int z = 0; z <= lim.z; ++z)
        for (int y = 0; y <= lim.y; ++y) {
          float* dst = &at(block, 0, y, z);
          v.readRow(o.x, o.y + y, o.z + z, lim.x + 1, dst);
          for (int x = 0; x <= lim.x; ++x) {
            lo = std::min(lo, dst[x]);
            hi = std::max(hi, dst[x]);
          }
        }
      out->minV[li] = lo;
      out->maxV[li] = hi;
      float* errs = &out->err[li * size_t(levels)];
      for (int p = 0; p + 1 < levels; ++p) {
        const int e = E >> p;
        kx.reset(e, lim.x);
        ky.reset(e, lim.y);
        kz.reset(e, lim.z);
        // The knot values: the samples, or the prefiltered values where the spacing asks for them.
        std::vector<float>* knotValues = &block;
        if (knots.covers(e)) {
          for (int Z : kz.knots)
            for (int Y : ky.knots)
              for (int X : kx.knots) at(filtered, X, Y, Z) = knots.at(e, o + glm::ivec3(X, Y, Z));
          knotValues = &filtered;
        }
        // x: rows on the knot lattice of (y, z).
        for (int Z : kz.knots)
          for (int Y : ky.knots) {
            const float* src = &at(*knotValues, 0, Y, Z);
            float* dst = &at(ax, 0, Y, Z);
            for (int x = 0; x <= lim.x; ++x) {
              const float a = src[kx.left[size_t(x)]], b = src[kx.right[size_t(x)]];
              dst[x] = a + (b - a) * kx.w[size_t(x)];
            }
          }
        // y: planes on the knots of z.
        for (int Z : kz.knots)
          for (int y = 0; y <= lim.y; ++y) {
            const float* a = &at(ax, 0, ky.left[size_t(y)], Z);
            const float* b = &at(ax, 0, ky.right[size_t(y)], Z);
            float* dst = &at(by, 0, y, Z);
            const float w = ky.w[size_t(y)];
            for (int x = 0; x <= lim.x; ++x) dst[x] = a[x] + (b[x] - a[x]) * w;
          }
        // z: compare with the samples.
        float eps = 0.0f;
        for (int z = 0; z <= lim.z; ++z)
          for (int y = 0; y <= lim.y; ++y) {
            const float* a = &at(by, 0, y, kz.left[size_t(z)]);
            const float* b = &at(by, 0, y, kz.right[size_t(z)]);
            const float* s = &at(block, 0, y, z);
            eps = std::max(eps, maxLerpResidual(s, a, b, kz.w[size_t(z)], lim.x + 1));
          }
        errs[p] = eps;
      }
    }
  }
}

// The samples of the lattice of spacing s (positions that are multiples of s, or the grid's last
// index): the corners of every node of edge s or more, kept while the volume streams past.
struct CornerSamples {
  int spacing = 0;
  glm::ivec3 count{0};
  std::vector<float> values;

  CornerSamples(const glm::ivec3& dims, int s) : spacing(s) {
    if (s == 0) return;
    count = knotCounts(dims, s);
    values.resize(size_t(count.x) * size_t(count.y) * size_t(count.z));
  }
  void addPlane(const SampleWindow& w, int z) {
    const glm::ivec3 n = w.dims();
    const int k = spacing ? knotIndexAt(z, spacing, n.z) : -1;
    if (k < 0) return;
    w.visitPlane(z, [&](const auto* d) {
      for (int j = 0; j < count.y; ++j)
        for (int i = 0; i < count.x; ++i)
          values[size_t(i) + size_t(count.x) * (size_t(j) + size_t(count.y) * size_t(k))] =
              float(d[size_t(knotPosition(i, spacing, n.x)) + size_t(n.x) * size_t(knotPosition(j, spacing, n.y))]);
    });
  }
  float at(const glm::ivec3& q, const glm::ivec3& n) const {
    const glm::ivec3 j(knotIndexAt(q.x, spacing, n.x), knotIndexAt(q.y, spacing, n.y), knotIndexAt(q.z, spacing, n.z));
    return values[size_t(j.x) + size_t(count.x) * (size_t(j.y) + size_t(count.y) * size_t(j.z))];
  }
};

// ε_0 of every node above the leaves, straight from the samples, all levels as each plane streams
// past (each row is scanned from cache for every level): along a row of fixed (y, z) a node's
// trilinear approximation is linear in x, so each node's piece of a row costs one bilinear pair and
// a vectorized scan. The far corners are the grid's last samples where a node overhangs the grid
// (position clamping); samples on a face shared by two nodes count in both.
class DirectErrors {
 public:
  DirectErrors(const Geometry& g, const KnotPyramid& knots, const CornerSamples& samples) : mG(g), mLevels(g.leafLevel) {
    const glm::ivec3 dims = g.dims;
    mCorners.resize(size_t(mLevels));
    for (int k = 0; k < mLevels; ++k) {
      const int E = g.edgeAt(k);
      mCorners[size_t(k)].resize(g.countAt(k));
      for (size_t node = 0; node < g.countAt(k); ++node) {
        const glm::ivec3 o = g.unravel(k, node) * E, hi = glm::min(o + E, dims - 1);
        for (int c = 0; c < 8; ++c) {
          const glm::ivec3 q(c & 1 ? hi.x : o.x, c & 2 ? hi.y : o.y, c & 4 ? hi.z : o.z);
          mCorners[size_t(k)][node][size_t(c)] = knots.covers(E) ? knots.at(E, q) : samples.at(q, dims);
        }
      }
    }
    mErr.resize(size_t(omp_get_max_threads()));
    for (auto& e : mErr) {
      e.resize(size_t(mLevels));
      for (int k = 0; k < mLevels; ++k) e[size_t(k)].assign(g.countAt(k), 0.0f);
    }
  }

  void addPlane(const SampleWindow& v, int z) {
    if (mLevels == 0) return;
    const glm::ivec3 dims = mG.dims;
    auto inverse = [](int d) { return d > 0 ? 1.0f / float(d) : 0.0f; };
    // The nodes of level k along one axis whose closed extent [o, min(o + E, n − 1)] holds sample t.
    auto nodesHolding = [&](int k, int a, int t, int* first, int* last) {
      const int E = mG.edgeAt(k);
      *last = std::min(t / E, mG.grid[size_t(k)][a] - 1);
      *first = t % E == 0 && t > 0 ? std::max(t / E - 1, 0) : *last;
    };
#pragma omp parallel
    {
      std::vector<std::vector<float>>& err = mErr[size_t(omp_get_thread_num())];
      std::vector<float> rowValues(size_t(dims.x));
      const float* row = rowValues.data();
#pragma omp for schedule(dynamic, 8)
      for (int y = 0; y < dims.y; ++y) {
        v.readRow(0, y, z, dims.x, rowValues.data());
        for (int k = 0; k < mLevels; ++k) {
          const int E = mG.edgeAt(k);
          int z0, z1, y0, y1;
          nodesHolding(k, 2, z, &z0, &z1);
          nodesHolding(k, 1, y, &y0, &y1);
          for (int iz = z0; iz <= z1; ++iz)
            for (int iy = y0; iy <= y1; ++iy)
              for (int ix = 0; ix < mG.grid[size_t(k)].x; ++ix) {
                const size_t node = mG.dense(k, glm::ivec3(ix, iy, iz));
                const glm::ivec3 o = glm::ivec3(ix, iy, iz) * E, hi = glm::min(o + E, dims - 1);
                const std::array<float, 8>& c = mCorners[size_t(k)][node];
                const float wz = float(z - o.z) * inverse(hi.z - o.z), wy = float(y - o.y) * inverse(hi.y - o.y);
                auto bilerp = [&](int cx) {
                  const float a = c[size_t(cx)] + (c[size_t(cx | 2)] - c[size_t(cx)]) * wy;
                  const float b = c[size_t(cx | 4)] + (c[size_t(cx | 6)] - c[size_t(cx | 4)]) * wy;
                  return a + (b - a) * wz;
                };
                const float a = bilerp(0), b = bilerp(1);
                float& e = err[size_t(k)][node];
                e = std::max(e, maxLinearResidual(row + o.x, hi.x - o.x + 1, a, (b - a) * inverse(hi.x - o.x)));
              }
        }
      }
    }
  }

  // ε_0 per level and node (dense order), the largest over every thread's share.
  std::vector<std::vector<float>> finish() {
    std::vector<std::vector<float>> result = std::move(mErr.front());
    for (size_t t = 1; t < mErr.size(); ++t)
      for (int k = 0; k < mLevels; ++k)
        for (size_t node = 0; node < result[size_t(k)].size(); ++node)
          result[size_t(k)][node] = std::max(result[size_t(k)][node], mErr[t][size_t(k)][node]);
    return result;
  }

 private:
  const Geometry& mG;
  int mLevels;  // 0 … leafLevel − 1
  std::vector<std::vector<std::array<float, 8>>> mCorners;  // each node's corner knots (bit 0: x = hi.x, 1: y = hi.y, 2: z = hi.z)
  std::vector<std::vector<std::vector<float>>> mErr;        // per thread, level and node
};

}  // namespace

namespace {

// One pass over @p planes, @p held of them at a time: @p each(window, z) once plane z is in, and
// @p visitor's plane z − 1 then (its gradients need plane z), its last plane after the pass.
void streamPlanes(PlaneSource& planes, int held, PlaneVisitor* visitor, const std::function<void(const SampleWindow&, int)>& each,
                  ProgressTask* progress) {
  const int n = planes.dims().z;
  planes.rewind();
  SampleWindow w(planes, visitor ? std::max(held, 3) : held);
  for (int z = 0; z < n; ++z) {
    w.load(planes);
    if (each) each(w, z);
    if (visitor && z > 0) visitor->plane(w, z - 1);
    if (progress) progress->advance();
  }
  if (visitor) visitor->plane(w, n - 1);
}

}  // namespace

VolumeOctree VolumeOctree::build(const Volume& volume, const VolumeOctreeOptions& options) {
  HYB_CHECK(!volume.empty());
  const std::unique_ptr<PlaneSource> planes = planesOf(volume);
  return build(*planes, options);
}

VolumeOctree VolumeOctree::build(PlaneSource& planes, const VolumeOctreeOptions& options, PlaneVisitor* visitor) {
  if (options.leafEdge < 1 || options.leafEdge > 256 || (options.leafEdge & (options.leafEdge - 1)))
    HYB_THROW(ValueError, "leaf edge ", options.leafEdge, " invalid (expected a power of two in 1..256)");
  const glm::ivec3 dims = planes.dims();
  const Geometry g = geometryFor(dims, options.leafEdge);
  ProgressTask task(options.progress, "volume octree", 2 * uint64_t(dims.z));  // two passes over the planes

  // First pass: the prefiltered knots (their 16-bit range is known only at the end) and the corner
  // samples of the nodes above the leaves.
  CornerSamples cornerSamples(dims, g.leafLevel > 0 ? g.edgeAt(g.leafLevel - 1) : 0);
  KnotPyramid knots;
  {
    std::optional<KnotPyramid::Builder> pyramid;
    if (options.prefilter) pyramid.emplace(dims);
    streamPlanes(planes, 1, nullptr, [&](const SampleWindow& w, int z) {
      if (pyramid) pyramid->add([&](int y, float* out) { w.readRow(0, y, z, dims.x, out); });
      cornerSamples.addPlane(w, z);
    }, &task);
    if (pyramid) knots = pyramid->finish();
  }

  // Second pass: each plane's rows for the direct errors above the leaves, a row of leaves once its
  // last plane is in, and the visitor's plane once the next one is (its gradients need it).
  if (visitor) {
    visitor->begin(knots, g.depth);
    visitor->beginPass(0);
  }
  std::vector<LevelData> levels(size_t(g.leafLevel) + 1);
  {
    LevelData& leaves = levels[size_t(g.leafLevel)];
    const size_t count = g.countAt(g.leafLevel);
    leaves.minV.resize(count);
    leaves.maxV.resize(count);
    leaves.err.assign(count * size_t(g.depth - g.leafLevel + 1), 0.0f);
  }
  std::vector<std::vector<float>> upperErrors;
  {
    DirectErrors direct(g, knots, cornerSamples);
    int row = 0;  // next row of leaves
    streamPlanes(planes, g.leafEdge + 1, visitor, [&](const SampleWindow& w, int z) {
      direct.addPlane(w, z);
      for (; row < g.grid[size_t(g.leafLevel)].z && std::min(row * g.leafEdge + g.leafEdge, dims.z - 1) == z; ++row)
        buildLeafRow(w, g, knots, row, &levels[size_t(g.leafLevel)]);
    }, &task);
    HYB_CHECK(row == g.grid[size_t(g.leafLevel)].z);
    upperErrors = direct.finish();
  }
  if (visitor && visitor->passes() > 1) {
    ProgressTask more(options.progress, "knot store", uint64_t(visitor->passes() - 1) * uint64_t(dims.z));
    visitPlanes(planes, *visitor, 1, &more);
  }
  for (int k = g.leafLevel - 1; k >= 0; --k) {
    LevelData& d = levels[size_t(k)];
    const LevelData& c = levels[size_t(k) + 1];
    const size_t count = g.countAt(k);
    const size_t nErr = size_t(g.depth - k + 1);
    d.minV.assign(count, std::numeric_limits<float>::max());
    d.maxV.assign(count, -std::numeric_limits<float>::max());
    d.err.assign(count * nErr, 0.0f);
    const std::vector<float>& eps0 = upperErrors[size_t(k)];
    for (size_t i = 0; i < count; ++i) {
      const glm::ivec3 idx = g.unravel(k, i);
      float* e = &d.err[i * nErr];
      e[0] = eps0[i];
      forEachChild(g, k, idx * g.edgeAt(k), [&](int, const glm::ivec3& ci) {
        const size_t cd = g.dense(k + 1, ci);
        d.minV[i] = std::min(d.minV[i], c.minV[cd]);
        d.maxV[i] = std::max(d.maxV[i], c.maxV[cd]);
        const float* ce = &c.err[cd * (nErr - 1)];
        for (size_t p = 1; p < nErr; ++p) e[p] = std::max(e[p], ce[p - 1]);  // ε_p(n) = max_c ε_(p−1)(c)
      });
    }
  }

  // Flatten into the breadth-first array.
  Skeleton s = buildSkeleton(g);
  VolumeOctree t;
  t.mDims = dims;
  t.mDepth = g.depth;
  t.mLeafEdge = g.leafEdge;
  t.mErrors.resize(s.errorCount);
  for (size_t i = 0; i < s.nodes.size(); ++i) {
    OctreeNode& n = s.nodes[i];
    const LevelData& d = levels[n.level];
    const size_t di = s.dense[i], nErr = size_t(g.depth - n.level + 1);
    n.minValue = d.minV[di];
    n.maxValue = d.maxV[di];
    std::copy_n(&d.err[di * nErr], nErr, &t.mErrors[n.errorOffset]);
  }
  t.mNodes = std::move(s.nodes);
  t.mKnots = std::move(knots);
  return t;
}

void visitPlanes(PlaneSource& planes, PlaneVisitor& visitor, int first, ProgressTask* progress) {
  for (int pass = first; pass < visitor.passes(); ++pass) {
    visitor.beginPass(pass);
    streamPlanes(planes, 3, &visitor, {}, progress);
  }
}

VolumeOctree VolumeOctree::fromParts(glm::ivec3 dims, int leafEdge, std::vector<OctreeNode> nodes,
                                     std::vector<float> errors, const std::string& source, const Volume* prefilteredFrom) {
  VolumeOctree t = checkedShell(dims, leafEdge, nodes, errors, source, prefilteredFrom);
  t.mNodes = std::move(nodes);
  t.mErrors = std::move(errors);
  return t;
}

VolumeOctree VolumeOctree::fromParts(glm::ivec3 dims, int leafEdge, const MappedParts& parts, const std::string& source,
                                     const Volume* prefilteredFrom) {
  const std::span<const OctreeNode> nodes = parts.nodes;
  const std::span<const float> errors = parts.errors;
  std::shared_ptr<const InputFile::Mapping> owner = parts.owner;
  HYB_CHECK(owner);
  VolumeOctree t = checkedShell(dims, leafEdge, nodes, errors, source, prefilteredFrom);
  t.mOwner = std::move(owner);
  t.mMappedNodes = nodes;
  t.mMappedErrors = errors;
  return t;
}

VolumeOctree VolumeOctree::checkedShell(glm::ivec3 dims, int leafEdge, std::span<const OctreeNode> nodes, std::span<const float> errors,
                                        const std::string& source, const Volume* prefilteredFrom) {
  validateDims(dims, source);
  if (leafEdge < 1 || leafEdge > 256 || (leafEdge & (leafEdge - 1)))
    HYB_THROW(IoError, source, ": stored leaf edge ", leafEdge, " invalid (expected a power of two in 1..256)");
  const Geometry g = geometryFor(dims, leafEdge);
  uint64_t expectedNodes = 0, expectedErrors = 0;
  for (int k = 0; k <= g.leafLevel; ++k) {
    expectedNodes += g.countAt(k);
    expectedErrors += g.countAt(k) * uint64_t(g.depth - k + 1);
  }
  if (nodes.size() != expectedNodes || errors.size() != expectedErrors)
    HYB_THROW(IoError, source, ": octree holds ", nodes.size(), " nodes and ", errors.size(), " errors, expected ",
              expectedNodes, " and ", expectedErrors, " for dims ", dims.x, "x", dims.y, "x", dims.z);
  // The shape buildSkeleton makes, checked with the stored array as its own breadth-first queue
  // (the expected array is never made: it would double the octree's memory on a large scene).
  const auto mismatch = [&](size_t i) {
    HYB_THROW(IoError, source, ": octree node ", i, " does not match the structure of a ", dims.x, "x", dims.y, "x", dims.z, " grid");
  };
  if (nodes[0].level != 0 || nodes[0].origin != glm::u16vec3(0)) mismatch(0);
  uint64_t next = 1, errorOffset = 0;
  for (size_t i = 0; i < nodes.size(); ++i) {
    const OctreeNode& a = nodes[i];
    if (a.errorOffset != errorOffset) mismatch(i);
    errorOffset += uint64_t(g.depth - a.level + 1);
    uint8_t mask = 0;
    const uint64_t first = next;
    if (a.level != g.leafLevel)
      forEachChild(g, a.level, glm::ivec3(a.origin), [&](int slot, const glm::ivec3&) {
        mask |= uint8_t(1u << slot);
        if (next >= nodes.size()) mismatch(i);
        const OctreeNode& c = nodes[next++];
        if (c.level != a.level + 1 || glm::ivec3(c.origin) != glm::ivec3(a.origin) + childOffset(slot, g.edgeAt(a.level + 1)))
          mismatch(size_t(next - 1));
      });
    if (a.childMask != mask || (mask && a.firstChild != first)) mismatch(i);
  }
  for (size_t i = 0; i < nodes.size(); ++i) {
    const OctreeNode& a = nodes[i];
    if (!std::isfinite(a.minValue) || !std::isfinite(a.maxValue) || a.minValue > a.maxValue)
      HYB_THROW(IoError, source, ": octree node ", i, " has an invalid value range");
  }
  for (float e : errors)
    if (!std::isfinite(e) || e < 0.0f) HYB_THROW(IoError, source, ": octree holds an invalid nodal error ", e);
  VolumeOctree t;
  t.mDims = dims;
  t.mDepth = g.depth;
  t.mLeafEdge = g.leafEdge;
  if (prefilteredFrom) {
    HYB_CHECK(prefilteredFrom->dims() == dims);
    t.mKnots = KnotPyramid(*prefilteredFrom);
  }
  return t;
}

namespace {

// Knots spaced @p step from @p origin up to @p end (exclusive of overshoot), clamped at the grid.
KnotLattice makeLattice(const glm::ivec3& origin, int step, const glm::ivec3& end, const glm::ivec3& dims) {
  KnotLattice k;
  k.origin = origin;
  k.step = step;
  k.last = glm::min(end, dims - 1);
  k.dims = (k.last - origin + step - 1) / step + 1;
  return k;
}

}  // namespace

KnotLattice VolumeOctree::lattice(const OctreeNode& n, int p) const {
  HYB_DCHECK(p >= 0 && p <= maxLevel(n));
  const glm::ivec3 o(n.origin);
  return makeLattice(o, edge(n) >> p, o + edge(n), mDims);
}

KnotLattice VolumeOctree::coarseLattice(const OctreeNode& n, int p) const {
  HYB_DCHECK(p >= 0 && p <= maxLevel(n));
  const int step = 2 * (edge(n) >> p);
  const glm::ivec3 o(n.origin), lo = o / step * step, hi = (o + edge(n) + step - 1) / step * step;
  return makeLattice(lo, step, hi, mDims);
}

void VolumeOctree::validateAgainst(const Volume& volume, const std::string& source) const {
  HYB_CHECK(volume.dims() == mDims);
  const auto fail = [&](size_t i, const char* what) {
    HYB_THROW(IoError, source, ": octree node ", i, " ", what, " (the scene's octree does not describe its volume)");
  };
  const std::span<const OctreeNode> all = nodes();
  std::vector<uint8_t> wrong(all.size(), 0);
#pragma omp parallel for schedule(dynamic, 64)
  for (size_t i = 0; i < all.size(); ++i) {
    const OctreeNode& n = all[i];
    if (!n.isLeaf()) continue;
    glm::ivec3 lo, hi;
    voxelBox(n, &lo, &hi);
    float mn = volume.at(lo.x, lo.y, lo.z), mx = mn;
    for (int z = lo.z; z <= hi.z; ++z)
      for (int y = lo.y; y <= hi.y; ++y)
        for (int x = lo.x; x <= hi.x; ++x) {
          const float v = volume.at(x, y, z);
          mn = std::min(mn, v);
          mx = std::max(mx, v);
        }
    wrong[i] = mn != n.minValue || mx != n.maxValue;
  }
  for (size_t i = all.size(); i-- > 0;) {
    const OctreeNode& n = all[i];
    if (wrong[i]) fail(i, "has a min/max other than its samples'");
    if (errors(n).back() != 0.0f) fail(i, "has a non-zero error at full resolution");
    if (n.isLeaf()) continue;
    float mn = std::numeric_limits<float>::infinity(), mx = -mn;
    for (int c = 0; c < n.childCount(); ++c) {
      mn = std::min(mn, all[n.firstChild + uint32_t(c)].minValue);
      mx = std::max(mx, all[n.firstChild + uint32_t(c)].maxValue);
    }
    if (mn != n.minValue || mx != n.maxValue) fail(i, "has a min/max other than its children's");
  }
}

void VolumeOctree::voxelBox(const OctreeNode& n, glm::ivec3* lo, glm::ivec3* hi) const {
  *lo = glm::ivec3(n.origin);
  *hi = glm::min(*lo + edge(n), mDims - 1);
}

std::vector<VoxelBlock> isoBlocks(const VolumeOctree& octree, float iso) {
  std::vector<VoxelBlock> blocks;
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const OctreeNode& n = octree.nodes()[stack.back()];
    stack.pop_back();
    if (!(n.minValue < iso && n.maxValue >= iso)) continue;
    if (n.isLeaf()) {
      VoxelBlock b;
      octree.voxelBox(n, &b.lo, &b.hi);
      blocks.push_back(b);
      continue;
    }
    for (int slot = 7; slot >= 0; --slot)
      if (n.childMask & (1u << slot)) stack.push_back(childIndex(n, slot));
  }
  return blocks;
}

}  // namespace hyb
