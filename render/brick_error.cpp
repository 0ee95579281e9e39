#include "render/brick_error.h"

#include <algorithm>
#include <bit>
#include <cmath>

#include "hybrid_octree/knot_source.h"
#include "volume/core/parallel.h"

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

// One brick's measure, its stages as methods (as SlicesFrame's are): made, it holds the level's
// knots, the reference field, which of the level's cells can be visible and the node's projection
// across the view; total() casts the rays.
class BrickImageError::Measure {
 public:
  Measure(const BrickImageError& e, const OctreeNode& n, int p)
      : mE(e), mStep(e.mOctree.edge(n) >> p), mL(e.mOctree.lattice(n, p)), mSpacing(e.mVolume.spacing()) {
    readLevel();
    readReference(n);
    markVisibleCells();
    project(n);
  }

  // The sum over the rays across the node's projection.
  double total() const {
    double total = 0.0;
    for (float su = mPmin.x + 0.5f * mH; su < mPmax.x; su += mH)
      for (float sv = mPmin.y + 0.5f * mH; sv < mPmax.y; sv += mH) total += ray(su, sv);
    return total;
  }

 private:
  // The level's knots: value and shading gradient, as the brick's texels hold them.
  void readLevel() {
    const std::vector<glm::vec4> both = latticeKnots(mE.mKnots, mL);
    mKnots.resize(mL.count());
    mGradients.resize(mL.count());
    for (size_t i = 0; i < both.size(); ++i) {
      mKnots[i] = both[i].x;
      mGradients[i] = glm::vec3(both[i].y, both[i].z, both[i].w);
    }
  }

  // The reference field: the samples in a node up to 64 voxels across; beyond, the knots 1/64 of
  // its edge apart (what rays that sample every 1/64 of the edge resolve), so that a brick's
  // measure reads at most 66³ knots through the knot source whatever the node's size. Its knots
  // reach one step past the node's far faces (a gradient there looks ahead, as the samples' does).
  void readReference(const OctreeNode& n) {
    const int f = std::max(1, mE.mOctree.edge(n) / 64);
    mF.origin = glm::ivec3(n.origin);
    mF.step = f;
    mF.last = glm::min(mF.origin + mE.mOctree.edge(n) + f, mE.mVolume.dims() - 1);
    mF.dims = (mF.last - mF.origin + f - 1) / f + 1;
    mReference.resize(size_t(mF.count()));
    mE.mKnots.read(f, mF.origin / f, mF.dims, mReference.data(), nullptr);
  }

  // Whether the level's field can be visible in each cell (the range of its eight knots).
  void markVisibleCells() {
    mCells = glm::max(mL.dims - 1, glm::ivec3(1));
    mVisibleCell.resize(size_t(mCells.x) * mCells.y * mCells.z);
    for (int z = 0, i = 0; z < mCells.z; ++z)
      for (int y = 0; y < mCells.y; ++y)
        for (int x = 0; x < mCells.x; ++x, ++i) {
          float vmin = 1e30f, vmax = -1e30f;
          for (int s = 0; s < 8; ++s) {
            const glm::ivec3 k = glm::min(glm::ivec3(x + (s & 1), y + ((s >> 1) & 1), z + ((s >> 2) & 1)), mL.dims - 1);
            const float v = mKnots[linear(k, mL.dims)];
            vmin = std::min(vmin, v);
            vmax = std::max(vmax, v);
          }
          mVisibleCell[size_t(i)] = mE.mTf.maxAlpha(vmin, vmax) > 0.0f;
        }
  }

  // The node's box, the rays' direction (towards its centre from the eye) and the box's projection
  // on the plane across them; the rays' spacing and their samples'.
  void project(const OctreeNode& n) {
    const Camera& camera = mE.mCamera;
    mE.mOctree.voxelBox(n, &mA, &mB);
    mLo = glm::vec3(mA) * mSpacing;
    mHi = glm::vec3(mB) * mSpacing;
    mCentre = 0.5f * (mLo + mHi);
    mDir = glm::vec3(camera.forward());
    if (!camera.ortho && glm::length(mCentre - glm::vec3(camera.eye)) > 0.0f) mDir = glm::normalize(mCentre - glm::vec3(camera.eye));
    mU = glm::normalize(std::abs(mDir.x) < 0.9f ? glm::cross(mDir, glm::vec3(1, 0, 0)) : glm::cross(mDir, glm::vec3(0, 1, 0)));
    mV = glm::cross(mDir, mU);
    mPmin = glm::vec2(1e30f);
    mPmax = glm::vec2(-1e30f);
    for (int c = 0; c < 8; ++c) {
      const glm::vec3 corner((c & 1) ? mHi.x : mLo.x, (c & 2) ? mHi.y : mLo.y, (c & 4) ? mHi.z : mLo.z);
      const glm::vec2 pc(glm::dot(corner - mCentre, mU), glm::dot(corner - mCentre, mV));
      mPmin = glm::min(mPmin, pc);
      mPmax = glm::max(mPmax, pc);
    }
    // Rays an eighth of the node's edge apart choose as rays a voxel apart do, for a fraction of the
    // work (docs/multires.md); one sample per voxel spacing along them (coarser in large nodes).
    const float minSpacing = std::min({mSpacing.x, mSpacing.y, mSpacing.z});
    mH = minSpacing * std::max(1.0f, float(mE.mOctree.edge(n)) / 8.0f);
    mDs = minSpacing * std::max(1.0f, float(mE.mOctree.edge(n)) / 64.0f);
  }

  // The reference field and its gradient (per mm) at voxel position q.
  float fine(const glm::vec3& q, glm::vec3* g) const {
    glm::ivec3 i0, i1;
    glm::vec3 w, scale;
    for (int a = 0; a < 3; ++a) {
      i0[a] = std::clamp(int((q[a] - float(mF.origin[a])) / float(mF.step)), 0, std::max(mF.dims[a] - 2, 0));
      i1[a] = std::min(i0[a] + 1, mF.dims[a] - 1);
      const int x0 = mF.knot(a, i0[a]), x1 = mF.knot(a, i1[a]);
      w[a] = x1 > x0 ? (q[a] - float(x0)) / float(x1 - x0) : 0.0f;
      scale[a] = x1 > x0 ? 1.0f / (float(x1 - x0) * mSpacing[a]) : 1.0f / mSpacing[a];
    }
    float c[8];
    for (int s = 0; s < 8; ++s)
      c[s] = mReference[linear(glm::ivec3(s & 1 ? i1.x : i0.x, s & 2 ? i1.y : i0.y, s & 4 ? i1.z : i0.z), mF.dims)];
    const float v = trilinear(c, w, g);
    *g *= scale;
    return v;
  }

  // Which cell of the knots holds q.
  glm::ivec3 cellOf(const glm::vec3& q) const {
    glm::ivec3 j;
    for (int a = 0; a < 3; ++a) j[a] = std::clamp(int((q[a] - float(mL.origin[a])) / float(mStep)), 0, mCells[a] - 1);
    return j;
  }

  // The level's field (what the brick shows, without blending) and its shading gradient at q in cell j.
  float level(const glm::vec3& q, const glm::ivec3& j, glm::vec3* g) const {
    glm::vec3 w;
    for (int a = 0; a < 3; ++a) {
      if (mL.dims[a] < 2) {
        w[a] = 0.0f;
        continue;
      }
      const float lo = float(mL.knot(a, j[a])), hi = float(mL.knot(a, j[a] + 1));
      w[a] = std::clamp((q[a] - lo) / (hi - lo), 0.0f, 1.0f);
    }
    float c[8];
    glm::vec3 gc[8];
    for (int s = 0; s < 8; ++s) {
      const size_t k = linear(glm::min(j + glm::ivec3(s & 1, (s >> 1) & 1, (s >> 2) & 1), mL.dims - 1), mL.dims);
      c[s] = mKnots[k];
      gc[s] = mGradients[k];
    }
    *g = glm::mix(glm::mix(glm::mix(gc[0], gc[1], w.x), glm::mix(gc[2], gc[3], w.x), w.y),
                  glm::mix(glm::mix(gc[4], gc[5], w.x), glm::mix(gc[6], gc[7], w.x), w.y), w.z);
    glm::vec3 unused;
    return trilinear(c, w, &unused);
  }

  // One ray: the squared difference of the colours that reach the eye, times the area it stands for.
  double ray(float su, float sv) const {
    const glm::vec3 o = mCentre + mU * su + mV * sv;
    float t0 = -1e30f, t1 = 1e30f;
    for (int k = 0; k < 3; ++k) {
      if (std::abs(mDir[k]) < 1e-12f) {
        if (o[k] < mLo[k] || o[k] > mHi[k]) return 0.0;
        continue;
      }
      float ta = (mLo[k] - o[k]) / mDir[k], tb = (mHi[k] - o[k]) / mDir[k];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    if (!(t1 > t0)) return 0.0;
    const float seen = mE.transmittance((o + mDir * t0) / mSpacing);
    if (seen < 1e-3f) return 0.0;
    glm::vec4 cf(0.0f), cl(0.0f);  // premultiplied colour and opacity, front to back
    for (float t = t0 + 0.5f * mDs; t < t1 && (cf.a < 0.999f || cl.a < 0.999f); t += mDs) {
      const glm::vec3 q = glm::clamp((o + mDir * t) / mSpacing, glm::vec3(mA), glm::vec3(mB));
      const glm::ivec3 block = glm::min(glm::ivec3(q) / mE.mBlock, mE.mBlockDims - 1), j = cellOf(q);
      if (!mE.mVisibleBlock[linear(block, mE.mBlockDims)] && !mVisibleCell[linear(j, mCells)])
        continue;  // both fields transparent here
      glm::vec3 gf, gl;
      const Entry &ef = mE.classify(fine(q, &gf)), &el = mE.classify(level(q, j, &gl));
      if (ef.kappa <= 0.0f && el.kappa <= 0.0f) continue;
      const glm::vec3 x = q * mSpacing;
      const float af = 1.0f - std::exp(-mE.extinction(ef, x) * mDs), al = 1.0f - std::exp(-mE.extinction(el, x) * mDs);
      cf += (1.0f - cf.a) * af * glm::vec4(ef.rgb * shade(gf, mDir), 1.0f);
      cl += (1.0f - cl.a) * al * glm::vec4(el.rgb * shade(gl, mDir), 1.0f);
    }
    const glm::vec4 d = (cf - cl) * seen;  // what reaches the eye of the difference
    return double(glm::dot(d, d)) * double(mH) * double(mH);
  }

  const BrickImageError& mE;
  const int mStep;  // voxels between the level's knots
  const KnotLattice mL;
  const glm::vec3 mSpacing;
  std::vector<float> mKnots;
  std::vector<glm::vec3> mGradients;
  KnotLattice mF;  // the reference field's knots
  std::vector<float> mReference;
  glm::ivec3 mCells{1};
  std::vector<uint8_t> mVisibleCell;
  glm::ivec3 mA{0}, mB{0};  // the node's voxel box
  glm::vec3 mLo{0.0f}, mHi{0.0f}, mCentre{0.0f};  // the same in mm, and its centre
  glm::vec3 mDir{0.0f}, mU{0.0f}, mV{0.0f};  // the rays' direction and the plane across them
  glm::vec2 mPmin{0.0f}, mPmax{0.0f};  // the box's projection on that plane
  float mH = 1.0f, mDs = 1.0f;  // mm between rays, between samples along a ray
};

double BrickImageError::measure(const OctreeNode& n, int p) const {
  if ((mOctree.edge(n) >> p) <= 1) return 0.0;
  return Measure(*this, n, p).total();
}

}  // namespace hyb
