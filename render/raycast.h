// The reference renderer (docs/renderer.md): a CPU hybrid ray tracer after Levoy, "A Hybrid Ray Tracer for
// Rendering Polygon and Volume Data", IEEE CG&A 1990. Full-resolution trilinear samples, the
// opacity-per-millimetre transfer function, surfaces intersected exactly and composited at their
// depth, empty-space skipping with the Volume Octree's min/max, early termination at α ≥ 0.999.
#pragma once

#include <functional>
#include <optional>
#include <vector>

#include "hybrid_octree/knot_source.h"
#include "hybrid_octree/volume_octree.h"
#include "render/bvh.h"
#include "render/camera.h"
#include "render/cut_plane.h"
#include "render/frame_request.h"
#include "render/geometry_channel.h"
#include "render/voi.h"
#include "render/image.h"
#include "render/preintegration.h"
#include "render/regions.h"
#include "render/transfer_function.h"
#include "volume/core/progress.h"
#include "volume/volume.h"

namespace hyb {

/// Options of the reference renderer.
struct RaycastOptions {
  double stepVoxels = 0.25;          ///< sample spacing, in units of the smallest voxel spacing
  bool shading = true;               ///< gradient (headlight) shading of the volume
  const Bvh* surface = nullptr;      ///< isosurface triangles in world mm, or none
  glm::vec4 surfaceColor{1.0f};      ///< straight RGBA; a < 1 is translucent (per crossing)
  /// User meshes (GridMeshes::whole, built over in their order), or none; crossing mesh k composites
  /// meshColors[k], shaded as the isosurface is.
  const Bvh* meshes = nullptr;
  std::vector<glm::vec4> meshColors;
  /// The user geometry scan-converted onto the volume's grid (render/geometry_channel.h), or none:
  /// composited with each segment's sample by compositeGeometry; nodes holding it are not skipped.
  const GeometryChannel* geometry = nullptr;
  bool volume = true;                ///< false: surfaces only
  bool skipEmptySpace = true;        ///< jump over nodes the transfer function makes transparent
  const CutPlane* cut = nullptr;     ///< cutting plane, or none
  const VolumeOfInterest* voi = nullptr;  ///< opacity scaling box, or none
  /// Pre-integrated classification: each segment between samples reads this table at the values
  /// of its two ends (shading and the volume of interest at its middle); none: post-classified at
  /// its middle.
  const PreIntegrationTable* preintegrated = nullptr;
  /// Where the samples are read: a paged scene's knot store, through its cache (the volume need
  /// not hold its samples), or none: the volume's own.
  const KnotSource* knots = nullptr;
  /// Levoy's progressive refinement: rays on a grid 2^(refineLevels − 1) pixels apart first, then,
  /// level by level, at half the spacing inside each square whose corners' colours (premultiplied
  /// RGBA) differ by more than refineTolerance; the other squares show the bilinear interpolation
  /// of their corners. With tolerance 0 the last level traces every pixel (the exact image).
  /// 1 level: every pixel at once.
  int refineLevels = 1;
  float refineTolerance = 0.0f;
  /// Receives the image after each level of refinement, and the rays traced so far.
  std::function<void(int level, const Image& image, uint64_t rays)> onLevel;
  const Progress* progress = nullptr;  ///< hears of the rays traced ("ray tracing"), or none
  /// A region of a sort-last frame (render/regions.h), or none: only the volume segments whose
  /// middles lie in it are composited (the surface given should be cut to it, cutMeshToRegion),
  /// so that the regions' images composited front to back make the whole frame's image.
  const RegionBox* region = nullptr;
  /// Traces only the image rows [rows.x, rows.y) (from the top); the image is those rows only.
  /// Needs refineLevels 1.
  std::optional<glm::ivec2> rows;
};

/// The options a frame's look and quality ask of the reference renderer, @p surface the
/// triangles it crosses (or none) and @p grid the frame in the grid frame, which must outlive
/// them: Levoy's refinement from Quality::progressive and adaptive. What an engine keeps across
/// frames (RaycastOptions::knots, preintegrated), the progress and onLevel are its own to set.
RaycastOptions raycastOptions(const FrameGrid& grid, const Look& look, const Quality& quality, const Bvh* surface);

/// Per-pixel statistics of a render.
struct RaycastStats {
  uint64_t samples = 0;         ///< volume samples taken
  uint64_t skippedLeaves = 0;   ///< transparent octree leaves jumped over
  uint64_t surfaceHits = 0;     ///< surface crossings composited
  uint64_t rays = 0;            ///< pixels traced (the others interpolated by refinement)
};

/// Entry and exit distances @p t0, @p t1 of the ray o + t·d through the box [lo, hi]; false when
/// it misses (both ray tracers).
bool raySlab(const glm::dvec3& o, const glm::dvec3& d, const glm::dvec3& lo, const glm::dvec3& hi, double* t0, double* t1);

/// Renders @p volume (world mm: voxel (i,j,k) at (i·sx, j·sy, k·sz)) into premultiplied RGBA,
/// multithreaded over rows. Deterministic.
Image raycast(const Volume& volume, const VolumeOctree& octree, const TransferFunction& tf, const Camera& camera,
              const RaycastOptions& options, RaycastStats* stats = nullptr);

}  // namespace hyb
