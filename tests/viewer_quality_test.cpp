#include "apps/viewer_quality.h"

#include <gtest/gtest.h>

namespace hyb::viewer {
namespace {

TEST(ViewerQuality, TheLadderGoesFromTheFinalFrameToCheaperOnes) {
  EXPECT_EQ(kLadder[0].scale, 1.0);
  EXPECT_EQ(kLadder[0].budgetPercent, 100.0);
  EXPECT_EQ(kLadder[0].step, 0.5);
  for (size_t k = 1; k < kLadder.size(); ++k) EXPECT_LT(kLadder[k].cost(), kLadder[k - 1].cost()) << k;
}

TEST(ViewerQuality, InteractiveFramesHoldTheTargetAndRefinementEndsAtTheFinalLevel) {
  AdaptiveQuality q(60.0);
  // Nothing measured: every estimate is 0, so the best interactive level is tried.
  EXPECT_EQ(q.chooseInteractiveLevel(), 1);
  // Level 1 is slow: 240 ms. Predictions scale by cost: the first level under 60 ms is chosen.
  q.record(1, 240.0);
  const int level = q.chooseInteractiveLevel();
  EXPECT_GT(level, 1);
  EXPECT_LE(q.estimateMs(level), 60.0);
  EXPECT_GT(q.estimateMs(level - 1), 60.0 * 0.8);
  // Measured faster than predicted, but not by the margin: the level stays.
  q.record(level, 0.9 * 60.0);
  q.record(level - 1, 55.0);  // the better level fits now, though not within 80 %
  EXPECT_EQ(q.chooseInteractiveLevel(), level);
  for (int i = 0; i < 4; ++i) q.record(level - 1, 20.0);
  const int better = q.chooseInteractiveLevel();
  EXPECT_LT(better, level);
  EXPECT_LE(q.estimateMs(better), 0.8 * 60.0);
  // Held at one level, the next better one is probed once every kProbeAfter frames.
  AdaptiveQuality held(60.0);
  held.record(1, 1000.0);
  const int base = held.chooseInteractiveLevel();
  int probes = 0;
  for (int i = 0; i < 3 * AdaptiveQuality::kProbeAfter; ++i) {
    const int l = held.chooseInteractiveLevel();
    EXPECT_TRUE(l == base || l == base - 1);
    probes += l == base - 1;
    held.record(l, l == base ? 40.0 : 200.0);  // the probe is too slow: back to base
  }
  EXPECT_EQ(probes, 3);  // after 12, 24 and 36 frames
  // A coarse interactive level refines in two steps, a fine one in one; both end at 0.
  AdaptiveQuality slow(60.0);
  slow.record(1, 5000.0);
  EXPECT_EQ(slow.chooseInteractiveLevel(), int(kLadder.size()) - 1);
  EXPECT_EQ(slow.refinement(), (std::vector<int>{2, 0}));
  AdaptiveQuality fast(60.0);
  fast.record(1, 10.0);
  EXPECT_EQ(fast.chooseInteractiveLevel(), 1);
  EXPECT_EQ(fast.refinement(), (std::vector<int>{0}));
}

TEST(ViewerQuality, AFrameThatUploadedItsTexturesIsNotTheLevelsTime) {
  AdaptiveQuality q(60.0);
  q.record(4, 300.0, true);  // the first frame at larger bricks: its textures uploaded
  EXPECT_EQ(q.estimateMs(4), 0.0);
  q.record(4, 40.0, false);
  EXPECT_EQ(q.estimateMs(4), 40.0);
  // Frames that stay cold (a cache too small for the view) are trusted from the third on.
  AdaptiveQuality thrashing(60.0);
  for (int i = 1; i < AdaptiveQuality::kColdFramesTrusted; ++i) thrashing.record(4, 300.0, true);
  EXPECT_EQ(thrashing.estimateMs(4), 0.0);
  thrashing.record(4, 300.0, true);
  EXPECT_EQ(thrashing.estimateMs(4), 300.0);
}

}  // namespace
}  // namespace hyb::viewer
