#include "surface/dmc.h"

#include <gtest/gtest.h>

#include <map>
#include <numbers>
#include <set>

#include "hybrid_octree/volume_octree.h"
#include "surface/cgal_geometry.h"
#include "surface/dmc_table.h"
#include "surface/triangulate.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

// Binary volume of dims whose corner values come from a bit pattern (1 = inside at iso 0.5).
Volume binaryVolume(glm::ivec3 dims, const std::vector<int>& bits) {
  std::vector<float> s(bits.begin(), bits.end());
  return Volume(dims, glm::dvec3(1.0), ScalarType::UInt8, std::move(s), "binary");
}

// Checks a DiscMC triangle mesh of a block of cells: every face lies on its plane id, which is one of
// the 13 orientations and points outward; edges inside the block have exactly two faces with
// opposite directions; edges on the block's outer faces have one; vertex fans are single.
void expectWatertight(const DiscreteMesh& m, const glm::ivec3& dims, const std::string& what) {
  const glm::ivec3 hi = 2 * (dims - 1);
  std::map<std::pair<uint32_t, uint32_t>, int> directed;
  for (size_t f = 0; f < m.faceCount(); ++f) {
    const uint32_t* v = &m.indices[m.offsets[f]];
    const size_t n = m.faceSize(f);
    const PlaneId& plane = m.planes[f];
    ASSERT_GE(plane.orientation, 0);
    ASSERT_LT(plane.orientation, kOrientationCount);
    for (size_t k = 0; k < n; ++k) ASSERT_EQ(plane.eval(m.vertices[v[k]]), 0) << what << ": vertex off its face's plane";
    // Geometric normal of the first triangle agrees with the plane's normal direction.
    const glm::ivec3 g = icross(m.vertices[v[1]] - m.vertices[v[0]], m.vertices[v[2]] - m.vertices[v[0]]);
    ASSERT_GT(idot(g, plane.normal()), 0) << what << ": face orientation disagrees with its plane";
    for (size_t k = 0; k < n; ++k) ++directed[{v[k], v[(k + 1) % n]}];
  }
  auto onBoundary = [&](const glm::ivec3& a, const glm::ivec3& b) {
    for (int axis = 0; axis < 3; ++axis)
      if (a[axis] == b[axis] && (a[axis] == 0 || a[axis] == hi[axis])) return true;
    return false;
  };
  for (const auto& [e, count] : directed) {
    ASSERT_EQ(count, 1) << what << ": directed edge used twice (inconsistent orientation or non-manifold)";
    const bool hasTwin = directed.count({e.second, e.first}) > 0;
    if (!hasTwin) {
      ASSERT_TRUE(onBoundary(m.vertices[e.first], m.vertices[e.second])) << what << ": crack (open edge inside the block)";
    }
  }
}

TEST(DmcTable, DerivationMatchesTheVerifiedStatistics) {
  const dmc::CaseTableStats s = dmc::caseTableStats();
  EXPECT_EQ(s.solved, 254);
  EXPECT_EQ(s.byPlaneCount[1], 54);
  EXPECT_EQ(s.byPlaneCount[2], 118);
  EXPECT_EQ(s.byPlaneCount[3], 56);
  EXPECT_EQ(s.byPlaneCount[4], 26);
  EXPECT_EQ(s.maxLoopSize, 7);
  int folds = 0;
  for (int m = 0; m < 256; ++m) {
    const dmc::Case& c = dmc::caseTable()[size_t(m)];
    EXPECT_EQ(c.triangles.empty(), m == 0 || m == 255);
    if (!c.hasFold()) continue;
    ++folds;
    const dmc::Case& alt = dmc::alternativeCaseTable()[size_t(m)];
    ASSERT_FALSE(alt.triangles.empty());
    EXPECT_FALSE(alt.hasFold() && alt.fold == c.fold);
  }
  EXPECT_EQ(folds, 24);
}

TEST(DmcTable, EveryConfigurationAloneIsWatertightOnThirteenOrientations) {
  for (int m = 1; m < 255; ++m) {
    std::vector<int> bits(8);
    for (int c = 0; c < 8; ++c) bits[size_t(c)] = (m >> c) & 1;
    const Volume v = binaryVolume({2, 2, 2}, bits);
    expectWatertight(extractDiscMC(v, 0.5f, {}, DmcFaces::Triangles), v.dims(), "config " + std::to_string(m));
    expectWatertight(extractDiscMC(v, 0.5f, {}, DmcFaces::CellPolygons), v.dims(), "polygons " + std::to_string(m));
  }
}

TEST(DmcTable, EveryConfigurationWithEveryFaceNeighbourIsWatertight) {
  // Two cells side by side along each axis: the shared face's 4 corners are common, the far 4
  // corners of the neighbour take all 16 values: 256 x 3 axes x 16 = 12,288 pairs (each direction
  // of a face is covered by the configuration on the other side).
  size_t pairs = 0;
  for (int axis = 0; axis < 3; ++axis) {
    glm::ivec3 dims(2);
    dims[axis] = 3;
    for (int m = 0; m < 256; ++m)
      for (int far = 0; far < 16; ++far) {
        std::vector<int> bits(12);
        auto set = [&](glm::ivec3 p, int value) { bits[size_t(p.x + dims.x * (p.y + dims.y * p.z))] = value; };
        for (int c = 0; c < 8; ++c) set(glm::ivec3(c & 1, (c >> 1) & 1, (c >> 2) & 1), (m >> c) & 1);
        int k = 0;
        for (int c = 0; c < 8; ++c) {
          glm::ivec3 p(c & 1, (c >> 1) & 1, (c >> 2) & 1);
          if (p[axis] == 0) continue;
          p[axis] = 2;
          set(p, (far >> k++) & 1);
        }
        const Volume v = binaryVolume(dims, bits);
        expectWatertight(extractDiscMC(v, 0.5f, {}, DmcFaces::Triangles), dims,
                         "config " + std::to_string(m) + " axis " + std::to_string(axis) + " far " + std::to_string(far));
        if (::testing::Test::HasFatalFailure()) return;
        ++pairs;
      }
  }
  EXPECT_EQ(pairs, size_t(12288));
}

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

TEST(Triangulate, ConvexityIsExactAndAllowsStraightThroughVertices) {
  // In the plane z = 0 (normal +z): a square, the square with a vertex on an edge, an L, a
  // triangle, three collinear points; the square clockwise is convex too (it never turns back).
  const std::vector<glm::ivec3> p = {{0, 0, 0}, {2, 0, 0}, {2, 2, 0}, {0, 2, 0}, {1, 0, 0}, {1, 1, 0}, {1, 2, 0}};
  const glm::ivec3 n(0, 0, 1);
  const std::vector<uint32_t> square = {0, 1, 2, 3}, squareMid = {0, 4, 1, 2, 3}, ell = {0, 1, 5, 6, 3}, tri = {0, 1, 2},
                              line = {0, 4, 1}, clockwise = {3, 2, 1, 0};
  EXPECT_TRUE(isConvex(p, square.data(), square.size(), n));
  EXPECT_TRUE(isConvex(p, squareMid.data(), squareMid.size(), n));
  EXPECT_FALSE(isConvex(p, ell.data(), ell.size(), n));
  EXPECT_TRUE(isConvex(p, tri.data(), tri.size(), n));
  EXPECT_FALSE(isConvex(p, line.data(), line.size(), n));
  EXPECT_TRUE(isConvex(p, clockwise.data(), clockwise.size(), n));
  EXPECT_FALSE(isConvex(p, square.data(), 2, n));
  // toTriangleMesh keeps the loops of the convex faces only, next to every face's triangles.
  DiscreteMesh m;
  m.vertices = p;
  const PlaneId plane{2, 1, 0};  // z = 0, normal +z
  m.addFace(squareMid.data(), squareMid.size(), plane);
  m.addFace(ell.data(), ell.size(), plane);
  const TriangleMesh t = toTriangleMesh(m, glm::dvec3(1.0));
  EXPECT_EQ(t.polygonStarts, (std::vector<uint32_t>{0, 3, 6}));
  EXPECT_EQ(t.loopStarts, (std::vector<uint32_t>{0, 5, 5}));
  EXPECT_EQ(t.loops.size(), 5u);
}

TEST(Dmc, RandomBinaryBlocksAreManifold) {
  // Larger random blocks exercise the fold conflict rule (two folds on one face).
  std::mt19937 rng(7);
  for (int trial = 0; trial < 300; ++trial) {
    std::vector<int> bits(64);
    for (int& b : bits) b = int(rng() & 1);
    const Volume v = binaryVolume({4, 4, 4}, bits);
    expectWatertight(extractDiscMC(v, 0.5f, {}, DmcFaces::Triangles), v.dims(), "trial " + std::to_string(trial));
    if (::testing::Test::HasFatalFailure()) return;
  }
}

TEST(Dmc, SphereAndTorusAreClosedManifoldAndWithinHalfACell) {
  struct Shape {
    std::string name;
    Volume volume;
    std::function<double(glm::dvec3)> distance;  // signed distance to the analytic surface, voxels
  };
  std::vector<Shape> shapes;
  for (double r : {3.3, 7.6, 12.2}) {
    const glm::ivec3 dims(int(2 * r) + 6);
    const glm::dvec3 c = glm::dvec3(dims - 1) * 0.5;
    shapes.push_back({"sphere " + std::to_string(r), test::sphereVolume(dims, r), [c, r](glm::dvec3 p) { return glm::length(p - c) - r; }});
  }
  for (auto [R, r] : {std::pair{8.3, 3.1}, std::pair{12.5, 5.2}}) {
    const glm::ivec3 dims(int(2 * (R + r)) + 6, int(2 * (R + r)) + 6, int(2 * r) + 6);
    const glm::dvec3 c = glm::dvec3(dims - 1) * 0.5;
    auto dist = [c, R, r](glm::dvec3 p) {
      const glm::dvec3 q = p - c;
      return glm::length(glm::dvec2(glm::length(glm::dvec2(q.x, q.y)) - R, q.z)) - r;
    };
    shapes.push_back({"torus", test::makeVolume(dims, [&](int i, int j, int k) { return -dist(glm::dvec3(i, j, k)); }), dist});
  }
  for (const Shape& s : shapes) {
    const DiscreteMesh m = extractDiscMC(s.volume, 0.0f);
    ASSERT_GT(m.faceCount(), size_t(0)) << s.name;
    expectWatertight(m, s.volume.dims(), s.name);
    for (const glm::ivec3& p : m.vertices) EXPECT_LE(std::fabs(s.distance(glm::dvec3(p) * 0.5)), 0.5 + 1e-9) << s.name;
    const MeshCheck c = checkMesh(toTriangleMesh(m, glm::dvec3(1.0)));
    EXPECT_TRUE(c.manifold) << s.name;
    EXPECT_TRUE(c.closed) << s.name;
    EXPECT_FALSE(c.selfIntersecting) << s.name;
    EXPECT_TRUE(c.outward) << s.name;
    EXPECT_EQ(c.boundaryEdges, size_t(0)) << s.name;
  }
}

TEST(Dmc, SphereVolumeAndHausdorffAgainstMarchingCubes) {
  const double r = 10.4;
  const Volume v = test::sphereVolume(glm::ivec3(27), r);
  const TriangleMesh dmcMesh = toTriangleMesh(extractDiscMC(v, 0.0f), glm::dvec3(1.0));
  const TriangleMesh mc = extractMarchingCubes(v, 0.0f);
  const MeshCheck a = checkMesh(dmcMesh), b = checkMesh(mc);
  const double exact = 4.0 / 3.0 * std::numbers::pi * r * r * r;
  EXPECT_NEAR(b.volume, exact, 0.02 * exact);  // interpolated MC: close to the sphere
  EXPECT_NEAR(a.volume, exact, 0.10 * exact);  // midpoints: within half a cell everywhere
  EXPECT_LE(hausdorffDistance(dmcMesh, mc, 0.01).upper, 0.5 + 0.01);
  EXPECT_EQ(dmcMesh.triangles.size(), mc.triangles.size());  // same loops, same triangle count
}

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

TEST(Dmc, DegenerateValues) {
  const Volume sphere = test::sphereVolume(glm::ivec3(9), 3.0);
  EXPECT_EQ(extractDiscMC(sphere, sphere.minValue() - 1.0f).faceCount(), size_t(0));  // all inside
  EXPECT_EQ(extractDiscMC(sphere, sphere.maxValue() + 1.0f).faceCount(), size_t(0));  // all outside
  EXPECT_EQ(extractDiscMC(sphere, sphere.minValue()).faceCount(), size_t(0));         // ≥ iso everywhere
  EXPECT_EQ(extractMarchingCubes(sphere, sphere.maxValue() + 1.0f).triangles.size(), size_t(0));
  const Volume constant = test::makeVolume({5, 4, 3}, [](int, int, int) { return 7.0f; });
  EXPECT_EQ(extractDiscMC(constant, 7.0f).faceCount(), size_t(0));
  // Isovalue equal to sample values: samples at iso count as inside; a box of 1s on 0s at iso 1.
  const Volume box = test::boxVolume({6, 6, 6}, glm::ivec3(2), glm::ivec3(3), 1.0f, 0.0f);
  const DiscreteMesh m = extractDiscMC(box, 1.0f);
  expectWatertight(m, box.dims(), "box at iso = sample value");
  const MeshCheck c = checkMesh(toTriangleMesh(m, glm::dvec3(1.0)));
  EXPECT_TRUE(c.closed && !c.selfIntersecting);
  // MC with iso equal to the inside value puts vertices on the inside corners: still a valid count.
  EXPECT_EQ(extractMarchingCubes(box, 1.0f).triangles.size(), m.triangleCount());
  // The smallest volume: one cell.
  const Volume tiny = binaryVolume({2, 2, 2}, {1, 0, 0, 0, 0, 0, 0, 0});
  EXPECT_EQ(extractDiscMC(tiny, 0.5f).faceCount(), size_t(1));
  EXPECT_EQ(extractMarchingCubes(tiny, 0.5f).triangles.size(), size_t(1));
  // Single slices have no cells.
  EXPECT_EQ(extractDiscMC(test::randomVolume({5, 5, 1}, 1), 0.0f).faceCount(), size_t(0));
}

TEST(Dmc, OctreeCullingGivesTheSameSurface) {
  const Volume v = test::sphereVolume({40, 33, 29}, 11.0);
  const VolumeOctree t = VolumeOctree::build(v);
  const std::vector<VoxelBlock> blocks = isoBlocks(t, 0.0f);
  EXPECT_LT(blocks.size(), size_t(5 * 4 * 4));  // fewer than the 80 leaves
  const DiscreteMesh culled = extractDiscMC(v, 0.0f, blocks), full = extractDiscMC(v, 0.0f);
  EXPECT_EQ(culled.faceCount(), full.faceCount());
  EXPECT_EQ(culled.vertices.size(), full.vertices.size());
  EXPECT_EQ(extractMarchingCubes(v, 0.0f, blocks).triangles.size(), extractMarchingCubes(v, 0.0f).triangles.size());

  // Leaves wider than a 64-bit row of samples are cut along x: nothing lost or doubled at the cuts.
  const Volume wide = test::randomVolume({150, 9, 7}, 3);
  VolumeOctreeOptions o;
  o.leafEdge = 256;
  const std::vector<VoxelBlock> whole = isoBlocks(VolumeOctree::build(wide, o), 0.0f);
  ASSERT_EQ(whole.size(), size_t(1));
  EXPECT_EQ(whole[0].hi.x - whole[0].lo.x, 149);
  const DiscreteMesh a = extractDiscMC(wide, 0.0f, whole), b = extractDiscMC(wide, 0.0f);
  EXPECT_EQ(a.faceCount(), b.faceCount());
  EXPECT_EQ(a.vertices.size(), b.vertices.size());
  size_t expected = 0;  // MC triangles counted cell by cell
  for (int k = 0; k + 1 < 7; ++k)
    for (int j = 0; j + 1 < 9; ++j)
      for (int i = 0; i + 1 < 150; ++i) {
        unsigned mask = 0;
        for (int c = 0; c < 8; ++c) mask |= unsigned(wide.at(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1)) >= 0.0f) << c;
        for (const auto& loop : dmc::caseTable()[mask].loops) expected += loop.size() - 2;
      }
  EXPECT_EQ(extractMarchingCubes(wide, 0.0f, whole).triangles.size(), expected);
  EXPECT_EQ(extractMarchingCubes(wide, 0.0f).triangles.size(), expected);
}

TEST(DmcCranium, BoneAndSkinSurfacesAreManifold) {
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  for (float iso : {400.0f, -500.0f}) {
    const DiscreteMesh m = extractDiscMC(v, iso, isoBlocks(t, iso));
    EXPECT_GT(m.faceCount(), size_t(100000));
    const MeshCheck c = checkMesh(toTriangleMesh(m, v.spacing()));
    EXPECT_TRUE(c.manifold) << iso;
    EXPECT_FALSE(c.selfIntersecting) << iso;
    EXPECT_GT(c.boundaryEdges, size_t(0));  // cut open by the volume's box
  }
}

}  // namespace
}  // namespace hyb
