// Multiresolution rendering: level blending, surface invariance, the speed/accuracy trade.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "hybrid_octree/selection.h"
#include "hybrid_octree/surface_octree.h"
#include "render/brick_error.h"
#include "render/raycast.h"
#include "render/slices.h"
#include "render_util.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using test::gl;

// A faint haze growing linearly along x (reproduced exactly at every level, and visible, so every
// node of 32 costs eight bricks to refine) with a rod of bone-like material seen end-on near the eye
// (one voxel across, at odd indices, so that a lattice two voxels apart misses it) and a thin plate
// of it seen face-on farther away; optionally an opaque wall between the eye and the plate.
Volume rodAndPlate(bool wall) {
  return test::makeVolume({65, 65, 65}, [wall](int i, int j, int k) {
    if (i >= 4 && i <= 12 && j == 15 && k == 15) return 700.0;                          // rod along the view
    if (i >= 44 && i <= 45 && j >= 40 && j <= 60 && k >= 40 && k <= 60) return 700.0;  // plate, 2 voxels thick
    if (wall && i >= 22 && i <= 29 && j >= 34 && k >= 34) return 3000.0;               // wall in front of the plate
    return 160.0 + 0.5 * i;
  });
}

// Looking along +x at the volume's centre from x = −150 mm.
Camera alongX() { return test::perspective(glm::dvec3(-150, 32, 32), glm::dvec3(32, 32, 32), glm::dvec3(0, 0, 1), 30, 64); }

// The resolution level of the visible brick holding voxel @p p (−1 when none).
int levelAt(const VolumeOctree& t, const Selection& sel, const glm::ivec3& p) {
  for (const Brick& b : sel.bricks) {
    const OctreeNode& n = t.nodes()[b.node];
    glm::ivec3 lo, hi;
    t.voxelBox(n, &lo, &hi);
    if (!b.hidden && glm::all(glm::lessThanEqual(lo, p)) && glm::all(glm::lessThanEqual(p, hi))) return resolutionLevel(t, b);
  }
  return -1;
}

TEST(BrickImageError, ZeroWhereTheLevelReproducesTheField) {
  VolumeOctreeOptions pointKnots;
  pointKnots.prefilter = false;  // prefiltered knots reproduce a trilinear field only to 16 bits
  const Volume v = test::makeVolume({33, 33, 33}, [](int i, int j, int k) { return test::trilinearField(i, j, k); });
  const VolumeOctree t = VolumeOctree::build(v, pointKnots);
  const TransferFunction tf({{-50.0f, {1, 0.5f, 0}, 0.0f}, {100.0f, {0, 0.5f, 1}, 0.3f}}, "ramp");
  BrickImageError e(v, t, tf, alongX());
  for (int p = 0; p <= t.maxLevel(t.root()); ++p) EXPECT_LT(e(0, p), 1e-3) << "level " << p;  // the field's range gives ~10^3
  // A field the levels do not reproduce has errors that vanish only at full resolution.
  const Volume s = test::sphereVolume({33, 33, 33}, 11.0);
  const VolumeOctree ts = VolumeOctree::build(s, pointKnots);
  const TransferFunction ring({{-2.0f, {1, 1, 1}, 0.0f}, {0.0f, {1, 1, 1}, 0.8f}, {2.0f, {1, 1, 1}, 0.0f}}, "shell");
  BrickImageError es(s, ts, ring, alongX());
  EXPECT_GT(es(0, 2), 1.0);
  EXPECT_GT(es(0, 4), 0.0);
  EXPECT_EQ(es(0, 5), 0.0);
  EXPECT_EQ(es.measured(), 3u);
  EXPECT_EQ(es(0, 2), es(0, 2));  // memoized
  EXPECT_EQ(es.measured(), 3u);
  // Measured together on all cores, the same values.
  BrickImageError batch(s, ts, ring, alongX());
  batch.prefetch({{0, 2}, {0, 4}, {0, 3}, {0, 2}});
  EXPECT_EQ(batch.measured(), 3u);
  EXPECT_EQ(batch(0, 2), es(0, 2));
  EXPECT_EQ(batch(0, 4), es(0, 4));
  EXPECT_EQ(batch.measured(), 3u);
}

TEST(BrickImageError, ABroadChangeOutweighsAPinpointOneAndOpaqueMaterialHidesWhatIsBehind) {
  const Volume v = rodAndPlate(false), walled = rodAndPlate(true);
  const VolumeOctree t = VolumeOctree::build(v), tw = VolumeOctree::build(walled);
  const TransferFunction tf = TransferFunction::preset("ct-bone");
  const Camera cam = alongX();
  const uint32_t rod = childIndex(t.root(), 0), plate = childIndex(t.root(), 7);  // the nodes of 32 holding them
  // Two voxels a texel: the rod vanishes (a pixel or two), the plate thins (its whole face). The
  // bound the selection uses without the image error, min(ε·slope, opacity), is about the same.
  auto bound = [&](uint32_t i) { const OctreeNode& n = t.nodes()[i]; return tf.distortion(n.minValue, n.maxValue, t.errors(n)[4]); };
  ASSERT_NEAR(bound(rod), bound(plate), 1e-3);
  BrickImageError e(v, t, tf, cam), ew(walled, tw, tf, cam);
  // (Rays four voxels apart may miss the rod altogether: a pinpoint change weighs little anyway.)
  EXPECT_GT(e(plate, 4), 4.0 * e(rod, 4)) << "plate " << e(plate, 4) << ", rod " << e(rod, 4);
  // Behind 8 mm of 0.6/mm opacity (transmittance 0.4^8 ≈ 7e-4) the plate weighs almost nothing;
  // the haze alone lets through 0.6–0.8.
  const glm::vec3 plateNodeFront(32, 48, 48);
  EXPECT_GT(e.transmittance(plateNodeFront), 0.6f);
  EXPECT_LT(ew.transmittance(plateNodeFront), 0.01f);
  EXPECT_LT(ew(plate, 4), 0.01 * e(plate, 4));  // (the grid marches in steps of four voxels)
  EXPECT_NEAR(ew(rod, 4), e(rod, 4), 1e-6 * e(rod, 4));  // the wall is not in front of the rod
}

TEST(BrickImageError, ACutAwayOrFadedBrickWeighsWhatIsLeftOfIt) {
  const Volume v = rodAndPlate(false);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = TransferFunction::preset("ct-bone");
  const Camera cam = alongX();
  const uint32_t rod = childIndex(t.root(), 0), plate = childIndex(t.root(), 7);
  BrickImageError all(v, t, tf, cam);
  // A cutting plane keeping x <= 40 mm removes the plate (x = 44, 45) and nothing of the rod.
  BrickImageError cut(v, t, tf, cam, {glm::dvec4(-1, 0, 0, 40)});
  ASSERT_GT(all(plate, 4), 0.0);
  EXPECT_EQ(cut(plate, 4), 0.0);
  EXPECT_NEAR(cut(rod, 4), all(rod, 4), 1e-9 + 1e-6 * all(rod, 4));
  // A volume of interest around the rod's node fades the plate to a tenth of its opacity (and the
  // haze in front of it, which lets more of the plate's difference through).
  VolumeOfInterest voi;
  voi.lo = glm::dvec3(-1.0);
  voi.hi = glm::dvec3(33.0);
  voi.ramp = 0.0;
  BrickImageError faded(v, t, tf, cam, {glm::dvec4(0, 0, 0, 1), &voi});
  EXPECT_LT(faded(plate, 4), 0.1 * all(plate, 4));
  EXPECT_NEAR(faded(rod, 4), all(rod, 4), 1e-9 + 1e-6 * all(rod, 4));
}

TEST(BrickImageError, TheBudgetGoesWhereTheImageChangesMost) {
  gl();
  const Volume v = rodAndPlate(false);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf = TransferFunction::preset("ct-bone");
  const Camera cam = alongX();
  BrickImageError imageError(v, t, tf, cam);
  SelectionParams bound;
  bound.spacing = v.spacing();
  bound.eye = cam.eye;
  bound.opacity = [&tf](float lo, float hi) { return tf.maxAlpha(lo, hi); };
  bound.distortion = [&tf](float lo, float hi, float error) { return tf.distortion(lo, hi, error); };
  SelectionParams measured = bound;
  measured.brickError = [&imageError](uint32_t node, int p) { return imageError(node, p); };
  const glm::ivec3 inRod(8, 15, 15), inPlate(44, 48, 48);
  const uint64_t full = selectNodes(t, bound).texels;
  const std::vector<uint8_t> reference = toRgba8(raycast(v, t, tf, cam, RaycastOptions{}), glm::vec3(0));
  auto db = [&](const Selection& sel) { return psnr(toRgba8(renderSlices({v, t, sel}, tf, cam, SlicesOptions{}), glm::vec3(0)), reference); };
  int discriminating = 0;
  for (uint64_t budget = full / 8; budget < full; budget += full / 16) {
    bound.texelBudget = measured.texelBudget = budget;
    const Selection a = selectNodes(t, bound), b = selectNodes(t, measured);
    EXPECT_LE(b.texels, budget);
    EXPECT_TRUE(isRestricted(t, b));
    // The measured priority's image is never worse; where the bound refines the nearer rod and
    // leaves the plate coarse while the measured one does the opposite, it is much better.
    const double dbBound = db(a), dbMeasured = db(b);
    EXPECT_GE(dbMeasured, dbBound - 0.1) << "budget " << budget;
    if (levelAt(t, a, inPlate) > 0 && levelAt(t, b, inPlate) == 0) {
      ++discriminating;
      EXPECT_GT(dbMeasured, dbBound + 3.0) << "budget " << budget;
    }
  }
  EXPECT_GT(discriminating, 0) << "no budget tells the two priorities apart: the scene tests nothing";
}

}  // namespace
}  // namespace hyb
