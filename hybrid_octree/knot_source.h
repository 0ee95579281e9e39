// Where bricks read their knots: the values of every lattice spacing s (the knots {0, s, 2s, …}
// and the grid's last index along each axis, docs/volume-octree.md) and the shading gradient at
// each knot. Two sources give the same numbers: the volume with its knot pyramid in memory
// (VolumeKnots), and the paged knot store of a scene file (KnotStore). A brick made from either is
// bit-identical, because both hand out the same numbers: the knots' values, and at spacings of two
// voxels or more the volume's own gradient at each knot (a coarse brick shades with the data's
// gradients, as a simplified mesh keeps its normals; docs/multires.md) rounded to bfloat16 (8
// bits of mantissa, float's range: finer than the 8-bit texels it ends in, and half the store's
// bytes of float). At spacing 1 the gradient is computed here from the knots, as
// Volume::gradientAt does.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <cstring>
#include <memory>
#include <span>
#include <vector>

#include "hybrid_octree/volume_octree.h"
#include "volume/volume.h"

namespace hyb {

/// @p x rounded to the nearest bfloat16 (ties to even; float's top 16 bits), the largest finite
/// one where rounding would reach infinity.
inline uint16_t toBfloat16(float x) {
  uint32_t u;
  std::memcpy(&u, &x, 4);
  const uint32_t r = (u + 0x7fffu + ((u >> 16) & 1u)) >> 16;
  return uint16_t((r & 0x7f80u) == 0x7f80u ? (u >> 16 & 0x8000u) | 0x7f7fu : r);
}
inline float fromBfloat16(uint16_t b) {
  const uint32_t u = uint32_t(b) << 16;
  float x;
  std::memcpy(&x, &u, 4);
  return x;
}
inline glm::vec3 bfloat16Rounded(const glm::vec3& g) {
  return {fromBfloat16(toBfloat16(g.x)), fromBfloat16(toBfloat16(g.y)), fromBfloat16(toBfloat16(g.z))};
}

/// The knots of spacing s with indices lo … lo + count − 1 per axis: what one KnotSource::read reads.
struct KnotBox {
  int s = 1;
  glm::ivec3 lo{0}, count{0};
};

/// Samples of a KnotSource (its spacing-1 knots) held in place in their stored type, x fastest:
/// a paged store's decompressed block, a volume's whole array, or a copy. @p keep holds them.
struct SampleBlock {
  glm::ivec3 lo{0}, dims{0};  ///< the voxels lo … lo + dims − 1
  ScalarType type = ScalarType::Float32;
  const void* samples = nullptr;
  std::shared_ptr<const void> keep;
  bool holds(const glm::ivec3& v) const {
    return glm::all(glm::greaterThanEqual(v, lo)) && glm::all(glm::lessThan(v, lo + dims));
  }
  /// A reader of this block's voxels as stored in type T: (i, j, k) → float.
  template <class T>
  auto reader() const {
    const char* base = static_cast<const char*>(samples);
    const glm::ivec3 o = lo;
    const size_t nx = size_t(dims.x), nxy = size_t(dims.x) * size_t(dims.y);
    return [base, o, nx, nxy](int i, int j, int k) {
      T x;  // (a paged store's blocks are bytes: copied, not aliased)
      std::memcpy(&x, base + (size_t(i - o.x) + nx * size_t(j - o.y) + nxy * size_t(k - o.z)) * sizeof(T), sizeof(T));
      return float(x);
    };
  }
  /// Calls @p f with a reader of this block's voxels, (i, j, k) → float as Volume::at gives it,
  /// the type dispatched once.
  template <class F>
  decltype(auto) visit(F&& f) const {
    switch (type) {
      case ScalarType::UInt8: return f(reader<uint8_t>());
      case ScalarType::Int8: return f(reader<int8_t>());
      case ScalarType::UInt16: return f(reader<uint16_t>());
      case ScalarType::Int16: return f(reader<int16_t>());
      default: return f(reader<float>());
    }
  }
  /// The value of voxel @p v (held here).
  float at(const glm::ivec3& v) const {
    return visit([&](const auto& read) { return read(v.x, v.y, v.z); });
  }
};

/// Voxels a side of the blocks KnotSource::sampleBlock copies by default (a paged store's blocks
/// are its own, kStoreBlock).
inline constexpr int kSampleBlock = 32;

/// The knot values of a sample grid at every power-of-two spacing.
class KnotSource {
 public:
  virtual ~KnotSource() = default;
  /// The sample grid.
  virtual glm::ivec3 dims() const = 0;
  /// Voxel spacing in mm.
  virtual glm::dvec3 spacing() const = 0;
  /// Writes the knots of spacing @p s with indices lo … lo + count − 1 per axis (inside
  /// knotCounts(dims(), s)) to @p values, x fastest, and for s ≥ 2 the volume's gradient at each
  /// (Volume::gradientAt, data units per mm, bfloat16Rounded) to @p gradients unless it is null
  /// (always null for s = 1).
  /// Thread-safe.
  /// @throw IoError when a paged source cannot read them (a damaged file, named with its block).
  virtual void read(int s, const glm::ivec3& lo, const glm::ivec3& count, float* values, glm::vec3* gradients) const = 0;
  /// Samples around voxel @p v (inside dims()) held in place, @p v among them: what a sampler
  /// reads one voxel at a time. By default the block of kSampleBlock³ holding it, copied by read().
  /// Thread-safe. @throw IoError as read().
  virtual SampleBlock sampleBlock(const glm::ivec3& v) const;
};

/// The knots of a volume in memory: the samples, or the octree's prefiltered knots where it holds
/// them. @p volume and @p octree must outlive it.
class VolumeKnots final : public KnotSource {
 public:
  VolumeKnots(const Volume& volume, const VolumeOctree& octree) : mVolume(volume), mOctree(octree) {}
  glm::ivec3 dims() const override { return mVolume.dims(); }
  glm::dvec3 spacing() const override { return mVolume.spacing(); }
  void read(int s, const glm::ivec3& lo, const glm::ivec3& count, float* values, glm::vec3* gradients) const override;
  /// The volume's whole array (a volume without samples: the default copy, which fails).
  SampleBlock sampleBlock(const glm::ivec3& v) const override;

 private:
  const Volume& mVolume;
  const VolumeOctree& mOctree;
};

/// The full-resolution field of a KnotSource (spacing 1) sampled as Volume::sample and
/// Volume::sampleGradient sample a volume in memory, bit for bit: what a ray tracer reads from a
/// paged scene, through the store's cache, without reading the samples whole. It reads the
/// source's blocks in place (KnotSource::sampleBlock: a paged store's cached blocks, nothing
/// copied) and keeps the last few in a table of kWays-way sets, least recently used replaced, as
/// neighbouring rays revisit them. One sampler per thread.
class KnotSampler {
 public:
  static constexpr int kWays = 4;
  /// @p source must outlive the sampler; @p blocks: how many blocks it keeps (a paged store's
  /// stay held while it does: 64 KB each for int16 samples, 16 MB by default).
  explicit KnotSampler(const KnotSource& source, int blocks = 256);
  /// @throw IoError as KnotSource::sampleBlock.
  float sample(const glm::vec3& p);
  glm::vec3 sampleGradient(const glm::vec3& p);
  /// The block holding voxel @p v, from the one last used or the table, else read: valid until the
  /// sampler's next call. @throw IoError as KnotSource::sampleBlock.
  const SampleBlock& blockAt(const glm::ivec3& v);

 private:
  struct Entry {
    SampleBlock block;
    uint64_t used = 0;  // the sampler's clock at its last use
  };
  /// Calls @p f with a reader of voxels (i, j, k) → float for the voxels lo … hi around @p p: one
  /// block's typed reader where a block holds them all (most samples), else voxel by voxel.
  template <class F>
  decltype(auto) around(const glm::vec3& p, F&& f);

  const KnotSource& mSource;
  glm::ivec3 mDims;
  glm::dvec3 mSpacing;
  std::vector<Entry> mEntries;  // sets of kWays
  const SampleBlock* mLast = nullptr;
  uint64_t mClock = 0;
};

/// The gradients of @p source's full-resolution field at voxel positions @p points (a KnotSampler
/// of its own): Volume::sampleGradient's numbers, bit for bit, without the samples in memory.
void sampleGradients(const KnotSource& source, std::span<const glm::vec3> points, glm::vec3* gradients);

/// The knots of lattice @p L as value and gradient (data units per mm), x fastest: what
/// KnotSource::read gives, the gradient at spacing 1 by central differences between the knot's
/// neighbours (one-sided at the grid's faces), exactly as Volume::gradientAt computes it.
std::vector<glm::vec4> latticeKnots(const KnotSource& source, const KnotLattice& L);
/// The knots latticeKnots reads for @p L on a grid of @p dims: at spacing 1 with one neighbour
/// either side where the grid has one (for the gradients).
KnotBox latticeKnotBox(const glm::ivec3& dims, const KnotLattice& L);

}  // namespace hyb
