// The selection policy of a view (docs/multires.md): what hybrid_octree/selection.h's refinement
// weighs for one camera and transfer function. Importance by the focus and the eye (Boada, Navazo
// and Scopigno's OTcut), LaMar's distance filter and screen-space stop, culling by the frustum, the
// cutting plane and the volume of interest, and within a texture budget Carmona et al.'s greedy
// refinement by the image error each refinement removes, measured for this view
// (render/brick_error.h).
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>

#include "hybrid_octree/selection.h"
#include "hybrid_octree/volume_octree.h"
#include "render/brick_error.h"
#include "render/slices/brick_textures.h"
#include "render/camera.h"
#include "render/cut_plane.h"
#include "render/transfer_function.h"
#include "render/voi.h"
#include "volume/volume.h"

namespace hyb {

/// The view-independent part of a selection: what the user chose.
struct SelectionChoice {
  double epsilon = 0.0;               ///< ε_u, data units (≥ 0)
  uint64_t texelBudget = 0;           ///< texels; 0 = unlimited
  std::optional<glm::dvec3> focus;    ///< region of interest, grid mm
  int maxBrickEdge = 16;              ///< B_max
  bool blend = true;                  ///< Carmona's blending towards coarser neighbours
  double lodPixels = 0.0;             ///< LaMar's screen-space stop, pixels; 0 = off
};

/// What a view shows of a volume, in its grid frame: the transfer function, the camera, the cutting
/// plane and the volume of interest (none: not set).
struct ViewShown {
  const TransferFunction& tf;
  const Camera& camera;
  const CutPlane* cut = nullptr;
  const VolumeOfInterest* voi = nullptr;
};

/// The image errors of one view, made on first use and shared by the selections of that view
/// (a budget sweep, progressive levels, repeated frames).
class ViewErrors {
 public:
  /// @p volume, @p octree, @p tf, @p camera, @p cut, @p voi and @p knots must outlive this object
  /// (grid frame). @p knots: where the bricks read their knots and samples (none: the volume in
  /// memory).
  ViewErrors(const Volume& volume, const VolumeOctree& octree, const ViewShown& shown, const KnotSource* knots = nullptr)
      : mVolume(volume), mOctree(octree), mTf(shown.tf), mCamera(shown.camera), mCut(shown.cut), mVoi(shown.voi), mKnots(knots) {}
  BrickImageError& get();
  size_t measured() const { return mErrors ? mErrors->measured() : 0; }

 private:
  const Volume& mVolume;
  const VolumeOctree& mOctree;
  const TransferFunction& mTf;
  const Camera& mCamera;
  const CutPlane* mCut;
  const VolumeOfInterest* mVoi;
  const KnotSource* mKnots;
  std::unique_ptr<BrickImageError> mErrors;
};

/// The selection parameters of @p choice for the view @p shown (grid frame): importance by the focus and
/// the eye, the transfer function's opacity (transparent nodes cost nothing) and distortion, the
/// screen-space stop, culling by the frustum, the cut's removed side and a volume of interest that
/// hides a node, and within a budget the priority measured by @p errors. Every pointer and
/// reference must outlive the parameters' use.
SelectionParams viewSelectionParams(const Volume& volume, const ViewShown& shown, const SelectionChoice& choice, ViewErrors* errors);

}  // namespace hyb
