// The viewer's adaptive quality: while the user drags, each frame is made at the best level of a
// fixed ladder whose measured (or predicted) time holds a frame-time target; when the input stops,
// better levels follow up to the final one (full resolution, ε = 0, the default step, full size),
// as ParaView's and Neuroglancer's interactive renderers do. Pure logic, fed with measured times.
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace hyb::viewer {

/// One rung: render size (fraction of the page's canvas), texture budget (percent of the view's
/// full-resolution bytes; 100 = no budget) and slice spacing (voxels), or, for a ray-traced rung,
/// the ray tracer's sample spacing (voxels).
struct QualityLevel {
  double scale;
  double budgetPercent;
  double step;
  bool rays = false;  ///< drawn by the ray tracer (the surface exact, crossed by Embree's queries)
  /// Relative cost against the final level (pixels × planes × texel share), for predictions.
  double cost() const;
  std::string describe() const;
};

/// A ladder: best first, level 0 the final frame's. Measured on the cranium against the reference
/// (docs/viewer.md), the volume alone loses accuracy mostly to the slice spacing (woodgrain: 512²
/// at 2.5 voxels is 26 dB, 128² at 1.3 voxels 31 dB), a translucent surface mostly to the image
/// size (its edges; the spacing matters little there): so the volume's ladder shrinks the image
/// before it spaces the slices, the surface's the other way round. A budget comes last in the
/// volume's (it compounds badly with a coarse spacing) and not in the surface's: a surface's
/// frames cost their triangles, and a budget rung's first frames upload new textures. The
/// surface's second rung, the full size at 1.5 voxels, is its sharper step (sharperStep): drawn
/// as the final frame is, it differs from it by what the spacing changes alone (48 dB on the
/// clinical study), where any smaller image magnified loses its edges (35-36 dB).
using Ladder = std::array<QualityLevel, 12>;
inline constexpr Ladder kVolumeLadder{{
    {1.0, 100.0, 0.5},
    {1.0, 100.0, 1.0},
    {0.75, 100.0, 1.0},
    {0.5, 100.0, 1.0},
    {0.5, 100.0, 1.3},
    {0.375, 100.0, 1.3},
    {0.3125, 100.0, 1.3},
    {0.25, 100.0, 1.3},
    {0.25, 100.0, 1.6},
    {0.21875, 100.0, 1.6},
    {0.1875, 100.0, 2.5},
    {0.1875, 50.0, 2.5},
}};
inline constexpr Ladder kSurfaceLadder{{
    {1.0, 100.0, 0.5},
    {1.0, 100.0, 1.5},
    {0.75, 100.0, 1.3},
    {0.5, 100.0, 1.6},
    {0.5, 100.0, 2.5},
    {0.375, 100.0, 2.0},
    {0.375, 100.0, 2.5},
    {0.3125, 100.0, 2.5},
    {0.25, 100.0, 2.5},
    {0.21875, 100.0, 2.5},
    {0.1875, 100.0, 2.5},
    {0.15625, 100.0, 2.5},
}};
/// The surface's ladder for a volume whose rays are short (surfaceRaysFit): below three quarters of
/// the canvas the frames are ray-traced by the moving frames' tracer (render/raycast_interactive.h).
/// At those sizes a slice frame's cost follows the surface's triangles (llvmpipe shades 4×4
/// blocks), a ray-traced one its pixels, and the ray tracer draws the exact surface composited
/// exactly: on the cranium a 192² frame at 1.5 voxels costs what the reference tracer's 128² at
/// 2.5 costs and shows 3 dB more as painted (docs/viewer.md). In memory or paged alike (the tracer
/// reads a scene file's cached blocks in place).
inline constexpr Ladder kSurfaceRayLadder{{
    {1.0, 100.0, 0.5},
    {1.0, 100.0, 1.5},
    {0.75, 100.0, 1.3},
    {0.5, 100.0, 1.5, true},
    {0.4375, 100.0, 1.5, true},
    {0.375, 100.0, 1.5, true},
    {0.375, 100.0, 2.0, true},
    {0.3125, 100.0, 2.0, true},
    {0.25, 100.0, 2.5, true},
    {0.21875, 100.0, 2.5, true},
    {0.1875, 100.0, 3.0, true},
    {0.15625, 100.0, 3.0, true},
}};

/// Longest ray, in the volume's smallest voxel spacings, for which the surface's moving frames
/// are ray-traced (kSurfaceRayLadder): the cranium's rays cross 256 such voxels, and its 128²
/// frames take 45-75 ms whether its samples are in memory or paged (docs/viewer.md); the
/// clinical study's cross 512, and its ray-traced frames held neither the frame rate nor the
/// latency (9 frames a second, p95 201 ms) where the sliced ladder does.
inline constexpr double kRayLadderVoxels = 384.0;
/// Whether a volume of @p dims voxels spaced @p spacing mm gets the ray-traced surface ladder:
/// its longest extent is at most kRayLadderVoxels of its smallest spacing.
bool surfaceRaysFit(const glm::ivec3& dims, const glm::dvec3& spacing);

/// Brick edge (texels) of the frames before the final one: an eighth of the bricks of the default
/// 16 at the same resolution, a third less time a frame on the cranium at the same accuracy
/// (docs/viewer.md); the final frame keeps the default, as `hybrid-octree render` does.
inline constexpr int kInteractiveBrickEdge = 32;

/// Screen-space level of detail of the frames before the final one: a brick is not refined once its
/// texels are at most 0.7 pixels apart (LaMar's criterion, a little coarser than the pixel grid's
/// Nyquist rate), so a small frame of a large study draws as many texels as its pixels need, not
/// the study's. Half a pixel is 0.7 dB closer at one frame size, but its frames cost about 30 %
/// more, warm and cold, and the cold ones (a new rung's textures) set the p95 (docs/scale.md).
inline constexpr double kInteractiveLodPixels = 0.7;

/// Screen-space level of detail of the final frame: texels half a pixel apart (the pixel grid's
/// Nyquist rate), finer than any frame of the cranium or the clinical study at 512² has voxels, so
/// those stay full resolution; a study whose voxels are smaller than that on the screen (the 8 GiB
/// phantom's quarter-pixel voxels) stops there instead of drawing every voxel (docs/scale.md).
inline constexpr double kFinalLodPixels = 0.5;

/// Texels a moving frame packs at most for textures the cache does not keep (Quality::packTexels):
/// sixteen bricks of kInteractiveBrickEdge, some 20-40 ms of packing on two cores. A new rung's
/// first frames packed hundreds of bricks (0.4-0.6 s on the clinical study); now they draw the
/// rest from coarser kept textures and the cut reaches the new one over a few frames. The refining
/// frame too: larger than the moving ones, it met finer bricks and packed them all (2 s on the
/// clinical study, before the final frame packed them again at its own level).
inline constexpr uint64_t kInteractivePackTexels = uint64_t(16) * kInteractiveBrickEdge * kInteractiveBrickEdge * kInteractiveBrickEdge;

/// Simplification error of the surface in the frames before the final one, in pixels where the
/// volume comes nearest the eye (Quality::surfaceErrorPixels): at two pixels the clinical-size
/// CT's bone surface holds the frame rate at a small loss in PSNR, at one it does not
/// (docs/scale.md).
inline constexpr double kInteractiveSurfaceErrorPixels = 2.0;

/// One ladder's levels for one client: which to render while the user drags, and after.
class AdaptiveQuality {
 public:
  explicit AdaptiveQuality(const Ladder& ladder, double targetMs = 80.0) : mLadder(ladder), mTargetMs(targetMs) { reset(); }
  const Ladder& ladder() const { return mLadder; }

  /// The level for the next interactive frame: the best whose time fits the target (with a margin
  /// to move to a better one, so that the level does not flicker), or when none does, the best
  /// whose time is within kNearFastest of the fastest (a quarter: the cheapest levels lose 2-3 dB).
  /// After kProbeAfter frames at one level the next better one is tried: its time may have been
  /// measured on a slow frame. A probe frame that is not its level's time (cold, or drawing
  /// bricks coarser: record) but within the target is followed by another, up to
  /// kColdFramesTrusted. With nothing measured (a volume just opened), the cheapest: its time
  /// then predicts the others' for this volume and image (a full-size frame of a large volume
  /// took seconds).
  int chooseInteractiveLevel();
  static constexpr int kProbeAfter = 12;
  static constexpr double kNearFastest = 1.25;
  static constexpr double kUpMargin = 0.9;  ///< a better level than the current must fit this share of the target
  /// The levels after the input stops, ending with 0: first, when it is better than the
  /// interactive one, the best level whose time fits kRefineFactor times the target (an image
  /// sharper soon, and the final frame not much later); then, when the last final frame took
  /// more than kSlowFinalMs, the best better level predicted from it to take at most
  /// kSharpStepShare of it (a full-size or nearly full-size image in a fraction of the final
  /// frame's seconds, painted while the final frame renders); with nothing measured,
  /// firstLevel() (a volume just opened shows a coarse frame first).
  std::vector<int> refinement() const;
  /// The sharper step refinement() puts before the final frame, or -1 when it puts none.
  int sharperStep() const;
  /// Forgets every time measured: another volume is shown, whose frames cost differently.
  void reset();
  static constexpr double kRefineFactor = 2.0;
  static constexpr double kSlowFinalMs = 2000.0;
  static constexpr double kSharpStepShare = 0.35;  ///< (the surface's full size at 1.5 voxels: 1/3)
  /// Records that a frame at @p level took @p ms (render and encode). A @p cold frame, one that
  /// uploaded most of its textures, or one that drew a share @p coarser of its bricks from coarser
  /// ones (textures beyond its packing bound, or knots the store is still loading), is not taken
  /// as the level's time (the level's later frames neither pay for the upload nor skip bricks)
  /// unless such frames keep coming (a texture cache too small for the view, a level whose bricks
  /// never all fit); then it is taken as costing ms / (1 − coarser), at most kMaxCoarserScale
  /// times ms: what it would have cost whole, so that such a level does not look cheap.
  void record(int level, double ms, bool cold = false, double coarser = 0.0);
  static constexpr double kMaxCoarserScale = 10.0;
  static constexpr int kColdFramesTrusted = 3;
  /// The measured time of @p level, or one predicted from the last measured level's.
  double estimateMs(int level) const;
  /// The level of a volume just opened, nothing measured: the cheapest without a budget.
  int firstLevel() const;
  double targetMs() const { return mTargetMs; }
  /// @p movers clients (this one among them) are dragging on one render thread: each one's next
  /// frame waits for the others', so an interactive frame aims at the target shared among them.
  void share(int movers) { mShare = std::max(1, movers); }
  /// The page's canvas has @p pixels: a new size scales the times measured at the last one by the
  /// ratio of their pixels, else a resized window's first frames are chosen by the old size's times.
  void canvas(double pixels);

 private:
  int firstRefinement() const;
  const Ladder& mLadder;
  double mTargetMs;
  int mShare = 1;  // share(): the interactive frames aim at mTargetMs / mShare
  std::array<double, Ladder().size()> mMeasured;  // smoothed ms per level, -1 unknown
  int mLast = 0;     // the level measured last
  double mFinalMs = -1.0;  // the last final frame's time, cold or not (-1: none yet)
  double mCanvasPixels = 0.0;  // canvas(): the size the times were measured at (0: none yet)
  int mCurrent = 0;  // the interactive level in use
  int mStay = 0;     // frames at mCurrent since it was chosen or probed
  int mCold = 0;     // cold frames in a row
  int mProbe = -1;   // the level being probed, until a frame of it is measured
  int mProbeFrames = 0;  // frames of the probe asked for so far
};

}  // namespace hyb::viewer
