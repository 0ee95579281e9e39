#include "hybrid_octree/knot_source.h"

#include <algorithm>

#include "volume/error.h"

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

KnotSampler::KnotSampler(const KnotSource& source, int tiles)
    : mSource(source), mDims(source.dims()), mSpacing(source.spacing()),
      mTiles(size_t(std::max((tiles + kWays - 1) / kWays, 1)) * kWays) {}

const KnotSampler::Tile& KnotSampler::tileAt(const glm::vec3& p) {
  // The voxel trilinearSample starts from; its tile covers kTile voxels from there on, and one
  // more either side (a gradient reads i0 − 1 … i0 + 2).
  const glm::ivec3 i0 = glm::min(glm::ivec3(glm::clamp(p, glm::vec3(0.0f), glm::vec3(mDims - 1))), mDims - 1);
  const glm::ivec3 key = i0 / kTile;
  const uint32_t h = uint32_t(key.x) * 73856093u ^ uint32_t(key.y) * 19349663u ^ uint32_t(key.z) * 83492791u;
  // A set of kWays tiles, the least recently used replaced: a ray's beam meets a dozen or more
  // tiles, and two of them sharing one slot of a direct-mapped table were read again by every
  // ray of the beam.
  Tile* set = &mTiles[size_t(h) % (mTiles.size() / kWays) * kWays];
  ++mClock;
  Tile* victim = set;
  for (int w = 0; w < kWays; ++w) {
    if (set[w].key == key) {
      set[w].used = mClock;
      return set[w];
    }
    if (set[w].used < victim->used) victim = &set[w];
  }
  Tile& t = *victim;
  t.key = glm::ivec3(-1);  // (a failed read leaves no tile half-made)
  t.lo = glm::max(key * kTile - 1, glm::ivec3(0));
  t.count = glm::min(key * kTile + kTile + 1, mDims - 1) - t.lo + 1;
  t.values.resize(size_t(t.count.x) * size_t(t.count.y) * size_t(t.count.z));
  mSource.read(1, t.lo, t.count, t.values.data(), nullptr);
  t.key = key;
  t.used = mClock;
  return t;
}

float KnotSampler::sample(const glm::vec3& p) {
  const Tile& t = tileAt(p);
  return trilinearSample(p, mDims, [&t](int i, int j, int k) { return t.at(i, j, k); });
}

glm::vec3 KnotSampler::sampleGradient(const glm::vec3& p) {
  const Tile& t = tileAt(p);
  return trilinearGradient(p, mDims, mSpacing, [&t](int i, int j, int k) { return t.at(i, j, k); });
}

void sampleGradients(const KnotSource& source, std::span<const glm::vec3> points, glm::vec3* gradients) {
  KnotSampler sampler(source, 16);  // a run of neighbouring points meets a few tiles
  for (size_t i = 0; i < points.size(); ++i) gradients[i] = sampler.sampleGradient(points[i]);
}

}  // namespace hyb
