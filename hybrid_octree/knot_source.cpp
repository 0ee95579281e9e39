#include "hybrid_octree/knot_source.h"

#include <algorithm>

#include "volume/core/error.h"

namespace hyb {

void VolumeKnots::read(int s, const glm::ivec3& lo, const glm::ivec3& count, float* values, glm::vec3* gradients) const {
  HYB_DCHECK(s > 1 || gradients == nullptr);
  const glm::ivec3 n = mVolume.dims();
  std::vector<int> xs(size_t(count.x));
  for (int i = 0; i < count.x; ++i) xs[size_t(i)] = knotPosition(lo.x + i, s, n.x);
  for (int k = 0; k < count.z; ++k)
    for (int j = 0; j < count.y; ++j) {
      const int y = knotPosition(lo.y + j, s, n.y), z = knotPosition(lo.z + k, s, n.z);
      if (s == 1) {
        mVolume.readRow(lo.x, y, z, count.x, values);
      } else {
        for (int i = 0; i < count.x; ++i) values[i] = mOctree.knotValue(mVolume, s, glm::ivec3(xs[size_t(i)], y, z));
        if (gradients) {
          for (int i = 0; i < count.x; ++i) gradients[i] = bfloat16Rounded(mVolume.gradientAt(xs[size_t(i)], y, z));
          gradients += count.x;
        }
      }
      values += count.x;
    }
}

KnotBox latticeKnotBox(const glm::ivec3& dims, const KnotLattice& L) {
  const glm::ivec3 first = L.origin / L.step;
  HYB_DCHECK(first * L.step == L.origin && glm::all(glm::lessThanEqual(first + L.dims, knotCounts(dims, L.step))));
  if (L.step > 1) return KnotBox{L.step, first, L.dims};
  const glm::ivec3 lo = glm::max(first - 1, glm::ivec3(0)), hi = glm::min(first + L.dims, dims - 1);
  return KnotBox{1, lo, hi - lo + 1};
}

std::vector<glm::vec4> latticeKnots(const KnotSource& source, const KnotLattice& L) {
  const glm::ivec3 n = source.dims(), first = L.origin / L.step;
  const KnotBox reads = latticeKnotBox(n, L);
  std::vector<glm::vec4> out;
  out.reserve(size_t(L.count()));
  if (L.step > 1) {
    std::vector<float> values(size_t(L.count()));
    std::vector<glm::vec3> gradients(size_t(L.count()));
    source.read(reads.s, reads.lo, reads.count, values.data(), gradients.data());
    for (size_t i = 0; i < values.size(); ++i) out.emplace_back(values[i], gradients[i]);
    return out;
  }
  const glm::dvec3 spacing = source.spacing();
  // The lattice's samples with one neighbour either side where the grid has one.
  const glm::ivec3 lo = reads.lo, box = reads.count;
  std::vector<float> values(size_t(box.x) * size_t(box.y) * size_t(box.z));
  source.read(1, lo, box, values.data(), nullptr);
  auto value = [&](const glm::ivec3& j) {
    const glm::ivec3 q = j - lo;
    return values[size_t(q.x) + size_t(box.x) * (size_t(q.y) + size_t(box.y) * size_t(q.z))];
  };
  for (int k = 0; k < L.dims.z; ++k)
    for (int j = 0; j < L.dims.y; ++j)
      for (int i = 0; i < L.dims.x; ++i) {
        const glm::ivec3 g = first + glm::ivec3(i, j, k);
        out.push_back(glm::vec4(value(g), centralDifferences(g, n, spacing, [&](int x, int y, int z) { return value({x, y, z}); })));
      }
  return out;
}

SampleBlock KnotSource::sampleBlock(const glm::ivec3& v) const {
  SampleBlock b;
  b.lo = v / kSampleBlock * kSampleBlock;
  b.dims = glm::min(b.lo + kSampleBlock, dims()) - b.lo;
  auto values = std::make_shared<std::vector<float>>(size_t(b.dims.x) * size_t(b.dims.y) * size_t(b.dims.z));
  read(1, b.lo, b.dims, values->data(), nullptr);
  b.samples = values->data();
  b.keep = std::move(values);
  return b;
}

SampleBlock VolumeKnots::sampleBlock(const glm::ivec3& v) const {
  if (!mVolume.hasSamples()) return KnotSource::sampleBlock(v);
  SampleBlock b;
  b.dims = mVolume.dims();
  b.type = mVolume.storedType();
  b.samples = mVolume.visitSamples([](const auto* p) { return static_cast<const void*>(p); });
  return b;
}

KnotSampler::KnotSampler(const KnotSource& source, int blocks)
    : mSource(source), mDims(source.dims()), mSpacing(source.spacing()),
      mEntries(size_t(std::max((blocks + kWays - 1) / kWays, 1)) * kWays) {}

const SampleBlock& KnotSampler::blockAt(const glm::ivec3& v) {
  if (mLast && mLast->holds(v)) return *mLast;
  // A set of kWays blocks, the least recently used replaced: a ray's beam meets a dozen or more
  // blocks, and two of them sharing one slot of a direct-mapped table were read again by every
  // ray of the beam.
  const glm::ivec3 key = v / kSampleBlock;
  const uint32_t h = uint32_t(key.x) * 73856093u ^ uint32_t(key.y) * 19349663u ^ uint32_t(key.z) * 83492791u;
  Entry* set = &mEntries[size_t(h) % (mEntries.size() / kWays) * kWays];
  ++mClock;
  Entry* victim = set;
  for (int w = 0; w < kWays; ++w) {
    if (set[w].block.samples && set[w].block.holds(v)) {
      set[w].used = mClock;
      return *(mLast = &set[w].block);
    }
    if (set[w].used < victim->used) victim = &set[w];
  }
  mLast = nullptr;
  victim->block = SampleBlock{};  // (a failed read leaves no block half-made)
  victim->block = mSource.sampleBlock(v);
  victim->used = mClock;
  return *(mLast = &victim->block);
}

template <class F>
decltype(auto) KnotSampler::around(const glm::vec3& p, F&& f) {
  // The voxels a gradient at p reads (trilinearGradient: i0 − 1 … i0 + 2, clamped).
  const glm::vec3 q = glm::clamp(p, glm::vec3(0.0f), glm::vec3(mDims - 1));
  const glm::ivec3 i0 = glm::min(glm::ivec3(q), mDims - 1);
  const glm::ivec3 lo = glm::max(i0 - 1, glm::ivec3(0)), hi = glm::min(i0 + 2, mDims - 1);
  const SampleBlock& b = blockAt(i0);
  if (b.holds(lo) && b.holds(hi)) return b.visit(f);
  return f([this](int i, int j, int k) { return blockAt({i, j, k}).at({i, j, k}); });
}

float KnotSampler::sample(const glm::vec3& p) {
  return around(p, [&](const auto& at) { return trilinearSample(p, mDims, at); });
}

glm::vec3 KnotSampler::sampleGradient(const glm::vec3& p) {
  return around(p, [&](const auto& at) { return trilinearGradient(p, mDims, mSpacing, at); });
}

void sampleGradients(const KnotSource& source, std::span<const glm::vec3> points, glm::vec3* gradients) {
  KnotSampler sampler(source, 16);  // a run of neighbouring points meets a few blocks
  for (size_t i = 0; i < points.size(); ++i) gradients[i] = sampler.sampleGradient(points[i]);
}

}  // namespace hyb
