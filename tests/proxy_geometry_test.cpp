#include "render/proxy_geometry.h"

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
  ASSERT_TRUE(shellPolygon(lo, hi, eye, frame, r, shellCells(frame, r, 0.1), &out));
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

}  // namespace
}  // namespace hyb
