#include "apps/viewer/viewer_quality.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace hyb::viewer {

double QualityLevel::cost() const {
  // Fragments follow the pixels and the planes; a budget shares the texels, which frame time
  // follows less than linearly (coarse bricks are sliced at fewer planes: docs/multires.md).
  return scale * scale * (0.5 / step) * std::pow(budgetPercent / 100.0, 0.75);
}

bool surfaceRaysFit(const glm::ivec3& dims, const glm::dvec3& spacing) {
  const glm::dvec3 extent = glm::dvec3(dims) * spacing;
  return std::max({extent.x, extent.y, extent.z}) <= kRayLadderVoxels * std::min({spacing.x, spacing.y, spacing.z});
}

std::string QualityLevel::describe() const {
  std::ostringstream s;
  s << "size " << int(std::lround(scale * 100)) << " %, budget " << budgetPercent << " %, step " << step << (rays ? ", ray-traced" : "");
  return s.str();
}

double AdaptiveQuality::estimateMs(int level) const {
  if (mMeasured[size_t(level)] >= 0.0) return mMeasured[size_t(level)];
  if (mMeasured[size_t(mLast)] < 0.0) return 0.0;  // nothing measured yet
  return mMeasured[size_t(mLast)] * mLadder[size_t(level)].cost() / mLadder[size_t(mLast)].cost();
}

void AdaptiveQuality::record(int level, double ms, bool cold, double coarser) {
  if (level == 0) mFinalMs = ms;  // (a cold one too: the first final frame of a large study is)
  const bool passing = cold || coarser > 0.0;  // a state the level's later frames leave behind, or not
  mCold = passing ? mCold + 1 : 0;
  const bool untrusted = passing && mCold < kColdFramesTrusted;
  // A probe is done once measured, or once a frame of it, even drawing coarser bricks or
  // uploading a bounded share of textures, took longer than the target: the level does not fit.
  if (level == mProbe && (!untrusted || ms > mTargetMs / mShare)) mProbe = -1;
  if (untrusted) return;
  ms /= std::max(1.0 - coarser, 1.0 / kMaxCoarserScale);
  double& m = mMeasured[size_t(level)];
  m = m < 0.0 ? ms : 0.6 * m + 0.4 * ms;  // smoothed: one slow frame of a shared machine moves it a little
  mLast = level;
}

int AdaptiveQuality::firstLevel() const {
  // A budget rung's selection measures the view's brick errors first, most of a large study's
  // first frame (docs/viewer.md).
  int k = int(mLadder.size()) - 1;
  while (k > 0 && mLadder[size_t(k)].budgetPercent < 100.0) --k;
  return k;
}

void AdaptiveQuality::canvas(double pixels) {
  if (mCanvasPixels > 0.0 && pixels != mCanvasPixels) {
    const double ratio = pixels / mCanvasPixels;
    for (double& ms : mMeasured)
      if (ms >= 0.0) ms *= ratio;
    if (mFinalMs >= 0.0) mFinalMs *= ratio;
  }
  mCanvasPixels = pixels;
}

void AdaptiveQuality::reset() {
  mMeasured.fill(-1.0);
  mFinalMs = -1.0;
  mCanvasPixels = 0.0;
  mLast = mCurrent = int(mLadder.size()) - 1;
  mStay = mCold = mProbeFrames = 0;
  mProbe = -1;
}

int AdaptiveQuality::chooseInteractiveLevel() {
  const int n = int(mLadder.size());
  if (mMeasured[size_t(mLast)] < 0.0) return mCurrent = firstLevel();  // nothing measured: nothing to predict from
  // A probe whose frames were passing (their textures new, or bricks drawn coarser: a finer level's
  // first frames are) is rendered again until one is its level's time, else that level kept the
  // slow time it was last measured at and the ladder stayed on a cheap level for good.
  if (mProbe >= 0 && mProbeFrames < kColdFramesTrusted) {
    ++mProbeFrames;
    return mProbe;
  }
  mProbe = -1;
  int level = -1;
  for (int k = 1; k < n && level < 0; ++k) {
    // Moving to a better level than the current needs a margin; staying or going coarser does not.
    const double target = mTargetMs / mShare;
    const double allowed = k < mCurrent ? kUpMargin * target : target;
    if (estimateMs(k) <= allowed) level = k;
  }
  if (level < 0) {
    // None fits: the best of those within a quarter of the fastest. Where a frame's cost does not
    // follow its pixels (a surface's triangles), the cheapest levels save nothing.
    double fastest = estimateMs(n - 1);
    for (int k = 1; k < n; ++k) fastest = std::min(fastest, estimateMs(k));
    for (level = 1; estimateMs(level) > kNearFastest * fastest; ++level) {
    }
  }
  mStay = level == mCurrent ? mStay + 1 : 0;
  mCurrent = level;
  if (level > 1 && mStay >= kProbeAfter) {
    mStay = 0;
    mProbeFrames = 1;
    return mProbe = level - 1;  // a probe: its measured time decides whether the level moves up
  }
  return level;
}

// The refining step before the final frame that fits kRefineFactor times the target, or -1.
int AdaptiveQuality::firstRefinement() const {
  for (int k = 1; k < mCurrent; ++k)
    if (estimateMs(k) <= kRefineFactor * mTargetMs) return k;
  return -1;
}

int AdaptiveQuality::sharperStep() const {
  if (mMeasured[size_t(mLast)] < 0.0 || !(mFinalMs > kSlowFinalMs)) return -1;
  const int first = firstRefinement();
  // By the cost model from the final frame: the small frames' times, with their fixed costs,
  // overestimate a large one's several times over.
  for (int k = 1; k < (first < 0 ? mCurrent : first); ++k)
    if (mLadder[size_t(k)].cost() / mLadder[0].cost() <= kSharpStepShare) return k;
  return -1;
}

std::vector<int> AdaptiveQuality::refinement() const {
  if (mMeasured[size_t(mLast)] < 0.0) return {firstLevel(), 0};  // nothing measured: a coarse frame first
  std::vector<int> steps;
  for (const int k : {firstRefinement(), sharperStep()})
    if (k > 0) steps.push_back(k);
  steps.push_back(0);
  return steps;
}

}  // namespace hyb::viewer
