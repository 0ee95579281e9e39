#include "render/slices/proxy_geometry.h"

#include <gtest/gtest.h>

#include <cmath>
#include <set>

namespace hyb {
namespace {

// The distinct corners of a fanned slice polygon.
std::set<std::array<float, 3>> corners(const std::vector<float>& fan) {
  std::set<std::array<float, 3>> out;
  for (size_t v = 0; v < fan.size(); v += 3) out.insert({fan[v], fan[v + 1], fan[v + 2]});
  return out;
}

TEST(ProxyGeometry, SlicePolygonsOfAUnitCube) {
  std::vector<float> fan;
  // Across z: the square at z = 0.25.
  ASSERT_TRUE(slicePolygon(glm::dvec3(0.0), glm::dvec3(1.0), glm::dvec3(0, 0, 1), 0.25, &fan));
  EXPECT_EQ(fan.size(), 2u * 9u);  // two triangles
  EXPECT_EQ(corners(fan), (std::set<std::array<float, 3>>{{0, 0, 0.25f}, {1, 0, 0.25f}, {0, 1, 0.25f}, {1, 1, 0.25f}}));
  // Along the diagonal through the centre: a regular hexagon.
  fan.clear();
  const glm::dvec3 n = glm::normalize(glm::dvec3(1.0));
  ASSERT_TRUE(slicePolygon(glm::dvec3(0.0), glm::dvec3(1.0), n, glm::dot(n, glm::dvec3(0.5)), &fan));
  EXPECT_EQ(fan.size(), 4u * 9u);
  EXPECT_EQ(corners(fan).size(), 6u);
  for (const auto& c : corners(fan)) EXPECT_NEAR(std::hypot(c[0] - 0.5, c[1] - 0.5, c[2] - 0.5), std::sqrt(0.5), 1e-6);
  // Outside the box: nothing.
  fan.clear();
  EXPECT_FALSE(slicePolygon(glm::dvec3(0.0), glm::dvec3(1.0), glm::dvec3(0, 0, 1), 1.5, &fan));
  EXPECT_TRUE(fan.empty());
}

TEST(ProxyGeometry, ClippingToABoxAndDepthRanges) {
  std::vector<glm::dvec3> tri = {{-1, 0.5, 0.5}, {2, 0.5, 0.5}, {0.5, 3, 0.5}};
  clipToBox(glm::dvec3(0.0), glm::dvec3(1.0), &tri);
  for (const glm::dvec3& p : tri)
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(p[a], -1e-12);
      EXPECT_LE(p[a], 1 + 1e-12);
    }
  EXPECT_EQ(tri.size(), 4u);  // the band of the triangle inside the square
  const ProxyDepth planes{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)};
  EXPECT_EQ(planes.range(glm::dvec3(0, 0, 2), glm::dvec3(1, 1, 5)), std::make_pair(2.0, 5.0));
  const ProxyDepth shells{true, glm::dvec3(0, 0, 1), glm::dvec3(0.5, 0.5, -3)};
  const auto [near, far] = shells.range(glm::dvec3(0, 0, 0), glm::dvec3(1, 1, 1));
  EXPECT_DOUBLE_EQ(near, 3.0);
  EXPECT_DOUBLE_EQ(far, std::sqrt(0.5 + 16.0));
  EXPECT_DOUBLE_EQ(shells.of(glm::dvec3(0.5, 0.5, 1)), 4.0);
}

TEST(ProxyGeometry, ShellsStayOnTheirSphereInsideTheBox) {
  const glm::dvec3 eye(0.5, 0.5, -10), lo(0.0), hi(1.0);
  ShellFrame frame;
  ASSERT_TRUE(shellFrame(lo, hi, eye, &frame));
  std::vector<float> out;
  const double r = 10.5;
  ASSERT_TRUE(shellPolygon(lo, hi, frame, {eye, r, shellCells(frame, r, 0.1)}, &out));
  // Chords of the sphere: their vertices on it (the clipped ones inside its chords), all in the box.
  for (size_t v = 0; v < out.size(); v += 3) {
    const glm::dvec3 p(out[v], out[v + 1], out[v + 2]);
    EXPECT_LE(glm::length(p - eye), r + 1e-5);
    EXPECT_GE(glm::length(p - eye), r - 0.1 / 4 - 1e-5);  // a sagitta of a quarter of the spacing
    for (int a = 0; a < 3; ++a) EXPECT_TRUE(p[a] >= -1e-6 && p[a] <= 1 + 1e-6);
  }
  // A box around the eye cannot be seen as one shell frame.
  EXPECT_FALSE(shellFrame(glm::dvec3(-1.0), glm::dvec3(1.0), glm::dvec3(0.0), &frame));
}

TEST(ProxyGeometry, VisibleBlocksAreFoundOncePerTransferFunction) {
  BrickRanges ranges;
  ranges.blocks = glm::ivec3(5, 3, 2);
  for (int i = 0; i < 30; ++i) ranges.values.push_back({10.0f * float(i), 10.0f * float(i) + 5.0f});  // block i: [10i, 10i + 5]
  auto visibleOf = [](float from, float to) {
    const TransferFunction tf({{from - 1, {1, 1, 1}, 0.0f}, {from, {1, 1, 1}, 0.5f}, {to, {1, 1, 1}, 0.5f}, {to + 1, {1, 1, 1}, 0.0f}}, "window");
    const LutLayout layout(0.0f, 300.0f, tf);
    std::vector<glm::vec4> lut(LutLayout::kSize);
    for (int e = 0; e < LutLayout::kSize; ++e) lut[size_t(e)] = tf.lookup(layout.value(e));
    return VisibleValues(lut, layout);
  };
  const VisibleValues window = visibleOf(98, 142);  // opaque over (97, 143): blocks 10 to 14, the row y = 2 of layer z = 0
  VisibleBlocks blocks;
  findVisibleBlocks(ranges, window, &blocks);
  ASSERT_EQ(blocks.bits.size(), 1u);
  EXPECT_EQ(blocks.bits[0], uint64_t(0b11111) << 10);
  EXPECT_EQ(blocks.lo, glm::ivec3(0, 2, 0));
  EXPECT_EQ(blocks.hi, glm::ivec3(4, 2, 0));
  EXPECT_EQ(blocks.key, window.key());
  // The same transfer function again (a new camera): kept as they are, not searched again.
  blocks.bits[0] = 0;
  findVisibleBlocks(ranges, visibleOf(98, 142), &blocks);
  EXPECT_EQ(blocks.bits[0], 0u);
  // Another one: found anew. Nothing visible: empty.
  const VisibleValues upper = visibleOf(238, 262);  // blocks 24 (240–245, at x 4 y 1) to 26 (x 1 y 2), layer z = 1
  EXPECT_NE(upper.key(), window.key());
  findVisibleBlocks(ranges, upper, &blocks);
  EXPECT_EQ(blocks.bits[0], uint64_t(0b111) << 24);
  EXPECT_EQ(blocks.lo, glm::ivec3(0, 1, 1));
  EXPECT_EQ(blocks.hi, glm::ivec3(4, 2, 1));
  findVisibleBlocks(ranges, visibleOf(500, 600), &blocks);
  EXPECT_TRUE(blocks.empty());
  EXPECT_EQ(blocks.bits[0], 0u);
}

TEST(ProxyGeometry, ProxyBoxesHoldTheVisibleBlocksEachPlaneMeetsAlsoWhenMerged) {
  // A lattice of 9 knots of step 1 per axis: 4 blocks of 2 cells per axis. Visible: block (0, 0, 0)
  // (voxels 0–2 on each axis) and block (3, 0, 3) (x 6–8, y 0–2, z 6–8).
  KnotLattice L;
  L.dims = glm::ivec3(9);
  L.last = glm::ivec3(8);
  VisibleBlocks v;
  v.blocks = glm::ivec3(4);
  v.bits.assign(1, 0);
  auto set = [&](int x, int y, int z) { const int i = x + 4 * (y + 4 * z); v.bits[size_t(i) / 64] |= uint64_t(1) << (i % 64); };
  set(0, 0, 0);
  set(3, 0, 3);
  const ProxyDepth depth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)};  // planes z = k
  std::vector<std::pair<glm::dvec3, glm::dvec3>> boxes(9);
  const glm::dvec3 spacing(0.5, 1.0, 2.0);
  proxyBoxes(v, L, spacing, depth, {2.0, 0, 1}, &boxes);  // planes z = 0, 2, …, 16 mm
  // z = 0…4 mm meet the first block only, z = 12…16 mm the second, 6 and 10 mm neither.
  for (int k = 0; k <= 2; ++k) {
    EXPECT_EQ(boxes[size_t(k)].first, glm::dvec3(0.0)) << k;
    EXPECT_EQ(boxes[size_t(k)].second, glm::dvec3(1.0, 2.0, 4.0)) << k;
  }
  for (int k = 3; k <= 5; ++k) EXPECT_GT(boxes[size_t(k)].first.x, boxes[size_t(k)].second.x) << k;
  for (int k = 6; k <= 8; ++k) {
    EXPECT_EQ(boxes[size_t(k)].first, glm::dvec3(3.0, 0.0, 12.0)) << k;
    EXPECT_EQ(boxes[size_t(k)].second, glm::dvec3(4.0, 2.0, 16.0)) << k;
  }
  // Merged by 2: groups of 2³ blocks, visible where any block is: the boxes of the groups (0, 0, 0)
  // (voxels 0–4) and (1, 0, 1) (x 4–8, y 0–4, z 4–8), each over the planes its group spans.
  proxyBoxes(v, L, spacing, depth, {2.0, 0, 2}, &boxes);
  for (int k = 0; k <= 3; ++k) {
    EXPECT_EQ(boxes[size_t(k)].first, glm::dvec3(0.0)) << k;
    EXPECT_EQ(boxes[size_t(k)].second, glm::dvec3(2.0, 4.0, 8.0)) << k;
  }
  EXPECT_EQ(boxes[4].first, glm::dvec3(0.0));  // z = 8 mm: both groups' faces
  EXPECT_EQ(boxes[4].second, glm::dvec3(4.0, 4.0, 16.0));
  for (int k = 5; k <= 8; ++k) {
    EXPECT_EQ(boxes[size_t(k)].first, glm::dvec3(2.0, 0.0, 8.0)) << k;
    EXPECT_EQ(boxes[size_t(k)].second, glm::dvec3(4.0, 4.0, 16.0)) << k;
  }
  // Five blocks along x (11 knots), the last visible, merged by 2: the third group holds that block
  // alone and its box ends at the lattice's last knot.
  KnotLattice row;
  row.dims = glm::ivec3(11, 3, 3);
  row.last = glm::ivec3(10, 2, 2);
  VisibleBlocks last;
  last.blocks = glm::ivec3(5, 1, 1);
  last.bits.assign(1, uint64_t(1) << 4);
  std::vector<std::pair<glm::dvec3, glm::dvec3>> one(1);
  proxyBoxes(last, row, glm::dvec3(1.0), ProxyDepth{false, glm::dvec3(1, 0, 0), glm::dvec3(0.0)}, {100.0, 0, 2}, &one);  // plane x = 0 only
  EXPECT_GT(one[0].first.x, one[0].second.x);  // the group (x 8–10) does not reach x = 0
  proxyBoxes(last, row, glm::dvec3(1.0), ProxyDepth{false, glm::dvec3(1, 0, 0), glm::dvec3(0.0)}, {9.0, 1, 2}, &one);  // plane x = 9
  EXPECT_EQ(one[0].first, glm::dvec3(8.0, 0.0, 0.0));
  EXPECT_EQ(one[0].second, glm::dvec3(10.0, 2.0, 2.0));
}

}  // namespace
}  // namespace hyb
