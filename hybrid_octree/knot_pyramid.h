// Prefiltered knots of the coarse lattices. A lattice whose knots lie s voxels apart samples the
// volume below its Nyquist rate; point-subsampled knots alias thin structures into stripes (a CT
// head holder seen edge-on). Here the knots of lattices spaced s ≥ kPrefilterSpacing apart hold the
// volume convolved with the separable tent of half-width s (the lattice's own linear B-spline,
// weights (s − |d|)/s² per axis), so a coarse brick shows a smoothed, alias-free field.
//
// Beyond the grid the volume is extended by odd reflection about its end samples (f(−d) =
// 2f(0) − f(d)): a trilinear field stays trilinear, so it is still reproduced at every level (to the
// knots' 16-bit storage).
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "volume/volume.h"

namespace hyb {

/// Lattices spaced kPrefilterSpacing…kPrefilterMaxSpacing voxels apart hold prefiltered knots: at 2
/// voxels the tent blurs bone edges more than aliasing costs, and beyond 32 (a few knots per axis)
/// filtering changes no image but lengthens the build (docs/volume-octree.md).
inline constexpr int kPrefilterSpacing = 4;
inline constexpr int kPrefilterMaxSpacing = 32;

/// Knots of spacing s along an axis of @p n samples: 0, s, 2s, … and n − 1.
inline int knotCount(int n, int s) { return (n - 1) / s + 1 + ((n - 1) % s != 0); }
/// Voxel index of knot @p j of spacing @p s on an axis of @p n samples (j < knotCount(n, s)): j·s,
/// the last knot moved onto the last sample.
inline int knotPosition(int j, int s, int n) { return std::min(j * s, n - 1); }
/// The knot index of position @p p on an axis of @p n samples at spacing @p s (the inverse of
/// knotPosition), or −1 when no knot lies there.
inline int knotIndexAt(int p, int s, int n) { return p == n - 1 ? knotCount(n, s) - 1 : (p % s == 0 ? p / s : -1); }
/// Knots per axis at spacing @p s.
inline glm::ivec3 knotCounts(const glm::ivec3& n, int s) { return {knotCount(n.x, s), knotCount(n.y, s), knotCount(n.z, s)}; }

/// The prefiltered knot values of every lattice spacing kPrefilterSpacing…kPrefilterMaxSpacing:
/// for spacing s, the positions {0, s, 2s, …} and the grid's last index along each axis (the knots
/// of any position-clamped lattice of that spacing), in 16 bits over each spacing's range: about a
/// hundredth of the volume's float samples.
class KnotPyramid {
 public:
  KnotPyramid() = default;
  /// Builds every spacing of @p volume on all cores.
  explicit KnotPyramid(const Volume& volume);

  /// Builds a pyramid from a volume's planes, in order, without holding the volume.
  class Builder {
   public:
    explicit Builder(const glm::ivec3& dims);
    ~Builder();
    /// Adds the next plane, whose row y @p readRow(y, out) reads as float (called from any thread).
    void add(const std::function<void(int y, float* out)>& readRow);
    /// The pyramid, once every plane was added.
    KnotPyramid finish();

   private:
    struct Impl;
    std::unique_ptr<Impl> mImpl;
  };

  bool empty() const { return mLevels.empty(); }
  /// Whether lattices of spacing @p s read their knots here.
  bool covers(int s) const { return s >= kPrefilterSpacing && !mLevels.empty() && s <= mLevels.back().spacing; }
  /// The prefiltered value at @p p, a knot of spacing @p s: each coordinate a multiple of s or the
  /// grid's last index. Requires covers(s).
  float at(int s, const glm::ivec3& p) const;
  /// What a lattice of spacing @p s holds at its knot @p p: at(s, p) where covered, else the sample.
  float knotValue(const Volume& v, int s, const glm::ivec3& p) const { return covers(s) ? at(s, p) : v.at(p.x, p.y, p.z); }
  /// The stored 16-bit code of knot index @p j (per axis, within the level's knot counts) of
  /// spacing @p s, and the level's mapping: at() = offset(s) + scale(s) · code. Requires covers(s).
  uint16_t code(int s, const glm::ivec3& j) const {
    const Level& l = level(s);
    return l.codes[size_t(j.x) + size_t(l.count.x) * (size_t(j.y) + size_t(l.count.y) * size_t(j.z))];
  }
  float offset(int s) const { return level(s).offset; }
  float scale(int s) const { return level(s).scale; }
  size_t bytesUsed() const;

 private:
  friend class Builder;
  struct Level {
    int spacing = 0;
    glm::ivec3 count{0};  // knots per axis
    float offset = 0.0f, scale = 0.0f;  // value = offset + scale · code
    std::vector<uint16_t> codes;
  };
  const Level& level(int s) const;
  glm::ivec3 mDims{0};
  std::vector<Level> mLevels;  // spacing kPrefilterSpacing·2^i at index i
};

}  // namespace hyb
