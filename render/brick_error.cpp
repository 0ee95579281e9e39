#include "render/brick_error.h"

#include <algorithm>
#include <bit>
#include <cmath>

#include "hybrid_octree/knot_source.h"
#include "volume/parallel.h"

namespace hyb {

namespace {


// The memo's key of brick (node, p).
uint64_t brickKey(uint32_t node, int p) { return uint64_t(node) * 64 + uint64_t(p); }

// Index of @p p in an x-fastest array of @p dims.
size_t linear(const glm::ivec3& p, const glm::ivec3& dims) { return size_t(p.x) + size_t(dims.x) * (size_t(p.y) + size_t(dims.y) * size_t(p.z)); }

// Value of the trilinear interpolation of corners @p c (slot order x | y<<1 | z<<2) at weights
// @p w, and in @p d its derivative along each weight.
float trilinear(const float c[8], const glm::vec3& w, glm::vec3* d) {
  const float x00 = c[0] + (c[1] - c[0]) * w.x, x10 = c[2] + (c[3] - c[2]) * w.x;
  const float x01 = c[4] + (c[5] - c[4]) * w.x, x11 = c[6] + (c[7] - c[6]) * w.x;
  const float y0 = x00 + (x10 - x00) * w.y, y1 = x01 + (x11 - x01) * w.y;
  const float dx0 = (c[1] - c[0]) + ((c[3] - c[2]) - (c[1] - c[0])) * w.y;
  const float dx1 = (c[5] - c[4]) + ((c[7] - c[6]) - (c[5] - c[4])) * w.y;
  *d = glm::vec3(dx0 + (dx1 - dx0) * w.z, (x10 - x00) + ((x11 - x01) - (x10 - x00)) * w.z, y1 - y0);
  return y0 + (y1 - y0) * w.z;
}

// Headlight shading as both renderers do it: 0.25 + 0.75 |cos| between the gradient and the ray.
float shade(const glm::vec3& g, const glm::vec3& dir) {
  const float gg = glm::dot(g, g);
  return gg > 1e-20f ? 0.25f + 0.75f * std::abs(glm::dot(g, dir)) / std::sqrt(gg) : 1.0f;
}

}  // namespace

BrickImageError::BrickImageError(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, const Camera& camera, const BrickErrorClipping& clipping)
    : mVolume(volume), mOctree(octree), mInMemory(volume, octree), mKnots(clipping.knots ? *clipping.knots : mInMemory), mTf(tf), mCamera(camera),
      mKept(clipping.kept), mVoi(clipping.voi), mLayout(volume.minValue(), volume.maxValue(), tf) {
  mTable.resize(LutLayout::kSize);
  for (int k = 0; k < LutLayout::kSize; ++k) {
    const glm::vec4 c = tf.lookup(mLayout.value(k));
    mTable[size_t(k)] = {glm::vec3(c), c.a, -std::log(std::max(1e-6f, 1.0f - c.a))};
  }
  buildTransmittance();
  buildVisibleBlocks();
}

void BrickImageError::buildVisibleBlocks() {
  // The octree's leaves: their ranges cover their closed boxes, all a sample's cell reads.
  mBlock = mOctree.leafEdge();
  mBlockDims = glm::max((mVolume.dims() - 1 + mBlock - 1) / mBlock, glm::ivec3(1));
  mVisibleBlock.assign(size_t(mBlockDims.x) * mBlockDims.y * mBlockDims.z, 0);
  for (const OctreeNode& n : mOctree.nodes()) {
    if (!n.isLeaf() || !(mTf.maxAlpha(n.minValue, n.maxValue) > 0.0f)) continue;
    const glm::ivec3 lo = glm::ivec3(n.origin) / mBlock, hi = glm::min((glm::ivec3(n.origin) + mOctree.edge(n)) / mBlock, mBlockDims) - 1;
    for (int z = lo.z; z <= hi.z; ++z)
      for (int y = lo.y; y <= hi.y; ++y)
        for (int x = lo.x; x <= hi.x; ++x) mVisibleBlock[linear({x, y, z}, mBlockDims)] = 1;
  }
}

float BrickImageError::extinction(const Entry& e, const glm::vec3& x) const {
  if (e.kappa <= 0.0f || glm::dot(glm::vec3(mKept), x) + mKept.w < 0.0f) return 0.0f;
  if (!mVoi) return e.kappa;
  return -std::log(std::max(1e-6f, 1.0f - std::min(1.0f, e.alpha * float(mVoi->factor(glm::dvec3(x))))));
}

const BrickImageError::Entry& BrickImageError::classify(float value) const {
  return mTable[size_t(mLayout.entry(value))];
}

void BrickImageError::buildTransmittance() {
  const glm::ivec3 dims = mVolume.dims();
  // Four voxels apart up to 256 voxels across, a power of two times more beyond.
  const int stride = int(std::bit_floor(unsigned(std::max(1, (std::max({dims.x, dims.y, dims.z}) + 255) / 256))));
  mGrid = 4 * stride;
  const int kGrid = mGrid;
  mGridDims = (dims - 1 + kGrid - 1) / kGrid + 1;
  const size_t count = size_t(mGridDims.x) * mGridDims.y * mGridDims.z;
  auto index = [&](const glm::ivec3& g) { return linear(g, mGridDims); };
  // Extinction per grid point: the mean over the knots of spacing `stride` nearest to it (every
  // voxel up to four apart; beyond, the knots of a lattice as a brick holds them), read a plane at
  // a time through the knot source.
  std::vector<float> kappa(count, 0.0f);
  std::vector<uint32_t> voxels(count, 0);
  const glm::ivec3 knots = (dims - 1) / stride + 1;  // those at multiples of the stride
  std::vector<float> plane(size_t(knots.x) * size_t(knots.y));
  for (int k = 0; k < knots.z; ++k) {
    mKnots.read(stride, glm::ivec3(0, 0, k), glm::ivec3(knots.x, knots.y, 1), plane.data(), nullptr);
    for (int j = 0; j < knots.y; ++j)
      for (int i = 0; i < knots.x; ++i) {
        const glm::ivec3 p = glm::ivec3(i, j, k) * stride;
        const size_t g = index(glm::min((p + kGrid / 2) / kGrid, mGridDims - 1));
        kappa[g] += extinction(classify(plane[size_t(i) + size_t(knots.x) * size_t(j)]), glm::vec3(p) * glm::vec3(mVolume.spacing()));
        ++voxels[g];
      }
  }
  for (size_t g = 0; g < count; ++g) kappa[g] = voxels[g] > 0 ? kappa[g] / float(voxels[g]) : 0.0f;
  // March from every grid point towards the eye through the nearest points' extinction.
  const glm::dvec3 spacing = mVolume.spacing(), extent = mVolume.extentMm();
  const double step = kGrid * std::min({spacing.x, spacing.y, spacing.z});
  mTransmittance.assign(count, 1.0f);
#pragma omp parallel for schedule(dynamic, 1)
  for (int z = 0; z < mGridDims.z; ++z)
    for (int y = 0; y < mGridDims.y; ++y)
      for (int x = 0; x < mGridDims.x; ++x) {
        const glm::dvec3 p = glm::dvec3(glm::min(glm::ivec3(x, y, z) * kGrid, dims - 1)) * spacing;
        const glm::dvec3 toEye = mCamera.ortho ? -mCamera.forward() : mCamera.eye - p;
        if (glm::dot(toEye, toEye) == 0.0) continue;
        const glm::dvec3 dir = glm::normalize(toEye);
        double tau = 0.0;
        for (double s = 0.5 * step; tau < 16.0; s += step) {
          const glm::dvec3 q = p + dir * s;
          if (glm::any(glm::lessThan(q, glm::dvec3(0.0))) || glm::any(glm::greaterThan(q, extent))) break;
          if (!mCamera.ortho && s * s >= glm::dot(toEye, toEye)) break;  // reached the eye inside the volume
          const glm::ivec3 g = glm::min(glm::ivec3(q / spacing / double(kGrid) + 0.5), mGridDims - 1);
          tau += double(kappa[index(g)]) * step;
        }
        mTransmittance[index(glm::ivec3(x, y, z))] = float(std::exp(-tau));
      }
}

float BrickImageError::transmittance(const glm::vec3& voxel) const {
  const glm::ivec3 dims = mVolume.dims();
  const int kGrid = mGrid;
  glm::ivec3 j;
  glm::vec3 w;
  for (int a = 0; a < 3; ++a) {
    if (mGridDims[a] < 2) {
      j[a] = 0;
      w[a] = 0.0f;
      continue;
    }
    const float x = std::clamp(voxel[a], 0.0f, float(dims[a] - 1));
    j[a] = std::min(int(x) / kGrid, mGridDims[a] - 2);
    const float lo = float(j[a] * kGrid), hi = float(std::min((j[a] + 1) * kGrid, dims[a] - 1));
    w[a] = std::clamp((x - lo) / (hi - lo), 0.0f, 1.0f);
  }
  float c[8];
  for (int s = 0; s < 8; ++s) {
    const glm::ivec3 g = glm::min(j + glm::ivec3(s & 1, (s >> 1) & 1, (s >> 2) & 1), mGridDims - 1);
    c[s] = mTransmittance[linear(g, mGridDims)];
  }
  glm::vec3 unused;
  return trilinear(c, w, &unused);
}

double BrickImageError::operator()(uint32_t node, int p) {
  const uint64_t key = brickKey(node, p);
  if (const auto it = mMemo.find(key); it != mMemo.end()) return it->second;
  const double e = measure(mOctree.nodes()[node], p);
  mMemo.emplace(key, e);
  return e;
}

void BrickImageError::prefetch(const std::vector<std::pair<uint32_t, int>>& bricks) {
  std::vector<std::pair<uint32_t, int>> todo;
  for (const auto& [node, p] : bricks)
    if (!mMemo.contains(brickKey(node, p)) && (mOctree.edge(mOctree.nodes()[node]) >> p) > 1) todo.push_back({node, p});
  std::sort(todo.begin(), todo.end());
  todo.erase(std::unique(todo.begin(), todo.end()), todo.end());
  if (todo.size() < 2) return;  // not worth the threads; operator() measures it
  std::vector<double> errors(todo.size());
  ParallelFailure failure;
#pragma omp parallel for schedule(dynamic, 1)
  for (size_t k = 0; k < todo.size(); ++k) failure.run([&] { errors[k] = measure(mOctree.nodes()[todo[k].first], todo[k].second); });
  failure.rethrow();
  for (size_t k = 0; k < todo.size(); ++k) mMemo.emplace(brickKey(todo[k].first, todo[k].second), errors[k]);
}

double BrickImageError::measure(const OctreeNode& n, int p) const {
  const int step = mOctree.edge(n) >> p;
  if (step <= 1) return 0.0;
  const KnotLattice L = mOctree.lattice(n, p);
  // The level's knots: value and shading gradient, as the brick's texels hold them.
  const std::vector<glm::vec4> both = latticeKnots(mKnots, L);
  std::vector<float> knots(L.count());
  std::vector<glm::vec3> gradients(L.count());
  for (size_t i = 0; i < both.size(); ++i) {
    knots[i] = both[i].x;
    gradients[i] = glm::vec3(both[i].y, both[i].z, both[i].w);
  }
  const glm::ivec3 dims = mVolume.dims();
  const glm::vec3 spacing(mVolume.spacing());

  // The reference field: the samples in a node up to 64 voxels across; beyond, the knots 1/64 of
  // its edge apart (what rays that sample every 1/64 of the edge resolve), so that a brick's
  // measure reads at most 66³ knots through the knot source whatever the node's size. Its knots
  // reach one step past the node's far faces (a gradient there looks ahead, as the samples' does).
  const int f = std::max(1, mOctree.edge(n) / 64);
  KnotLattice F;
  F.origin = glm::ivec3(n.origin);
  F.step = f;
  F.last = glm::min(F.origin + mOctree.edge(n) + f, dims - 1);
  F.dims = (F.last - F.origin + f - 1) / f + 1;
  std::vector<float> reference(size_t(F.count()));
  mKnots.read(f, F.origin / f, F.dims, reference.data(), nullptr);
  // The reference field and its gradient (per mm) at voxel position q.
  auto fine = [&](const glm::vec3& q, glm::vec3* g) {
    glm::ivec3 i0, i1;
    glm::vec3 w, scale;
    for (int a = 0; a < 3; ++a) {
      i0[a] = std::clamp(int((q[a] - float(F.origin[a])) / float(f)), 0, std::max(F.dims[a] - 2, 0));
      i1[a] = std::min(i0[a] + 1, F.dims[a] - 1);
      const int x0 = F.knot(a, i0[a]), x1 = F.knot(a, i1[a]);
      w[a] = x1 > x0 ? (q[a] - float(x0)) / float(x1 - x0) : 0.0f;
      scale[a] = x1 > x0 ? 1.0f / (float(x1 - x0) * spacing[a]) : 1.0f / spacing[a];
    }
    float c[8];
    for (int s = 0; s < 8; ++s)
      c[s] = reference[linear(glm::ivec3(s & 1 ? i1.x : i0.x, s & 2 ? i1.y : i0.y, s & 4 ? i1.z : i0.z), F.dims)];
    const float v = trilinear(c, w, g);
    *g *= scale;
    return v;
  };
  // Which cell of the knots holds q.
  const glm::ivec3 cells = glm::max(L.dims - 1, glm::ivec3(1));
  auto cellOf = [&](const glm::vec3& q) {
    glm::ivec3 j;
    for (int a = 0; a < 3; ++a) j[a] = std::clamp(int((q[a] - float(L.origin[a])) / float(step)), 0, cells[a] - 1);
    return j;
  };
  // Whether the level's field can be visible in each cell (the range of its eight knots).
  std::vector<uint8_t> visibleCell(size_t(cells.x) * cells.y * cells.z);
  for (int z = 0, i = 0; z < cells.z; ++z)
    for (int y = 0; y < cells.y; ++y)
      for (int x = 0; x < cells.x; ++x, ++i) {
        float vmin = 1e30f, vmax = -1e30f;
        for (int s = 0; s < 8; ++s) {
          const glm::ivec3 k = glm::min(glm::ivec3(x + (s & 1), y + ((s >> 1) & 1), z + ((s >> 2) & 1)), L.dims - 1);
          const float v = knots[linear(k, L.dims)];
          vmin = std::min(vmin, v);
          vmax = std::max(vmax, v);
        }
        visibleCell[size_t(i)] = mTf.maxAlpha(vmin, vmax) > 0.0f;
      }
  // The level's field (what the brick shows, without blending) and its shading gradient at q in cell j.
  auto level = [&](const glm::vec3& q, const glm::ivec3& j, glm::vec3* g) {
    glm::vec3 w;
    for (int a = 0; a < 3; ++a) {
      if (L.dims[a] < 2) {
        w[a] = 0.0f;
        continue;
      }
      const float lo = float(L.knot(a, j[a])), hi = float(L.knot(a, j[a] + 1));
      w[a] = std::clamp((q[a] - lo) / (hi - lo), 0.0f, 1.0f);
    }
    float c[8];
    glm::vec3 gc[8];
    for (int s = 0; s < 8; ++s) {
      const size_t k = linear(glm::min(j + glm::ivec3(s & 1, (s >> 1) & 1, (s >> 2) & 1), L.dims - 1), L.dims);
      c[s] = knots[k];
      gc[s] = gradients[k];
    }
    *g = glm::mix(glm::mix(glm::mix(gc[0], gc[1], w.x), glm::mix(gc[2], gc[3], w.x), w.y),
                  glm::mix(glm::mix(gc[4], gc[5], w.x), glm::mix(gc[6], gc[7], w.x), w.y), w.z);
    glm::vec3 unused;
    return trilinear(c, w, &unused);
  };

  glm::ivec3 a, b;
  mOctree.voxelBox(n, &a, &b);
  const glm::vec3 lo = glm::vec3(a) * spacing, hi = glm::vec3(b) * spacing, centre = 0.5f * (lo + hi);
  glm::vec3 dir = glm::vec3(mCamera.forward());
  if (!mCamera.ortho && glm::length(centre - glm::vec3(mCamera.eye)) > 0.0f) dir = glm::normalize(centre - glm::vec3(mCamera.eye));
  const glm::vec3 u = glm::normalize(std::abs(dir.x) < 0.9f ? glm::cross(dir, glm::vec3(1, 0, 0)) : glm::cross(dir, glm::vec3(0, 1, 0)));
  const glm::vec3 v = glm::cross(dir, u);
  glm::vec2 pmin(1e30f), pmax(-1e30f);
  for (int c = 0; c < 8; ++c) {
    const glm::vec3 corner((c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z);
    const glm::vec2 pc(glm::dot(corner - centre, u), glm::dot(corner - centre, v));
    pmin = glm::min(pmin, pc);
    pmax = glm::max(pmax, pc);
  }
  // Rays an eighth of the node's edge apart choose as rays a voxel apart do, for a fraction of the
  // work (docs/multires.md); one sample per voxel spacing along them (coarser in large nodes).
  const float minSpacing = std::min({spacing.x, spacing.y, spacing.z});
  const float h = minSpacing * std::max(1.0f, float(mOctree.edge(n)) / 8.0f);
  const float ds = minSpacing * std::max(1.0f, float(mOctree.edge(n)) / 64.0f);
  // One ray: the squared difference of the colours that reach the eye, times the area it stands for.
  auto ray = [&](float su, float sv) -> double {
    const glm::vec3 o = centre + u * su + v * sv;
    float t0 = -1e30f, t1 = 1e30f;
    for (int k = 0; k < 3; ++k) {
      if (std::abs(dir[k]) < 1e-12f) {
        if (o[k] < lo[k] || o[k] > hi[k]) return 0.0;
        continue;
      }
      float ta = (lo[k] - o[k]) / dir[k], tb = (hi[k] - o[k]) / dir[k];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    if (!(t1 > t0)) return 0.0;
    const float seen = transmittance((o + dir * t0) / spacing);
    if (seen < 1e-3f) return 0.0;
    glm::vec4 cf(0.0f), cl(0.0f);  // premultiplied colour and opacity, front to back
    for (float t = t0 + 0.5f * ds; t < t1 && (cf.a < 0.999f || cl.a < 0.999f); t += ds) {
      const glm::vec3 q = glm::clamp((o + dir * t) / spacing, glm::vec3(a), glm::vec3(b));
      const glm::ivec3 block = glm::min(glm::ivec3(q) / mBlock, mBlockDims - 1), j = cellOf(q);
      if (!mVisibleBlock[linear(block, mBlockDims)] && !visibleCell[linear(j, cells)])
        continue;  // both fields transparent here
      glm::vec3 gf, gl;
      const Entry &ef = classify(fine(q, &gf)), &el = classify(level(q, j, &gl));
      if (ef.kappa <= 0.0f && el.kappa <= 0.0f) continue;
      const glm::vec3 x = q * spacing;
      const float af = 1.0f - std::exp(-extinction(ef, x) * ds), al = 1.0f - std::exp(-extinction(el, x) * ds);
      cf += (1.0f - cf.a) * af * glm::vec4(ef.rgb * shade(gf, dir), 1.0f);
      cl += (1.0f - cl.a) * al * glm::vec4(el.rgb * shade(gl, dir), 1.0f);
    }
    const glm::vec4 d = (cf - cl) * seen;  // what reaches the eye of the difference
    return double(glm::dot(d, d)) * double(h) * double(h);
  };
  double total = 0.0;
  for (float su = pmin.x + 0.5f * h; su < pmax.x; su += h)
    for (float sv = pmin.y + 0.5f * h; sv < pmax.y; sv += h) total += ray(su, sv);
  return total;
}

}  // namespace hyb
