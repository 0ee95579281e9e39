#include "surface/triangulate.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <utility>
#include <vector>

#include "surface/dmc.h"

namespace hyb {
namespace {

// The triangulation is the polygon's constrained Delaunay one, measured in the polygon's own plane.
TEST(Triangulate, IsDelaunayInThePolygonsPlane) {
  // A 1 × 40 strip with a corner at every unit along both sides (T-junctions): ear clipping alone
  // fans it from one corner (edges up to √1601 long); its Delaunay triangles are half unit squares.
  constexpr int kLength = 40;
  std::vector<glm::ivec3> strip;
  std::vector<uint32_t> loop;
  for (int i = 0; i <= kLength; ++i) strip.push_back({i, 0, 0});
  for (int i = kLength; i >= 0; --i) strip.push_back({i, 1, 0});
  for (uint32_t i = 0; i < strip.size(); ++i) loop.push_back(i);
  std::vector<std::array<uint32_t, 3>> tris;
  ASSERT_TRUE(triangulatePolygon(strip, loop.data(), loop.size(), glm::ivec3(0, 0, 1), &tris));
  ASSERT_EQ(tris.size(), loop.size() - 2);
  int64_t area2 = 0;
  for (const auto& t : tris) {
    const glm::ivec3 a = strip[t[0]], b = strip[t[1]], c = strip[t[2]];
    const int64_t twice = int64_t(b.x - a.x) * (c.y - a.y) - int64_t(b.y - a.y) * (c.x - a.x);
    EXPECT_EQ(twice, 1);  // counter-clockwise, half a unit square
    area2 += twice;
    for (const auto& [p, q] : {std::pair{a, b}, std::pair{b, c}, std::pair{c, a}}) {
      const glm::ivec3 e = q - p;
      EXPECT_LE(e.x * e.x + e.y * e.y + e.z * e.z, 2);
    }
  }
  EXPECT_EQ(area2, 2 * kLength);
  // A kite in the plane x + y = 0 (normal (1,1,0)), diagonals A–C (A, C = ∓(3, −3, 0): 6√2 ≈ 8.49
  // long in the plane) and B–D (B, D = (0, 0, ∓4): 8 long). Delaunay takes the shorter, B–D; in
  // the dominant-axis projection (x dropped) A–C is 6 long and would win.
  const std::vector<glm::ivec3> kite = {{-3, 3, 0}, {0, 0, -4}, {3, -3, 0}, {0, 0, 4}};  // A, B, C, D
  const glm::ivec3 n(1, 1, 0);
  std::vector<uint32_t> order = {0, 1, 2, 3};
  const glm::ivec3 ab = kite[1] - kite[0], ac = kite[2] - kite[0];
  if (glm::dot(glm::vec3(glm::cross(glm::vec3(ab), glm::vec3(ac))), glm::vec3(n)) < 0) std::reverse(order.begin(), order.end());
  tris.clear();
  ASSERT_TRUE(triangulatePolygon(kite, order.data(), order.size(), n, &tris));
  ASSERT_EQ(tris.size(), size_t(2));
  for (const auto& t : tris) {
    EXPECT_TRUE(std::count(t.begin(), t.end(), 1u) == 1 && std::count(t.begin(), t.end(), 3u) == 1) << "diagonal A-C chosen";
  }
}

TEST(Triangulate, ATriangleMeshKeepsEachFacesTrianglesTogether) {
  // In the plane z = 0 (normal +z): the square with a vertex on an edge, and an L.
  const std::vector<glm::ivec3> p = {{0, 0, 0}, {2, 0, 0}, {2, 2, 0}, {0, 2, 0}, {1, 0, 0}, {1, 1, 0}, {1, 2, 0}};
  const std::vector<uint32_t> squareMid = {0, 4, 1, 2, 3}, ell = {0, 1, 5, 6, 3};
  DiscreteMesh m;
  m.vertices = p;
  const PlaneId plane{2, 1, 0};  // z = 0, normal +z
  m.addFace(squareMid.data(), squareMid.size(), plane);
  m.addFace(ell.data(), ell.size(), plane);
  const TriangleMesh t = toTriangleMesh(m, glm::dvec3(1.0));
  EXPECT_EQ(t.polygonStarts, (std::vector<uint32_t>{0, 3, 6}));
}

}  // namespace
}  // namespace hyb
