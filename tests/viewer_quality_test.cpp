#include "apps/viewer/viewer_quality.h"

#include <gtest/gtest.h>

namespace hyb::viewer {
namespace {

TEST(ViewerQuality, TheLaddersGoFromTheFinalFrameToCheaperOnes) {
  for (const Ladder* ladder : {&kVolumeLadder, &kSurfaceLadder, &kSurfaceRayLadder}) {
    EXPECT_FALSE((*ladder)[0].rays);  // the final frame is the slice frame `render` makes
    for (const QualityLevel& q : *ladder) EXPECT_TRUE(!q.rays || q.scale <= 0.5);
    EXPECT_EQ((*ladder)[0].scale, 1.0);
    EXPECT_EQ((*ladder)[0].budgetPercent, 100.0);
    EXPECT_EQ((*ladder)[0].step, 0.5);
    for (size_t k = 1; k < ladder->size(); ++k) EXPECT_LT((*ladder)[k].cost(), (*ladder)[k - 1].cost()) << k;
  }
  // At one image size the surface's ladder spaces slices at least as coarsely as the volume's.
  for (const QualityLevel& s : kSurfaceLadder) {
    for (const QualityLevel& v : kVolumeLadder) {
      if (s.scale == v.scale && s.budgetPercent == v.budgetPercent && s.scale < 1.0) {
        EXPECT_GE(s.step, v.step);
      }
    }
  }
}

// The surface's moving frames are ray-traced where a ray crosses at most kRayLadderVoxels of the
// smallest spacing: the cranium (256 across), not the clinical study (512), whatever the units.
TEST(ViewerQuality, RayTracedSurfaceFramesGoToVolumesWhoseRaysAreShort) {
  EXPECT_TRUE(surfaceRaysFit({256, 256, 108}, {0.957, 0.957, 1.5}));
  EXPECT_FALSE(surfaceRaysFit({512, 512, 432}, {0.479, 0.479, 0.375}));
  EXPECT_TRUE(surfaceRaysFit({384, 10, 10}, {1.0, 1.0, 1.0}));
  EXPECT_FALSE(surfaceRaysFit({385, 10, 10}, {1.0, 1.0, 1.0}));
  // Thick slices: 100 slices of 5 mm are 500 of the 1 mm pixels' spacing.
  EXPECT_FALSE(surfaceRaysFit({200, 200, 100}, {1.0, 1.0, 5.0}));
  EXPECT_TRUE(surfaceRaysFit({200, 200, 100}, {2.0, 2.0, 5.0}));
}

TEST(ViewerQuality, InteractiveFramesHoldTheTargetAndRefinementEndsAtTheFinalLevel) {
  AdaptiveQuality q(kVolumeLadder, 60.0);
  // Nothing measured (a volume just opened): the cheapest level without a budget (a budget's
  // selection measures the view's brick errors first), whose time predicts the others'.
  const int cheapest = int(kVolumeLadder.size()) - 2;
  ASSERT_LT(kVolumeLadder[size_t(cheapest) + 1].budgetPercent, 100.0);
  ASSERT_EQ(kVolumeLadder[size_t(cheapest)].budgetPercent, 100.0);
  EXPECT_EQ(q.firstLevel(), cheapest);
  EXPECT_EQ(AdaptiveQuality(kSurfaceLadder, 60.0).firstLevel(), int(kSurfaceLadder.size()) - 1);
  EXPECT_EQ(q.chooseInteractiveLevel(), cheapest);
  EXPECT_EQ(q.refinement(), (std::vector<int>{cheapest, 0}));  // a coarse frame first
  // Level 1 is slow: 240 ms. Predictions scale by cost: the first level under 60 ms is chosen.
  q.record(1, 240.0);
  const int level = q.chooseInteractiveLevel();
  EXPECT_GT(level, 1);
  EXPECT_LE(q.estimateMs(level), 60.0);
  EXPECT_GT(q.estimateMs(level - 1), 60.0 * AdaptiveQuality::kUpMargin);
  // Measured faster than predicted, but not by the margin: the level stays.
  q.record(level, 0.9 * 60.0);
  q.record(level - 1, 58.0);  // the better level fits now, though not within the margin
  EXPECT_EQ(q.chooseInteractiveLevel(), level);
  for (int i = 0; i < 4; ++i) q.record(level - 1, 20.0);
  const int better = q.chooseInteractiveLevel();
  EXPECT_LT(better, level);
  EXPECT_LE(q.estimateMs(better), AdaptiveQuality::kUpMargin * 60.0);
  // Held at one level, the next better one is probed once every kProbeAfter frames.
  AdaptiveQuality held(kVolumeLadder, 60.0);
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
  // A coarse interactive level refines through the best level that fits twice the target,
  // a fine one (or one with nothing measured) straight to the final one.
  AdaptiveQuality slow(kVolumeLadder, 60.0);
  slow.record(1, 5000.0);
  EXPECT_EQ(slow.chooseInteractiveLevel(), int(kVolumeLadder.size()) - 1);
  const std::vector<int> steps = slow.refinement();
  ASSERT_EQ(steps.size(), 2u);
  EXPECT_LE(slow.estimateMs(steps[0]), AdaptiveQuality::kRefineFactor * 60.0);
  EXPECT_GT(slow.estimateMs(steps[0] - 1), AdaptiveQuality::kRefineFactor * 60.0);
  EXPECT_EQ(steps[1], 0);
  // After a final frame slower than kSlowFinalMs (a cold one counts), a sharper step comes
  // between: the best level costing at most kSharpStepShare of the final one, the full size at
  // step 1.5 on the surface's ladder (1/3 of the final frame's cost), 75 % at step 1 on the
  // volume's (0.281; full size at step 1 costs 0.5).
  for (const bool cold : {false, true}) {
    AdaptiveQuality surface(kSurfaceLadder, 60.0);
    surface.record(8, 50.0);
    surface.record(0, AdaptiveQuality::kSlowFinalMs + 1.0, cold);
    const int interactive = surface.chooseInteractiveLevel();
    const std::vector<int> sharper = surface.refinement();
    ASSERT_EQ(sharper.size(), 3u);
    EXPECT_LT(sharper[0], interactive);
    EXPECT_EQ(sharper[1], 1);
    EXPECT_EQ(surface.sharperStep(), 1);
    EXPECT_EQ(kSurfaceLadder[1].scale, 1.0);
    EXPECT_EQ(kSurfaceRayLadder[1].scale, 1.0);
    EXPECT_EQ(sharper[2], 0);
  }
  slow.record(0, 1.5 * AdaptiveQuality::kSlowFinalMs);
  const std::vector<int> withSharper = slow.refinement();
  ASSERT_EQ(withSharper.size(), 3u);
  EXPECT_GT(withSharper[0], 2);
  EXPECT_EQ(withSharper[1], 2);
  EXPECT_EQ(withSharper[2], 0);
  slow.record(0, AdaptiveQuality::kSlowFinalMs);  // no longer slower: no sharper step
  EXPECT_EQ(slow.refinement(), (std::vector<int>{withSharper[0], 0}));
  EXPECT_EQ(slow.sharperStep(), -1);
  AdaptiveQuality fast(kSurfaceLadder, 60.0);
  fast.record(1, 10.0);
  EXPECT_EQ(fast.chooseInteractiveLevel(), 1);
  EXPECT_EQ(fast.refinement(), (std::vector<int>{0}));
  fast.record(0, 5000.0);  // a slow final frame, but the interactive level is already better
  EXPECT_EQ(fast.refinement(), (std::vector<int>{0}));
  // Another volume: what was measured on this one says nothing of it.
  fast.reset();
  EXPECT_EQ(fast.chooseInteractiveLevel(), int(kSurfaceLadder.size()) - 1);
  EXPECT_EQ(fast.estimateMs(1), 0.0);
}

// Clients dragging together on one render thread each wait for the others' frames: each aims at
// the target shared among them, and alone again at the whole target.
TEST(ViewerQuality, MoversShareTheFrameTarget) {
  AdaptiveQuality q(kVolumeLadder, 80.0);
  q.record(1, 240.0);
  const int alone = q.chooseInteractiveLevel();
  EXPECT_LE(q.estimateMs(alone), 80.0);
  q.share(4);
  const int shared = q.chooseInteractiveLevel();
  EXPECT_GT(shared, alone);
  EXPECT_LE(q.estimateMs(shared), 20.0);
  EXPECT_GT(q.estimateMs(shared - 1), 20.0);
  q.share(1);
  for (int i = 0; i < 4; ++i) q.record(shared, q.estimateMs(shared));
  EXPECT_EQ(q.chooseInteractiveLevel(), alone);
}

// Times measured at one canvas size predict another's by their pixels: a window made four times
// larger starts on a cheaper level, and back at its old size returns to the times it had.
TEST(ViewerQuality, ANewCanvasSizeScalesTheTimesMeasured) {
  AdaptiveQuality q(kVolumeLadder, 80.0);
  q.canvas(128.0 * 128.0);
  q.record(1, 40.0);
  q.record(0, 300.0);
  const int small = q.chooseInteractiveLevel();
  EXPECT_EQ(small, 1);
  q.canvas(256.0 * 256.0);
  EXPECT_DOUBLE_EQ(q.estimateMs(1), 160.0);
  const int large = q.chooseInteractiveLevel();
  EXPECT_GT(large, small);
  EXPECT_LE(q.estimateMs(large), 80.0);
  q.canvas(256.0 * 256.0);  // the same size: nothing scaled again
  EXPECT_DOUBLE_EQ(q.estimateMs(1), 160.0);
  // The final frame's time too: 300 ms at 128² is 4.8 s at 512², slow enough for a sharper step.
  EXPECT_EQ(q.sharperStep(), -1);
  q.canvas(512.0 * 512.0);
  EXPECT_GT(q.sharperStep(), 0);
  q.canvas(128.0 * 128.0);
  EXPECT_DOUBLE_EQ(q.estimateMs(1), 40.0);
  q.reset();
  q.canvas(512.0 * 512.0);  // nothing measured: nothing to scale
  EXPECT_DOUBLE_EQ(q.estimateMs(1), 0.0);
}

// When no level fits the target and the cheapest save little (a surface's triangles cost the same
// at any size), the best level within a quarter of the fastest is kept.
TEST(ViewerQuality, WhenNothingFitsTheBestOfTheFastestIsKept) {
  AdaptiveQuality q(kSurfaceLadder, 60.0);
  const int last = int(kSurfaceLadder.size()) - 1;
  q.record(last - 2, 100.0);
  q.record(last - 1, 104.0);
  q.record(last, 85.0);
  EXPECT_EQ(q.chooseInteractiveLevel(), last - 2);
  // A level that is much faster is taken, though it is not fast enough either.
  for (int i = 0; i < 2; ++i) q.record(last, 50.0);
  ASSERT_GT(q.estimateMs(last), 60.0);
  ASSERT_LT(q.estimateMs(last) * AdaptiveQuality::kNearFastest, 100.0);
  EXPECT_EQ(q.chooseInteractiveLevel(), last);
}

TEST(ViewerQuality, AFrameThatUploadedItsTexturesIsNotTheLevelsTime) {
  AdaptiveQuality q(kVolumeLadder, 60.0);
  q.record(4, 300.0, true);  // the first frame at larger bricks: its textures uploaded
  EXPECT_EQ(q.estimateMs(4), 0.0);
  q.record(4, 40.0, false);
  EXPECT_EQ(q.estimateMs(4), 40.0);
  // Frames that stay cold (a cache too small for the view) are trusted from the third on.
  AdaptiveQuality thrashing(kVolumeLadder, 60.0);
  for (int i = 1; i < AdaptiveQuality::kColdFramesTrusted; ++i) thrashing.record(4, 300.0, true);
  EXPECT_EQ(thrashing.estimateMs(4), 0.0);
  thrashing.record(4, 300.0, true);
  EXPECT_EQ(thrashing.estimateMs(4), 300.0);
}

// A frame that drew some of its bricks coarser (beyond its packing bound, or still loading) is
// passing, as a cold one is: not the level's time unless such frames keep coming, and then it
// costs what it would have whole, so a level whose bricks never all fit (a quarter drawn at a
// time) does not look cheap and the ladder does not climb to it.
TEST(ViewerQuality, AFrameThatDrewBricksCoarserCountsAsTheWholeFrame) {
  AdaptiveQuality q(kVolumeLadder, 80.0);
  q.record(4, 30.0, false, 0.5);  // a new level's first frame
  EXPECT_EQ(q.estimateMs(4), 0.0);
  q.record(4, 45.0);
  EXPECT_DOUBLE_EQ(q.estimateMs(4), 45.0);
  AdaptiveQuality persistent(kVolumeLadder, 80.0);
  for (int i = 1; i < AdaptiveQuality::kColdFramesTrusted; ++i) persistent.record(4, 30.0, false, 0.5);
  EXPECT_EQ(persistent.estimateMs(4), 0.0);
  persistent.record(4, 30.0, false, 0.5);
  EXPECT_DOUBLE_EQ(persistent.estimateMs(4), 60.0);
  AdaptiveQuality capped(kVolumeLadder, 80.0);
  for (int i = 0; i < AdaptiveQuality::kColdFramesTrusted; ++i) capped.record(4, 30.0, false, 0.99);
  EXPECT_DOUBLE_EQ(capped.estimateMs(4), 30.0 * AdaptiveQuality::kMaxCoarserScale);
  AdaptiveQuality ladder(kVolumeLadder, 80.0);
  const int last = int(kVolumeLadder.size()) - 1;
  ladder.record(last, 20.0);
  const int chosen = ladder.chooseInteractiveLevel();
  EXPECT_LT(chosen, last);
  for (int i = 0; i < 8; ++i) ladder.record(chosen, 25.0, false, 0.75);  // 100 ms whole: too slow
  EXPECT_GT(ladder.chooseInteractiveLevel(), chosen);

  // A probe's first frames draw bricks coarser (the finer level's bricks are new): it is asked
  // for again until one is measured, and a fast one moves the level up; without that, the slow
  // time the level was once measured at kept the ladder on the cheaper level for good.
  AdaptiveQuality stuck(kVolumeLadder, 80.0);
  stuck.record(last - 1, 300.0);  // measured once, on a slow frame
  stuck.record(last, 30.0);
  int frames = 0, probeFrames = 0;
  while (frames < 3 * AdaptiveQuality::kProbeAfter) {
    const int l = stuck.chooseInteractiveLevel();
    ++frames;
    if (l != last) {
      EXPECT_EQ(l, last - 1);
      ++probeFrames;
      stuck.record(l, probeFrames == 1 ? 70.0 : 50.0, false, probeFrames == 1 ? 0.4 : 0.0);
      if (probeFrames == 2) break;
    } else {
      stuck.record(l, 30.0);
    }
  }
  EXPECT_EQ(frames, AdaptiveQuality::kProbeAfter + 1);  // the probe (the kProbeAfter-th frame), then again
  EXPECT_DOUBLE_EQ(stuck.estimateMs(last - 1), 0.6 * 300.0 + 0.4 * 50.0);
  for (int i = 0; i < 4; ++i) stuck.record(last - 1, 50.0);  // (its later frames)
  EXPECT_EQ(stuck.chooseInteractiveLevel(), last - 1);
  // At most kColdFramesTrusted probe frames, the last taken whatever it was; and one alone when
  // it takes longer than the target, since its level does not fit (the frames a probe repeats
  // cost the latency's tail).
  for (const double probeMs : {70.0, 200.0}) {
    AdaptiveQuality cold(kVolumeLadder, 80.0);
    cold.record(last - 1, 300.0);
    cold.record(last, 30.0);
    std::vector<int> levels;
    for (int i = 0; i < AdaptiveQuality::kProbeAfter + 4; ++i) {
      const int l = cold.chooseInteractiveLevel();
      levels.push_back(l);
      cold.record(l, l == last ? 30.0 : probeMs, l != last);
    }
    EXPECT_EQ(std::count(levels.begin(), levels.end(), last - 1), probeMs < 80.0 ? AdaptiveQuality::kColdFramesTrusted : 1) << probeMs;
    EXPECT_EQ(levels.back(), last);
  }
}

}  // namespace
}  // namespace hyb::viewer
