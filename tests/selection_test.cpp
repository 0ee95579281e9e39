#include "hybrid_octree/selection.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <set>

#include "hybrid_octree/volume_octree.h"
#include "render/brick_error.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

uint64_t cellsOf(const VolumeOctree& t, const OctreeNode& n) {
  glm::ivec3 lo, hi;
  t.voxelBox(n, &lo, &hi);
  const glm::ivec3 c = glm::max(hi - lo, glm::ivec3(0));
  return uint64_t(c.x) * c.y * c.z;
}

uint64_t summedTexels(const Selection& sel) {
  uint64_t sum = 0;
  for (const Brick& b : sel.bricks) sum += b.texelCount();
  return sum;
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

// How many bricks of @p sel cover each cell of the grid.
std::vector<int> cellCoverage(const VolumeOctree& t, const Selection& sel) {
  const glm::ivec3 c = t.dims() - 1;
  std::vector<int> covered(size_t(c.x) * size_t(c.y) * size_t(c.z), 0);
  for (const Brick& b : sel.bricks) {
    glm::ivec3 lo, hi;
    t.voxelBox(t.nodes()[b.node], &lo, &hi);
    for (int z = lo.z; z < hi.z; ++z)
      for (int y = lo.y; y < hi.y; ++y)
        for (int x = lo.x; x < hi.x; ++x) ++covered[size_t(x) + size_t(c.x) * (size_t(y) + size_t(c.y) * size_t(z))];
  }
  return covered;
}

TEST(Selection, BricksNotResidentAreDrawnFromTheFinestResidentCoarserBrickWithoutAHole) {
  const Volume v = test::randomVolume({70, 45, 33}, 11);
  const VolumeOctree t = VolumeOctree::build(v);
  const Selection full = selectNodes(t, SelectionParams{});  // full resolution: bricks of edge 16 at spacing 1
  const glm::ivec3 cells = t.dims() - 1;
  auto spacing = [&](const Brick& b) { return t.edge(t.nodes()[b.node]) >> b.p; };
  for (const int resident : {2, 8, 32, 64}) {  // lattices at least this far apart are at hand
    SCOPED_TRACE(resident);
    std::vector<Brick> missing;
    const Selection drawn = residentSelection(t, full, [&](const Brick& b) { return spacing(b) >= resident; }, &missing);
    EXPECT_EQ(missing.size(), full.bricks.size());
    // The same nodes at a coarser level while their edge allows it, then their ancestors of that edge.
    const int edge = std::max(resident, 16);
    const glm::ivec3 nodes = (cells + edge - 1) / edge;
    EXPECT_EQ(drawn.bricks.size(), size_t(nodes.x * nodes.y * nodes.z));
    uint64_t texels = 0;
    for (const Brick& b : drawn.bricks) {
      EXPECT_EQ(spacing(b), resident);
      EXPECT_EQ(t.edge(t.nodes()[b.node]), edge);
      EXPECT_EQ(b.error, t.errors(t.nodes()[b.node])[size_t(b.p)]);
      texels += b.texelCount();
    }
    EXPECT_EQ(drawn.texels, texels);
    const std::vector<int> covered = cellCoverage(t, drawn);
    EXPECT_TRUE(std::all_of(covered.begin(), covered.end(), [](int c) { return c == 1; }));  // every cell once: no hole, no overlap
  }
  // Half the bricks at hand: those keep their level, the others' ancestors of edge 32 replace them and their siblings.
  std::vector<Brick> missing;
  auto even = [&](const Brick& b) { return b.node % 2 == 0; };
  const Selection drawn = residentSelection(t, full, [&](const Brick& b) { return spacing(b) == 1 ? even(b) : spacing(b) >= 32; }, &missing);
  EXPECT_EQ(missing.size(), size_t(std::count_if(full.bricks.begin(), full.bricks.end(), [&](const Brick& b) { return !even(b); })));
  const std::vector<int> covered = cellCoverage(t, drawn);
  EXPECT_TRUE(std::all_of(covered.begin(), covered.end(), [](int c) { return c == 1; }));
  for (const Brick& b : drawn.bricks) EXPECT_TRUE(spacing(b) == 1 ? even(b) : spacing(b) == 32);
  // Everything at hand: the selection itself.
  missing.clear();
  const Selection same = residentSelection(t, full, [](const Brick&) { return true; }, &missing);
  EXPECT_TRUE(missing.empty());
  ASSERT_EQ(same.bricks.size(), full.bricks.size());
  for (size_t i = 0; i < same.bricks.size(); ++i) EXPECT_EQ(same.bricks[i].node, full.bricks[i].node);
  EXPECT_EQ(same.texels, full.texels);
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

}  // namespace
}  // namespace hyb
