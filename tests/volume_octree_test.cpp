#include "hybrid_octree/volume_octree.h"

#include <gtest/gtest.h>

#include <numeric>
#include <set>

#include "hybrid_octree/selection.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using test::bruteForceNodalError;

// Every node's closed box, cut at the grid.
void boxOf(const VolumeOctree& t, const OctreeNode& n, glm::ivec3* lo, glm::ivec3* hi) { t.voxelBox(n, lo, hi); }

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

TEST(VolumeOctreeCranium, ExactSelectionAndSmallOverhead) {
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  EXPECT_EQ(t.depth(), 8);
  EXPECT_EQ(t.root().minValue, -1024.0f);
  EXPECT_EQ(t.root().maxValue, 2986.0f);
  EXPECT_LE(double(t.bytesUsed()), 0.15 * double(v.sourceBytes()));  // the octree may cost at most 15 % of the volume
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
