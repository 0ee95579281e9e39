// The image error of a brick: what the budgeted selection (Carmona et al.; docs/multires.md) weighs when
// it spends texels, measured for the view and transfer function at hand instead of bounded from the
// nodal error alone.
//
// For node n at texture level p, rays parallel to the line from the eye to the node's centre (the
// view direction for orthographic cameras), one per voxel spacing across the node's projection,
// march through its box. Along each, the samples' field and the level's field (the trilinear
// interpolation of the knots the brick holds) are classified by the transfer function, shaded by
// their own gradients the way the renderers shade (headlight) and composited front to back. The
// error is the sum over the rays of the squared difference of the two premultiplied colours and
// opacities, attenuated by the transmittance from the node to the eye (a grid four voxels apart,
// coarser beyond 256 voxels across, marched once per view), times the area a ray stands for: the squared error the brick adds to the
// image, which is what PSNR counts. So a thin structure that a coarse level smooths away, or
// aliases, weighs what it changes on the screen along its whole path, a sharp edge weighs its
// contrast, and what lies behind opaque material weighs little.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <unordered_map>
#include <utility>
#include <vector>

#include "hybrid_octree/knot_source.h"
#include "hybrid_octree/volume_octree.h"
#include "render/camera.h"
#include "render/transfer_function.h"
#include "render/voi.h"
#include "volume/volume.h"

namespace hyb {

/// What a view removes of the volume for BrickImageError: the cutting plane's kept side (all by
/// default), a volume of interest, and where the bricks' knots are read (none: in memory).
struct BrickErrorClipping {
  glm::dvec4 kept{0, 0, 0, 1};
  const VolumeOfInterest* voi = nullptr;
  const KnotSource* knots = nullptr;
};

class BrickImageError {
 public:
  /// Prepares one view: the transfer function's table and the transmittance grid. Only the half
  /// space @p kept (a·x + d ≥ 0, world mm; a cutting plane's CutPlane::keptSide) is drawn, and
  /// @p voi, if any, scales opacity as the renderers do. Knots and samples are read from @p knots
  /// (none: @p volume's samples and @p octree), a node's worth at a time: a paged scene's samples
  /// are never read whole. @p volume, @p octree, @p voi and @p knots must outlive this object (the
  /// transfer function and the camera are copied).
  BrickImageError(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, const Camera& camera,
                  const BrickErrorClipping& clipping = {});

  /// The image error of node @p node at level @p p (0 where the level is exact: one texel per
  /// voxel). Memoized: each brick is measured once.
  double operator()(uint32_t node, int p);

  /// Measures those of @p bricks (node, level) not measured yet, on all cores: what a selection
  /// is about to ask for (SelectionParams::prefetchBrickErrors).
  void prefetch(const std::vector<std::pair<uint32_t, int>>& bricks);

  /// Bricks measured so far.
  size_t measured() const { return mMemo.size(); }

  /// Transmittance from the point @p voxel (voxel units) to the eye, interpolated in the grid.
  float transmittance(const glm::vec3& voxel) const;

 private:
  struct Entry {
    glm::vec3 rgb;  // straight colour
    float alpha;    // opacity of one mm
    float kappa;    // extinction per mm, −ln(1 − alpha)
  };
  class Measure;  // one brick's measure (brick_error.cpp)
  const Entry& classify(float value) const;
  /// Extinction per mm of @p e at world point @p x: none on the removed side, scaled by the VOI.
  float extinction(const Entry& e, const glm::vec3& x) const;
  double measure(const OctreeNode& n, int p) const;
  void buildTransmittance();
  void buildVisibleBlocks();

  const Volume& mVolume;  // its grid and range: the knots are read through mKnots
  const VolumeOctree& mOctree;
  const VolumeKnots mInMemory;
  const KnotSource& mKnots;
  const TransferFunction mTf;
  const Camera mCamera;
  glm::vec4 mKept;
  const VolumeOfInterest* mVoi;
  int mBlock = 8;                      // voxel cells per edge of a block: the octree's leaf edge
  glm::ivec3 mBlockDims{0};
  std::vector<uint8_t> mVisibleBlock;  // per block: can the samples' field be visible there?
  LutLayout mLayout;  // as the slice renderer classifies
  std::vector<Entry> mTable;  // classification per entry of mLayout
  int mGrid = 4;  // voxels between the transmittance grid's points
  glm::ivec3 mGridDims{0};
  std::vector<float> mTransmittance;  // per grid point, mGrid voxels apart
  std::unordered_map<uint64_t, double> mMemo;
};

}  // namespace hyb
