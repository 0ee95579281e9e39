#include "hybrid_octree/volume_octree.h"

#include <gtest/gtest.h>

#include <numeric>
#include <set>

#include "hybrid_octree/selection.h"
#include "render/brick_error.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using test::bruteForceNodalError;

// Every node's closed box, cut at the grid.
void boxOf(const VolumeOctree& t, const OctreeNode& n, glm::ivec3* lo, glm::ivec3* hi) { t.voxelBox(n, lo, hi); }

TEST(VolumeOctree, StructureOfNonPowerOfTwoGrid) {
  const Volume v = test::randomVolume({33, 20, 9}, 1);
  const VolumeOctree t = VolumeOctree::build(v);
  // Cells 32 x 19 x 8 -> L = 5; leaves of edge 8: 4 x 3 x 1; edge 16: 2 x 2 x 1; the root.
  EXPECT_EQ(t.depth(), 5);
  EXPECT_EQ(t.leafEdge(), 8);
  EXPECT_EQ(t.nodes().size(), size_t(1 + 4 + 12));
  size_t leaves = 0;
  uint64_t cellsCovered = 0;
  for (size_t i = 0; i < t.nodes().size(); ++i) {
    const OctreeNode& n = t.nodes()[i];
    if (n.isLeaf()) {
      ++leaves;
      EXPECT_EQ(t.edge(n), 8);
      glm::ivec3 lo, hi;
      boxOf(t, n, &lo, &hi);
      const glm::ivec3 c = hi - lo;
      cellsCovered += uint64_t(c.x) * c.y * c.z;
      continue;
    }
    EXPECT_GT(n.firstChild, i);  // breadth first: children after parents
    for (int slot = 0; slot < 8; ++slot) {
      if (!(n.childMask & (1u << slot))) continue;
      const OctreeNode& c = t.nodes()[childIndex(n, slot)];
      EXPECT_EQ(c.level, n.level + 1);
      EXPECT_EQ(glm::ivec3(c.origin), glm::ivec3(n.origin) + childOffset(slot, t.edge(c)));
      EXPECT_EQ(childSlot(glm::ivec3(c.origin), t.depth() - c.level), slot);
    }
  }
  EXPECT_EQ(leaves, size_t(12));
  EXPECT_EQ(cellsCovered, uint64_t(32 * 19 * 8));  // the leaves tile the grid's cells exactly once
}

TEST(VolumeOctree, MinMaxMatchBruteForce) {
  const Volume v = test::randomVolume({33, 20, 9}, 2);
  const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{4});
  for (const OctreeNode& n : t.nodes()) {
    glm::ivec3 lo, hi;
    boxOf(t, n, &lo, &hi);
    float mn = 1e30f, mx = -1e30f;
    for (int z = lo.z; z <= hi.z; ++z)
      for (int y = lo.y; y <= hi.y; ++y)
        for (int x = lo.x; x <= hi.x; ++x) {
          mn = std::min(mn, v.at(x, y, z));
          mx = std::max(mx, v.at(x, y, z));
        }
    EXPECT_EQ(n.minValue, mn);
    EXPECT_EQ(n.maxValue, mx);
  }
  EXPECT_EQ(t.root().minValue, v.minValue());
  EXPECT_EQ(t.root().maxValue, v.maxValue());
}

TEST(VolumeOctree, TrilinearFieldHasZeroErrorAtEveryLevel) {
  // Non-power-of-two dims: partial nodes must reproduce the field too (position clamping).
  for (const glm::ivec3 dims : {glm::ivec3(37, 20, 9), glm::ivec3(17, 17, 17), glm::ivec3(2, 2, 2), glm::ivec3(65, 3, 40)}) {
    const Volume v = test::makeVolume(dims, [](int i, int j, int k) { return test::trilinearField(i, j, k); });
    const float scale = std::max(std::fabs(v.minValue()), std::fabs(v.maxValue()));
    // Prefiltered knots reproduce the field too (the tent keeps it, the odd reflection beyond the
    // grid keeps it linear), up to their 16-bit storage over the data's range.
    const float stored = (v.maxValue() - v.minValue()) / 65535.0f;
    for (const VolumeOctreeOptions options : {VolumeOctreeOptions{1, false}, VolumeOctreeOptions{2, false}, VolumeOctreeOptions{8, false},
                                              VolumeOctreeOptions{1, true}, VolumeOctreeOptions{8, true}}) {
      const VolumeOctree t = VolumeOctree::build(v, options);
      for (const OctreeNode& n : t.nodes())
        for (float e : t.errors(n))
          EXPECT_LE(e, 1e-5f * scale + (options.prefilter ? stored : 0.0f)) << "dims " << dims.x << "x" << dims.y << "x" << dims.z;
    }
  }
}

// Sample i of the axis of n samples extended by odd reflection about its end samples, as weights
// on the real samples, added times @p scale into @p w.
void addOddExtension(int n, int i, double scale, std::vector<double>* w) {
  if (n == 1 || (i >= 0 && i < n)) {
    (*w)[size_t(n == 1 ? 0 : i)] += scale;
    return;
  }
  const int end = i < 0 ? 0 : n - 1;
  (*w)[size_t(end)] += 2.0 * scale;
  addOddExtension(n, 2 * end - i, -scale, w);
}

// The tent of half-width s at knot q of an axis of n samples, as weights on the real samples.
std::vector<double> tentWeights(int n, int s, int q) {
  std::vector<double> w(size_t(n), 0.0);
  for (int d = 1 - s; d < s; ++d) addOddExtension(n, q + d, double(s - std::abs(d)) / (double(s) * s), &w);
  return w;
}

TEST(KnotPyramid, KnotsAreTheTentFilteredVolumeWithOddReflection) {
  for (const glm::ivec3 dims : {glm::ivec3(37, 20, 9), glm::ivec3(1, 5, 3), glm::ivec3(2, 2, 2), glm::ivec3(65, 3, 40)}) {
    const Volume v = test::randomVolume(dims, 11);
    const KnotPyramid pyramid(v);
    for (int s = kPrefilterSpacing; s <= kPrefilterMaxSpacing; s *= 2) {
      ASSERT_TRUE(pyramid.covers(s));
      std::vector<int> knots[3];
      for (int a = 0; a < 3; ++a) {
        for (int q = 0; q < dims[a] - 1; q += s) knots[a].push_back(q);
        knots[a].push_back(dims[a] - 1);
      }
      for (int z : knots[2])
        for (int y : knots[1])
          for (int x : knots[0]) {
            const std::vector<double> wx = tentWeights(dims.x, s, x), wy = tentWeights(dims.y, s, y), wz = tentWeights(dims.z, s, z);
            double expected = 0.0;
            for (int k = 0; k < dims.z; ++k)
              for (int j = 0; j < dims.y; ++j)
                for (int i = 0; i < dims.x; ++i) expected += wx[size_t(i)] * wy[size_t(j)] * wz[size_t(k)] * v.at(i, j, k);
            // Stored in 16 bits over the spacing's range (the reflection may reach beyond the data's).
            ASSERT_NEAR(pyramid.at(s, glm::ivec3(x, y, z)), expected, 3.0 * (v.maxValue() - v.minValue()) / 65535.0)
                << "spacing " << s << " knot " << x << "," << y << "," << z;
          }
    }
  }
  // Samples near the float limits (a range near FLT_MAX; the reflection extrapolates near the faces,
  // the prefix sums add up to thousands of samples): every knot and every nodal error stays finite.
  const Volume huge = test::makeVolume({19, 11, 6}, [](int i, int j, int k) { return ((i * 7 + j * 3 + k) % 5 - 2) * 0.8e38; });
  const VolumeOctree ht = VolumeOctree::build(huge);
  for (float e : ht.errorData()) ASSERT_TRUE(std::isfinite(e));
  for (int q : {0, 4, 8, 12, 16, 18}) ASSERT_TRUE(std::isfinite(ht.knotValue(huge, 4, glm::ivec3(q, 4, 5))));
  // Beyond the covered spacings, and point-subsampled octrees, lattices take the samples.
  const Volume v = test::randomVolume({9, 9, 9}, 2);
  EXPECT_FALSE(KnotPyramid(v).covers(2 * kPrefilterMaxSpacing));
  EXPECT_FALSE(KnotPyramid(v).covers(kPrefilterSpacing / 2));
  const VolumeOctree point = VolumeOctree::build(v, VolumeOctreeOptions{8, false});
  EXPECT_EQ(point.knotValue(v, 4, glm::ivec3(4, 8, 0)), v.at(4, 8, 0));
}

TEST(VolumeOctree, SingleSpikeGivesHeightAtEveryAncestor) {
  // Point-subsampled knots (the paper's definition); prefiltered ones are checked against the
  // definition by the brute-force tests.
  const float h = 37.5f;
  const glm::ivec3 spike(5, 9, 3);  // odd coordinates: never a knot of any sub-grid coarser than 1
  const Volume v = test::makeVolume({33, 33, 17}, [&](int i, int j, int k) { return glm::ivec3(i, j, k) == spike ? h : 0.0f; });
  const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{8, false});
  int ancestors = 0;
  for (const OctreeNode& n : t.nodes()) {
    glm::ivec3 lo, hi;
    t.voxelBox(n, &lo, &hi);
    const bool contains = glm::all(glm::greaterThanEqual(spike, lo)) && glm::all(glm::lessThanEqual(spike, hi));
    const auto e = t.errors(n);
    for (int p = 0; p <= t.maxLevel(n); ++p) {
      const float expected = (contains && p < t.maxLevel(n)) ? h : 0.0f;
      EXPECT_EQ(e[size_t(p)], expected) << "level " << int(n.level) << " p " << p;
    }
    ancestors += contains;
  }
  EXPECT_EQ(ancestors, t.depth() - 3 + 1);  // root down to the edge-8 leaf
}

TEST(VolumeOctree, RecurrenceEqualsBruteForceOnRandomVolumes) {
  for (const glm::ivec3 dims : {glm::ivec3(17, 17, 17), glm::ivec3(33, 20, 9)}) {
    const Volume v = test::randomVolume(dims, 7);
    for (const VolumeOctreeOptions options : {VolumeOctreeOptions{2, true}, VolumeOctreeOptions{8, true}, VolumeOctreeOptions{8, false}}) {
      const VolumeOctree t = VolumeOctree::build(v, options);
      EXPECT_EQ(t.prefiltered(), options.prefilter);
      size_t checked = 0;
      for (const OctreeNode& n : t.nodes())
        for (int p = 0; p <= t.maxLevel(n); ++p) {
          const float brute = bruteForceNodalError(v, t, glm::ivec3(n.origin), t.edge(n), p);
          EXPECT_NEAR(t.errors(n)[size_t(p)], brute, 1e-4f * 200.0f)
              << "dims " << dims.x << "x" << dims.y << "x" << dims.z << " level " << int(n.level) << " p " << p;
          ++checked;
        }
      EXPECT_GT(checked, t.nodes().size());
    }
  }
}

TEST(VolumeOctree, ConstantAndTinyVolumes) {
  // Constant: every error is exactly zero.
  const Volume c = test::makeVolume({10, 7, 3}, [](int, int, int) { return 42.0f; });
  const VolumeOctree tc = VolumeOctree::build(c);
  for (const OctreeNode& n : tc.nodes()) {
    EXPECT_EQ(n.minValue, 42.0f);
    for (float e : tc.errors(n)) EXPECT_EQ(e, 0.0f);
  }
  // One voxel, a single row and a single slice build without reading outside the grid.
  for (const glm::ivec3 dims : {glm::ivec3(1, 1, 1), glm::ivec3(9, 1, 1), glm::ivec3(5, 6, 1)}) {
    const Volume v = test::randomVolume(dims, 3);
    const VolumeOctree t = VolumeOctree::build(v);
    EXPECT_GE(t.nodes().size(), size_t(1));
    EXPECT_EQ(t.root().minValue, v.minValue());
    EXPECT_EQ(t.root().maxValue, v.maxValue());
    for (const OctreeNode& n : t.nodes())
      for (int p = 0; p <= t.maxLevel(n); ++p)
        EXPECT_NEAR(t.errors(n)[size_t(p)], bruteForceNodalError(v, t, glm::ivec3(n.origin), t.edge(n), p), 1e-3f);
  }
}

TEST(VolumeOctree, RejectsBadLeafEdge) {
  const Volume v = test::randomVolume({4, 4, 4}, 1);
  EXPECT_THROW(VolumeOctree::build(v, VolumeOctreeOptions{3}), ValueError);
  EXPECT_THROW(VolumeOctree::build(v, VolumeOctreeOptions{0}), ValueError);
  EXPECT_THROW(VolumeOctree::build(v, VolumeOctreeOptions{512}), ValueError);
}

// ---------------------------------------------------------------------------------------------
// Selection

uint64_t cellsOf(const VolumeOctree& t, const OctreeNode& n) {
  glm::ivec3 lo, hi;
  t.voxelBox(n, &lo, &hi);
  const glm::ivec3 c = glm::max(hi - lo, glm::ivec3(0));
  return uint64_t(c.x) * c.y * c.z;
}

TEST(Selection, ZeroEpsilonSelectsFullResolutionEverywhere) {
  const Volume v = test::randomVolume({70, 45, 33}, 11);
  const VolumeOctree t = VolumeOctree::build(v);
  SelectionParams params;
  params.epsilon = 0.0f;
  const Selection sel = selectNodes(t, params);
  uint64_t cells = 0;
  for (const Brick& b : sel.bricks) {
    const OctreeNode& n = t.nodes()[b.node];
    EXPECT_EQ(b.p, t.maxLevel(n));  // one texel per voxel
    EXPECT_EQ(b.error, 0.0f);
    EXPECT_LE(1 << b.p, params.maxBrickEdge);
    cells += cellsOf(t, n);
  }
  EXPECT_EQ(cells, uint64_t(69 * 44 * 32));  // bricks tile the grid exactly once
  EXPECT_EQ(sel.maxError, 0.0f);
  EXPECT_GE(sel.texels, v.voxelCount());
}

TEST(Selection, EpsilonAboveRangeSelectsRootAtLevelZero) {
  const Volume v = test::randomVolume({70, 45, 33}, 12);
  const VolumeOctree t = VolumeOctree::build(v);
  SelectionParams params;
  params.epsilon = v.maxValue() - v.minValue();
  const Selection sel = selectNodes(t, params);
  ASSERT_EQ(sel.bricks.size(), size_t(1));
  EXPECT_EQ(sel.bricks[0].node, 0u);
  EXPECT_EQ(sel.bricks[0].p, 0);
  EXPECT_EQ(sel.texels, uint64_t(8));
}

TEST(Selection, ErrorsStayWithinToleranceAndRefinementsAreNeeded) {
  const Volume v = test::sphereVolume({65, 65, 40}, 20.0);
  const VolumeOctree t = VolumeOctree::build(v);
  for (float eps : {0.01f, 0.1f, 0.5f, 2.0f}) {
    SelectionParams params;
    params.epsilon = eps;
    params.maxBrickEdge = 8;
    params.restricted = false;  // without forced refinements every step was asked for by ε_u
    const Selection sel = selectNodes(t, params);
    for (const Brick& b : sel.bricks) {
      const OctreeNode& n = t.nodes()[b.node];
      EXPECT_LE(b.error, eps);
      EXPECT_LE(1 << b.p, params.maxBrickEdge);
      if (b.node == 0) {
        if (b.p > 0) {
          EXPECT_GT(t.errors(n)[size_t(b.p - 1)], eps);  // the root's p is minimal
        }
      } else {
        EXPECT_EQ(1 << b.p, params.maxBrickEdge);  // other bricks: B_max intervals per edge
        // The parent was split because it was over the tolerance at that level.
        uint32_t parent = 0;
        for (uint32_t i = 0; i < t.nodes().size(); ++i) {
          const OctreeNode& q = t.nodes()[i];
          if (!q.isLeaf() && b.node >= q.firstChild && b.node < q.firstChild + uint32_t(q.childCount())) parent = i;
        }
        EXPECT_GT(t.errors(t.nodes()[parent])[size_t(b.p)], eps);
      }
    }
    EXPECT_LE(sel.maxError, eps);
  }
}

TEST(Selection, FocusTightensErrorNearTheFocus) {
  const Volume v = test::sphereVolume({65, 65, 65}, 25.0);
  const VolumeOctree t = VolumeOctree::build(v);
  SelectionParams params;
  params.epsilon = 0.3f;
  params.focus = glm::dvec3(0.0);
  params.focusRadiusMm = 8.0;
  params.maxBrickEdge = 8;  // small bricks so importance can differ between them
  const Selection sel = selectNodes(t, params);
  for (const Brick& b : sel.bricks) {
    const OctreeNode& n = t.nodes()[b.node];
    EXPECT_LE(b.error, params.epsilon / b.importance * 1.0001f);
    if (n.origin == glm::u16vec3(0)) {
      EXPECT_FLOAT_EQ(b.importance, 1.0f);  // the focus is in this node
    }
  }
  SelectionParams uniform = params;
  uniform.focus.reset();
  EXPECT_LT(sel.texels, selectNodes(t, uniform).texels);  // looser far from the focus
}

uint64_t summedTexels(const Selection& sel) {
  uint64_t sum = 0;
  for (const Brick& b : sel.bricks) sum += b.texelCount();
  return sum;
}

TEST(Selection, TexelBudgetIsNeverExceededAndTheTreeStaysRestricted) {
  const Volume v = test::sphereVolume({65, 65, 65}, 25.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const TransferFunction tf({{-5.0f, {1, 1, 1}, 0.0f}, {5.0f, {1, 1, 1}, 0.2f}}, "ramp");
  Camera cam;
  cam.eye = glm::dvec3(150, 40, 20);
  cam.center = glm::dvec3(32);
  BrickImageError imageError(v, t, tf, cam);
  std::mt19937 rng(7);
  for (int run = 0; run < 4; ++run) {
    SelectionParams params;
    params.maxBrickEdge = 8;
    params.blend = run % 2 == 1;
    if (run >= 2) params.brickError = [&imageError](uint32_t node, int p) { return imageError(node, p); };  // the render command's priority
    const uint64_t full = selectNodes(t, params).texels;
    std::uniform_int_distribution<uint64_t> pick(8, full);
    for (int trial = 0; trial < 12; ++trial) {
      params.texelBudget = trial == 0 ? full : pick(rng);
      const Selection sel = selectNodes(t, params);
      EXPECT_TRUE(sel.budgetMet);
      EXPECT_LE(sel.texels, params.texelBudget);
      EXPECT_EQ(summedTexels(sel), sel.texels);
      EXPECT_TRUE(isRestricted(t, sel));
      if (!params.blend) {
        EXPECT_EQ(sel.blendedBricks, 0u);
      }
    }
  }
  SelectionParams params;
  params.texelBudget = 1;  // impossible even for the root at p = 0
  EXPECT_FALSE(selectNodes(t, params).budgetMet);
}

TEST(Selection, RestrictionRefinesCoarseNeighbours) {
  // Noise in one block touching the plane x = 32, constant elsewhere: ε alone leaves the coarse
  // node beyond the plane (ratio 4) beside fine ones (ratio 1). Point-subsampled knots: prefiltered
  // ones would carry the noise across the plane and refine that node by ε already.
  const Volume v = test::makeVolume({65, 65, 65}, [](int i, int j, int k) {
    return i >= 24 && i < 32 && j < 8 && k < 8 ? double((i * 7 + j * 13 + k * 29) % 11) : 0.0;
  });
  const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{8, false});
  SelectionParams params;
  params.maxBrickEdge = 8;
  params.restricted = false;
  const Selection loose = selectNodes(t, params);
  EXPECT_FALSE(isRestricted(t, loose));
  params.restricted = true;
  const Selection restricted = selectNodes(t, params);
  EXPECT_TRUE(isRestricted(t, restricted));
  EXPECT_GT(restricted.bricks.size(), loose.bricks.size());
  EXPECT_EQ(restricted.maxError, 0.0f);
}

TEST(Selection, TransparentNodesCostNothing) {
  const Volume v = test::sphereVolume({65, 65, 65}, 20.0);  // values from about −35 to 20
  const VolumeOctree t = VolumeOctree::build(v);
  SelectionParams params;
  params.maxBrickEdge = 16;
  params.opacity = [](float, float hi) { return hi >= 5.0f ? 1.0f : 0.0f; };  // only the core is visible
  const Selection sel = selectNodes(t, params);
  uint64_t visibleCells = 0;
  for (const Brick& b : sel.bricks) {
    const OctreeNode& n = t.nodes()[b.node];
    EXPECT_EQ(b.hidden, n.maxValue < 5.0f);
    if (b.hidden) {
      EXPECT_EQ(b.texelCount(), 0u);
    } else {
      visibleCells += cellsOf(t, n);
    }
  }
  EXPECT_LT(visibleCells, uint64_t(64 * 64 * 64) / 2);
  EXPECT_LT(sel.texels, selectNodes(t, SelectionParams{}).texels / 2);
  params.opacity = [](float, float) { return 0.0f; };
  const Selection none = selectNodes(t, params);
  ASSERT_EQ(none.bricks.size(), 1u);
  EXPECT_TRUE(none.bricks[0].hidden);
  EXPECT_EQ(none.texels, 0u);
}

TEST(Selection, DistanceFilterRefinesNodesNearTheEye) {
  const Volume v = test::randomVolume({65, 65, 65}, 8);
  const VolumeOctree t = VolumeOctree::build(v);
  SelectionParams params;
  params.maxBrickEdge = 8;
  params.epsilon = 1000.0f;  // ε_u alone keeps the root
  EXPECT_EQ(selectNodes(t, params).bricks.size(), 1u);
  params.eye = glm::dvec3(-1.0, -1.0, -1.0);  // just outside the corner at the origin
  const Selection sel = selectNodes(t, params);
  EXPECT_TRUE(isRestricted(t, sel));
  for (const Brick& b : sel.bricks) {
    const OctreeNode& n = t.nodes()[b.node];
    glm::ivec3 lo, hi;
    t.voxelBox(n, &lo, &hi);
    const double distance = glm::length(*params.eye - glm::clamp(*params.eye, glm::dvec3(lo), glm::dvec3(hi)));
    if (resolutionLevel(t, b) > 0) {
      EXPECT_GE(distance, glm::length(glm::dvec3(hi - lo))) << "a coarse brick nearer than its diagonal";
    }
    if (n.origin == glm::u16vec3(0)) {
      EXPECT_EQ(resolutionLevel(t, b), 0);  // the brick at the eye: one texel per voxel
    }
  }
}

TEST(Selection, ScreenSpaceStopLeavesTexelsNoFinerThanAPixel) {
  const Volume v = test::randomVolume({65, 65, 65}, 9);
  const VolumeOctree t = VolumeOctree::build(v);
  SelectionParams params;
  params.maxBrickEdge = 8;
  const uint64_t full = selectNodes(t, params).texels;
  params.pixelSize = [](const glm::dvec3&, const glm::dvec3&) { return 2.0; };  // 2 mm a pixel everywhere
  params.lodPixels = 1.0;
  const Selection sel = selectNodes(t, params);
  for (const Brick& b : sel.bricks) EXPECT_EQ(resolutionLevel(t, b), 1);  // texels 2 mm apart: refined no further
  EXPECT_LT(sel.texels, full / 6);
  params.lodPixels = 0.0;  // off
  EXPECT_EQ(selectNodes(t, params).texels, full);
  params.lodPixels = -1.0;
  EXPECT_THROW(selectNodes(t, params), ValueError);
}

TEST(Selection, FrustumCulledNodesCostNothing) {
  const Volume v = test::randomVolume({65, 65, 65}, 3);
  const VolumeOctree t = VolumeOctree::build(v);
  SelectionParams params;
  params.maxBrickEdge = 16;
  params.inView = [](const glm::dvec3& lo, const glm::dvec3&) { return lo.x < 32.0; };  // the half x < 32 is seen
  const Selection sel = selectNodes(t, params);
  for (const Brick& b : sel.bricks) EXPECT_EQ(b.hidden, t.nodes()[b.node].origin.x >= 32);
  EXPECT_LT(sel.texels, selectNodes(t, SelectionParams{}).texels * 6 / 10);
}

TEST(Selection, BlendCornersMarkCoarserNeighbours) {
  const Volume v = test::randomVolume({33, 33, 33}, 4);
  const VolumeOctree t = VolumeOctree::build(v);  // root edge 32, leaves edge 8
  // Root split into eight edge-16 children at p = 3 (ratio 2); child 0 split again (ratio 1).
  Selection sel;
  const OctreeNode& root = t.root();
  const OctreeNode& child0 = t.nodes()[childIndex(root, 0)];
  for (int s = 0; s < 8; ++s) sel.bricks.push_back({childIndex(child0, s), 3});
  for (int s = 1; s < 8; ++s) sel.bricks.push_back({childIndex(root, s), 3});
  assignBlendCorners(t, &sel);
  EXPECT_TRUE(isRestricted(t, sel));
  EXPECT_EQ(sel.bricks[0].coarseCorners, 0x00);  // [0,8]³: inside child 0
  EXPECT_EQ(sel.bricks[1].coarseCorners, 0xAA);  // [8,16]x[0,8]²: its x = 16 corners touch coarser bricks
  EXPECT_EQ(sel.bricks[7].coarseCorners, 0xFE);  // [8,16]³: all but (8,8,8)
  for (int b = 8; b < 15; ++b) EXPECT_EQ(sel.bricks[size_t(b)].coarseCorners, 0x00);
  EXPECT_EQ(sel.blendedBricks, 7u);
  // The coarse lattice: every other knot of the 9³ fine one.
  const KnotLattice c = t.coarseLattice(t.nodes()[sel.bricks[7].node], 3);
  EXPECT_EQ(c.origin, glm::ivec3(8));
  EXPECT_EQ(c.step, 2);
  EXPECT_EQ(c.dims, glm::ivec3(5));
}

TEST(Selection, TexelDimsAreCroppedToTheGrid) {
  const Volume v = test::randomVolume({33, 20, 9}, 1);
  const VolumeOctree t = VolumeOctree::build(v);
  // Root: edge 32; at p = 5 one texel per voxel, cut at the grid: exactly the grid's samples.
  EXPECT_EQ(t.texelDims(t.root(), 5), glm::ivec3(33, 20, 9));
  EXPECT_EQ(t.texelDims(t.root(), 0), glm::ivec3(2, 2, 2));
  // p = 2 (spacing 8): knots 0,8,16,19 in y and 0,8 in z.
  EXPECT_EQ(t.texelDims(t.root(), 2), glm::ivec3(5, 4, 2));
}

TEST(Selection, RejectsInvalidParameters) {
  const VolumeOctree t = VolumeOctree::build(test::randomVolume({9, 9, 9}, 1));
  SelectionParams params;
  params.epsilon = -1.0f;
  EXPECT_THROW(selectNodes(t, params), ValueError);
  params.epsilon = std::nanf("");
  EXPECT_THROW(selectNodes(t, params), ValueError);
  params.epsilon = 0.0f;
  params.maxBrickEdge = 48;
  EXPECT_THROW(selectNodes(t, params), ValueError);
}

// ---------------------------------------------------------------------------------------------
// The real CT

TEST(VolumeOctreeCranium, ExactSelectionAndSmallOverhead) {
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  EXPECT_EQ(t.depth(), 8);
  EXPECT_EQ(t.root().minValue, -1024.0f);
  EXPECT_EQ(t.root().maxValue, 2986.0f);
  EXPECT_LE(double(t.bytesUsed()), 0.15 * double(v.sourceBytes()));  // overhead target of the issue
  SelectionParams params;
  const Selection exact = selectNodes(t, params);
  EXPECT_EQ(exact.maxError, 0.0f);
  params.epsilon = 3000.0f;
  const Selection coarse = selectNodes(t, params);
  EXPECT_LT(coarse.texels, exact.texels / 10);
  EXPECT_LE(coarse.maxError, 3000.0f);
  // Spot-check the recurrence against the definition on a few nodes of every level.
  for (size_t i = 0; i < t.nodes().size(); i += 997) {
    const OctreeNode& n = t.nodes()[i];
    for (int p = 0; p <= std::min(2, t.maxLevel(n)); ++p)
      EXPECT_NEAR(t.errors(n)[size_t(p)], bruteForceNodalError(v, t, glm::ivec3(n.origin), t.edge(n), p), 0.05f);
  }
}

}  // namespace
}  // namespace hyb
