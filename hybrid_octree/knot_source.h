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
};

/// The knots of a volume in memory: the samples, or the octree's prefiltered knots where it holds
/// them. @p volume and @p octree must outlive it.
class VolumeKnots final : public KnotSource {
 public:
  VolumeKnots(const Volume& volume, const VolumeOctree& octree) : mVolume(volume), mOctree(octree) {}
  glm::ivec3 dims() const override { return mVolume.dims(); }
  glm::dvec3 spacing() const override { return mVolume.spacing(); }
  void read(int s, const glm::ivec3& lo, const glm::ivec3& count, float* values, glm::vec3* gradients) const override;

 private:
  const Volume& mVolume;
  const VolumeOctree& mOctree;
};

/// The full-resolution field of a KnotSource (spacing 1) sampled as Volume::sample and
/// Volume::sampleGradient sample a volume in memory, bit for bit: what a ray tracer reads from a
/// paged scene, through the store's cache, without reading the samples whole. It reads tiles of
/// kTile³ voxels (with the neighbour either side a gradient needs) and keeps the last few in a
/// table of kWays-way sets, as neighbouring rays revisit them. One sampler per thread.
class KnotSampler {
 public:
  static constexpr int kTile = 32;
  static constexpr int kWays = 4;
  /// @p source must outlive the sampler; @p tiles: how many tiles it keeps (each ≤ 171 KB: 22 MB
  /// by default, what the rays of a few pixels' squares revisit).
  explicit KnotSampler(const KnotSource& source, int tiles = 128);
  /// @throw IoError as KnotSource::read.
  float sample(const glm::vec3& p);
  glm::vec3 sampleGradient(const glm::vec3& p);

 private:
  struct Tile {
    glm::ivec3 key{-1};
    uint64_t used = 0;  // the sampler's clock at its last use
    glm::ivec3 lo{0}, count{0};
    std::vector<float> values;
    float at(int i, int j, int k) const {
      return values[size_t(i - lo.x) + size_t(count.x) * (size_t(j - lo.y) + size_t(count.y) * size_t(k - lo.z))];
    }
  };
  /// The tile holding every voxel a sample or gradient at @p p reads.
  const Tile& tileAt(const glm::vec3& p);

  const KnotSource& mSource;
  glm::ivec3 mDims;
  glm::dvec3 mSpacing;
  std::vector<Tile> mTiles;  // sets of kWays
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
