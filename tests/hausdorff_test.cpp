#include "surface/cgal_geometry.h"

#include <gtest/gtest.h>

#include <cmath>

#include "surface/dmc.h"
#include "test_util.h"

namespace hyb {
namespace {

// Closed-form Hausdorff distances: the bracket holds the exact value and is no wider than asked.
TEST(Hausdorff, BracketsClosedFormDistances) {
  auto square = [](float z, float size) {  // [0,size]² at height z, two triangles
    TriangleMesh m;
    m.vertices = {{0, 0, z}, {size, 0, z}, {size, size, z}, {0, size, z}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}};
    return m;
  };
  auto within = [](const HausdorffBracket& h, double exact, double bound) {
    EXPECT_LE(h.lower, exact + 1e-6);  // the squares' corners are floats
    EXPECT_GE(h.upper, exact - 1e-6);
    EXPECT_LE(h.upper - h.lower, bound + 1e-12);
  };
  // Parallel squares 0.3 apart; a half square (the far edge of the whole one is 0.5 from it, in
  // one direction only: the distance is symmetric's larger side).
  within(hausdorffDistance(square(0, 1), square(0.3f, 1), 0.01), 0.3, 0.01);
  within(hausdorffDistance(square(0, 1), square(0, 0.5f), 0.01), 0.5 * std::sqrt(2.0), 0.01);
  within(hausdorffDistance(square(0, 0.5f), square(0, 1), 0.001), 0.5 * std::sqrt(2.0), 0.001);
  // An acute triangle against its own corners (degenerate triangles, points): every corner of it
  // is on the other mesh, the farthest point is its circumcentre (not a midpoint of any
  // subdivision), a circumradius away — found only by splitting the triangle.
  TriangleMesh acute, corners;
  acute.vertices = corners.vertices = {{0, 0, 0}, {1, 0, 0}, {0.3f, 0.8f, 0}};
  acute.triangles = {{0, 1, 2}};
  corners.triangles = {{0, 0, 0}, {1, 1, 1}, {2, 2, 2}};
  const glm::dvec3 a0(acute.vertices[0]), a1(acute.vertices[1]), a2(acute.vertices[2]);
  const double circumradius =
      glm::length(a1 - a0) * glm::length(a2 - a1) * glm::length(a0 - a2) / (2.0 * glm::length(glm::cross(a1 - a0, a2 - a0)));
  for (const double bound : {0.05, 0.002}) within(hausdorffDistance(acute, corners, bound), circumradius, bound);
  // Without the splits the bracket stays true, only wide: the corners' 0 and the enclosing radius
  // (the circumradius itself: the triangle is acute).
  const HausdorffBracket rough = hausdorffDistance(acute, corners, 0.002, 0);
  EXPECT_EQ(rough.lower, 0.0);
  EXPECT_NEAR(rough.upper, circumradius, 1e-6);
  // Degenerate triangles (a point, a segment) are measured as the sets they are.
  TriangleMesh flat = square(0, 1);
  flat.vertices.push_back({2, 0, 0});
  flat.triangles.push_back({1, 4, 4});  // the segment (1,0,0)-(2,0,0)
  within(hausdorffDistance(flat, square(0, 1), 0.01), 1.0, 0.01);
  within(hausdorffDistance(square(0, 1), flat, 0.01), 1.0, 0.01);
  TriangleMesh stray = square(0, 1);
  stray.vertices.push_back({0, 0, 50});  // no triangle uses it: not part of the surface
  within(hausdorffDistance(stray, square(0.2f, 1), 0.01), 0.2, 0.01);
  // Empty meshes; a bound that is not positive is refused.
  EXPECT_EQ(hausdorffDistance(TriangleMesh{}, TriangleMesh{}, 0.01).upper, 0.0);
  EXPECT_TRUE(std::isinf(hausdorffDistance(square(0, 1), TriangleMesh{}, 0.01).lower));
  EXPECT_THROW(hausdorffDistance(square(0, 1), square(0, 1), 0.0), ValueError);
  EXPECT_THROW(hausdorffDistance(square(0, 1), square(0, 1), std::nan("")), ValueError);
}

// Slivers, as a fanned polygon has them: a 60 × 1 strip with a corner every unit along both long
// sides, fanned from one corner (triangles up to 60 long and 1/60 wide), against the same strip
// 0.3 above it cut into unit squares. The distance is 0.3 exactly; bisecting at the longest edge
// settles the fan in ~170 k splits of one query each, where four-way splits (three queries each)
// keep every piece a sliver and need ~750 k: past this limit their bracket is 30 units wide.
TEST(Hausdorff, SettlesSliversWithinAModestWorkLimit) {
  constexpr int kLength = 60;
  TriangleMesh fan, squares;
  for (int i = 0; i <= kLength; ++i) fan.vertices.push_back({float(i), 0, 0});
  for (int i = kLength; i >= 0; --i) fan.vertices.push_back({float(i), 1, 0});
  for (uint32_t i = 1; i + 1 < fan.vertices.size(); ++i) fan.triangles.push_back({0, i, i + 1});
  for (int i = 0; i <= kLength; ++i) squares.vertices.insert(squares.vertices.end(), {{float(i), 0, 0.3f}, {float(i), 1, 0.3f}});
  for (uint32_t i = 0; i < uint32_t(kLength); ++i)
    squares.triangles.insert(squares.triangles.end(), {{2 * i, 2 * i + 2, 2 * i + 3}, {2 * i, 2 * i + 3, 2 * i + 1}});
  const HausdorffBracket h = hausdorffDistance(fan, squares, 0.01, 500000);
  EXPECT_LE(h.lower, 0.3 + 1e-6);
  EXPECT_GE(h.upper, 0.3 - 1e-6);
  EXPECT_LE(h.upper - h.lower, 0.01 + 1e-12);
}

// Against brute force on curved meshes: DiscMC's and MC's spheres (anisotropic voxels), each
// triangle's corners, edge midpoints and centroid measured against every triangle of the other.
TEST(Hausdorff, AgreesWithBruteForceSampling) {
  const Volume v = test::sphereVolume(glm::ivec3(11), 3.7);
  const TriangleMesh a = toTriangleMesh(extractDiscMC(v, 0.0f), glm::dvec3(1.0, 1.0, 1.5)), b = extractMarchingCubes(v, 0.0f);
  TriangleMesh bMm = b;
  for (glm::vec3& p : bMm.vertices) p.z *= 1.5f;
  auto segment = [](glm::dvec3 p, glm::dvec3 s0, glm::dvec3 s1) {
    const double t = glm::clamp(glm::dot(p - s0, s1 - s0) / std::max(glm::dot(s1 - s0, s1 - s0), 1e-300), 0.0, 1.0);
    return glm::length(p - (s0 + t * (s1 - s0)));
  };
  auto pointTriangle = [&](glm::dvec3 p, glm::dvec3 t0, glm::dvec3 t1, glm::dvec3 t2) {  // the plane inside, else the edges
    const glm::dvec3 n = glm::cross(t1 - t0, t2 - t0);
    const double nn = glm::dot(n, n);
    if (nn > 0.0) {
      const glm::dvec3 q = p - n * (glm::dot(p - t0, n) / nn);
      if (glm::dot(glm::cross(t1 - t0, q - t0), n) >= 0 && glm::dot(glm::cross(t2 - t1, q - t1), n) >= 0 && glm::dot(glm::cross(t0 - t2, q - t2), n) >= 0)
        return glm::length(p - q);
    }
    return std::min({segment(p, t0, t1), segment(p, t1, t2), segment(p, t2, t0)});
  };
  auto sampled = [&](const TriangleMesh& from, const TriangleMesh& to) {
    double worst = 0.0;
    for (const glm::uvec3& t : from.triangles)
      for (const glm::dvec3 w : {glm::dvec3(1, 0, 0), glm::dvec3(0.5, 0.5, 0), glm::dvec3(1.0 / 3.0)}) {
        const glm::dvec3 p = w.x * glm::dvec3(from.vertices[t.x]) + w.y * glm::dvec3(from.vertices[t.y]) + w.z * glm::dvec3(from.vertices[t.z]);
        double d = 1e300;
        for (const glm::uvec3& u : to.triangles)
          d = std::min(d, pointTriangle(p, to.vertices[u.x], to.vertices[u.y], to.vertices[u.z]));
        worst = std::max(worst, d);
      }
    return worst;
  };
  const double brute = std::max(sampled(a, bMm), sampled(bMm, a));
  const HausdorffBracket h = hausdorffDistance(a, bMm, 0.005);
  EXPECT_GE(h.upper + 1e-6, brute);  // no sampled point is farther than the upper end
  EXPECT_LE(h.upper - h.lower, 0.005 + 1e-12);
  EXPECT_GT(h.lower, 0.2);  // DiscMC's vertices are not MC's
  EXPECT_LE(h.upper, 0.5 * glm::length(glm::dvec3(1.0, 1.0, 1.5)) + 0.005);  // within half a cell's diagonal
}

}  // namespace
}  // namespace hyb
