#include "surface/cgal_geometry.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <cmath>
#include <map>
#include <numbers>

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

// An n × n grid of squares over [0, size]² at height z, each cut into two triangles.
TriangleMesh grid(int n, float size, float z) {
  TriangleMesh m;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) m.vertices.push_back({size * float(i) / float(n), size * float(j) / float(n), z});
  for (uint32_t j = 0; j < uint32_t(n); ++j)
    for (uint32_t i = 0; i < uint32_t(n); ++i) {
      const uint32_t a = j * uint32_t(n + 1) + i, b = a + 1, c = a + uint32_t(n + 1) + 1, d = a + uint32_t(n + 1);
      m.triangles.insert(m.triangles.end(), {{a, b, c}, {a, c, d}});
    }
  return m;
}

// A sphere of radius @p r about the origin: an octahedron whose triangles are split in four @p levels
// times, every vertex on the sphere (closed: edge midpoints shared).
TriangleMesh sphere(double r, int levels) {
  std::vector<glm::dvec3> v{{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
  std::vector<glm::uvec3> t{{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4}, {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}};
  for (int l = 0; l < levels; ++l) {
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> middle;
    auto mid = [&](uint32_t a, uint32_t b) {
      const auto [it, added] = middle.try_emplace(std::minmax(a, b), uint32_t(v.size()));
      if (added) v.push_back(glm::normalize(v[a] + v[b]));
      return it->second;
    };
    std::vector<glm::uvec3> next;
    for (const glm::uvec3& f : t) {
      const uint32_t ab = mid(f.x, f.y), bc = mid(f.y, f.z), ca = mid(f.z, f.x);
      next.insert(next.end(), {{f.x, ab, ca}, {ab, f.y, bc}, {ca, bc, f.z}, {ab, bc, ca}});
    }
    t = std::move(next);
  }
  TriangleMesh m;
  for (const glm::dvec3& p : v) m.vertices.push_back(glm::vec3(r * p));
  m.triangles = t;
  return m;
}

// The sampled distance's exact parts: a square grid (squares 0.1 wide) and the same 0.3 above it
// are 0.3 apart at every point. A triangle's bound is its corners' largest distance to a triangle
// nearest one of them, which holds the point above that corner: the others are within the
// triangle's diagonal of it sideways. The samples number about density × both areas.
TEST(SampledHausdorff, ShiftedPlaneIsMeasuredExactly) {
  const SampledHausdorffOptions options{0.05, 0.999};
  const SampledHausdorff h = sampledHausdorffDistance(grid(10, 1.0f, 0.0f), grid(10, 1.0f, 0.3f), options);
  EXPECT_NEAR(h.lower, 0.3, 1e-6);  // float vertices
  EXPECT_GE(h.upper, 0.3 - 1e-6);
  EXPECT_LE(h.upper, std::sqrt(0.3 * 0.3 + 2 * 0.1 * 0.1) + 1e-6);
  EXPECT_DOUBLE_EQ(h.patchArea, std::numbers::pi * 0.05 * 0.05);
  EXPECT_EQ(h.confidence, 0.999);
  const double expected = 2.0 * std::log(2.0 / 0.001) / h.patchArea;  // two unit squares
  EXPECT_NEAR(double(h.samples), expected, 5.0 * std::sqrt(expected));  // Poisson: 5 standard deviations
}

// One vertex of a grid moved by d off the plane: the mesh is d from the flat one there and less
// everywhere else (every point of the moved fan is lower), d is reached only at that vertex, which
// the exact part measures: found whatever the samples.
TEST(SampledHausdorff, DisplacedVertexIsCaughtExactly) {
  TriangleMesh moved = grid(20, 1.0f, 0.0f);
  const float d = 0.37f;
  moved.vertices[7 * 21 + 12].z = d;
  for (const double confidence : {0.999, 0.01}) {  // almost no samples at 1 %: the vertex is still measured
    const SampledHausdorff h = sampledHausdorffDistance(moved, grid(20, 1.0f, 0.0f), {0.1, confidence});
    EXPECT_NEAR(h.lower, d, 1e-6) << confidence;
    EXPECT_GE(h.upper, d - 1e-6) << confidence;
    EXPECT_NEAR(sampledHausdorffDistance(grid(20, 1.0f, 0.0f), moved, {0.1, confidence}).lower, d, 1e-6) << confidence;
  }
}

// Concentric spheres, radii r < R, every vertex on its sphere: a point of one mesh is at least its
// sphere's gap from the other (R − r) and at most R − ρ, ρ the inner polyhedron's inradius (the
// ray from the centre meets the other mesh within its own spheres). The vertices of the outer
// mesh are R − r from the inner one's sphere, so the bracket holds [R − r, R − ρ]; the upper bound
// is at most that plus the largest triangle's enclosing radius.
TEST(SampledHausdorff, ConcentricSpheresWithinTheirTessellation) {
  const double r = 1.0, R = 1.25;
  const TriangleMesh inner = sphere(r, 3), outer = sphere(R, 3);
  double inradius = r, largest = 0.0;
  for (const TriangleMesh* m : {&inner, &outer})
    for (const glm::uvec3& t : m->triangles) {
      const glm::dvec3 a(m->vertices[t.x]), b(m->vertices[t.y]), c(m->vertices[t.z]);
      if (m == &inner) inradius = std::min(inradius, std::abs(glm::dot(glm::normalize(glm::cross(b - a, c - a)), a)));
      largest = std::max(largest, glm::length(glm::cross(b - a, c - a)) == 0.0 ? 0.0 : glm::length(a - b) * glm::length(b - c) * glm::length(c - a) /
                                                                                     (2.0 * glm::length(glm::cross(b - a, c - a))));
    }
  ASSERT_GT(inradius, 0.98 * r);  // a fine tessellation: the bracket is narrow
  for (const uint64_t seed : {1, 2, 3}) {
    const SampledHausdorff h = sampledHausdorffDistance(outer, inner, {0.02, 0.999, seed});
    EXPECT_GE(h.lower, R - r - 1e-6) << seed;
    EXPECT_LE(h.lower, R - inradius + 1e-6) << seed;
    EXPECT_GE(h.upper, h.lower) << seed;
    EXPECT_LE(h.upper, R - inradius + largest + 1e-6) << seed;  // the circumradius bounds the enclosing radius
  }
}

// A farthest point inside a triangle, not at a vertex: a square of half-width 0.25 against a
// ring about its centre (a regular 64-gon of radius 1, its edges as flat triangles, no area). A
// point x of the square is the apothem a minus |x| or so from the ring, at most a at the centre:
// what lies ≥ a − p from it is a 64-gon of inradius p, an area of 64 p² tan(π/64), 1.0008 times
// the patch π p². The square's corners are 0.65 from the ring and the ring's vertices at most
// 0.75 from the square, so only samples find more. They miss that 64-gon with probability
// exp(−density × its area) = ((1 − confidence) / 2)^1.0008: at 99.9 % every seed tried finds
// it; at 80 %, 10 % of seeds miss (400 seeds: 40, within 3 standard deviations).
TEST(SampledHausdorff, FindsAnInteriorFarthestPointAtItsConfidence) {
  const TriangleMesh square = grid(1, 0.5f, 0.0f);  // [0, 0.5]², two triangles: no vertex at its centre (0.25, 0.25)
  TriangleMesh ring;
  constexpr int kSides = 64;
  for (int i = 0; i < kSides; ++i) {
    const double angle = 2.0 * std::numbers::pi * i / kSides;
    ring.vertices.push_back({float(0.25 + std::cos(angle)), float(0.25 + std::sin(angle)), 0.0f});
    ring.triangles.push_back({uint32_t(i), uint32_t((i + 1) % kSides), uint32_t((i + 1) % kSides)});
  }
  const double apothem = std::cos(std::numbers::pi / kSides), p = 0.02;
  for (uint64_t seed = 1; seed <= 20; ++seed) {
    const SampledHausdorff h = sampledHausdorffDistance(square, ring, {p, 0.999, seed});
    EXPECT_GE(h.lower, apothem - p) << seed;
    EXPECT_LE(h.lower, apothem + 1e-6) << seed;
    EXPECT_GE(h.upper, apothem - 1e-6) << seed;
  }
  int missed = 0;
  for (uint64_t seed = 1; seed <= 400; ++seed) missed += sampledHausdorffDistance(square, ring, {p, 0.8, seed}).lower < apothem - p;
  EXPECT_NEAR(missed, 40, 3 * 6);  // binomial(400, 0.1): σ = 6
}

// On curved meshes (DiscMC's and MC's spheres, anisotropic voxels) the sampled bracket and the
// exact one both hold the distance, so they overlap; the largest distance is reached along whole
// regions, so the sampled lower end is within the patch radius of the exact one. The result does
// not depend on the threads.
TEST(SampledHausdorff, AgreesWithTheExactBracket) {
  const Volume v = test::sphereVolume(glm::ivec3(11), 3.7);
  const TriangleMesh a = toTriangleMesh(extractDiscMC(v, 0.0f), glm::dvec3(1.0, 1.0, 1.5));
  TriangleMesh b = extractMarchingCubes(v, 0.0f);
  for (glm::vec3& p : b.vertices) p.z *= 1.5f;
  const HausdorffBracket exact = hausdorffDistance(a, b, 0.001);
  const SampledHausdorffOptions options{0.05, 0.999};
  const SampledHausdorff h = sampledHausdorffDistance(a, b, options);
  EXPECT_LE(h.lower, exact.upper + 1e-9);
  EXPECT_GE(h.upper, exact.lower - 1e-9);
  EXPECT_GE(h.lower, exact.lower - options.patchRadius);
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const SampledHausdorff one = sampledHausdorffDistance(a, b, options);
  omp_set_num_threads(threads);
  EXPECT_EQ(one.lower, h.lower);
  EXPECT_EQ(one.upper, h.upper);
  EXPECT_EQ(one.samples, h.samples);
}

TEST(SampledHausdorff, RefusesBadOptionsAndMeasuresEmptyMeshes) {
  const TriangleMesh square = grid(1, 1.0f, 0.0f);
  for (const double radius : {0.0, -1.0, std::numeric_limits<double>::infinity(), std::nan("")})
    EXPECT_THROW(sampledHausdorffDistance(square, square, {radius, 0.9}), ValueError) << radius;
  for (const double confidence : {0.0, 1.0, 1.5, std::nan("")})
    EXPECT_THROW(sampledHausdorffDistance(square, square, {0.1, confidence}), ValueError) << confidence;
  TriangleMesh broken = square;
  broken.vertices[2].y = std::numeric_limits<float>::infinity();
  EXPECT_THROW(sampledHausdorffDistance(broken, square, {0.1, 0.9}), ValueError);
  EXPECT_EQ(sampledHausdorffDistance(TriangleMesh{}, TriangleMesh{}, {0.1, 0.9}).upper, 0.0);
  const SampledHausdorff one = sampledHausdorffDistance(square, TriangleMesh{}, {0.1, 0.9});
  EXPECT_TRUE(std::isinf(one.lower) && std::isinf(one.upper));
  EXPECT_EQ(one.samples, 0u);
}

// checkMesh's polygon mesh: CGAL's conditions, on soups that break one each.
TEST(MeshCheck, ManifoldIsCgalsPolygonMesh) {
  TriangleMesh tetra;  // outward
  tetra.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  tetra.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  MeshCheck c = checkMesh(tetra);
  EXPECT_TRUE(c.manifold && c.closed && c.outward && !c.selfIntersecting);
  EXPECT_EQ(c.boundaryEdges, 0u);
  EXPECT_NEAR(c.volume, 1.0 / 6.0, 1e-12);
  TriangleMesh inward = tetra;
  for (glm::uvec3& t : inward.triangles) std::swap(t.y, t.z);
  c = checkMesh(inward);
  EXPECT_TRUE(c.manifold && c.closed && !c.outward);
  EXPECT_NEAR(c.volume, -1.0 / 6.0, 1e-12);
  // Open: one face taken away leaves three boundary edges; a vertex no triangle uses changes nothing.
  TriangleMesh open = tetra;
  open.triangles.pop_back();
  open.vertices.push_back({5, 5, 5});
  c = checkMesh(open);
  EXPECT_TRUE(c.manifold && !c.closed && !c.selfIntersecting);
  EXPECT_EQ(c.boundaryEdges, 3u);
  // Two tetrahedra touching at a vertex: every edge has two triangles, but that vertex two fans.
  TriangleMesh pinched = tetra;
  for (const glm::vec3& p : {glm::vec3(-1, 0, 0), glm::vec3(0, -1, 0), glm::vec3(0, 0, -1)}) pinched.vertices.push_back(p);
  pinched.triangles.insert(pinched.triangles.end(), {{0, 4, 5}, {0, 5, 6}, {0, 6, 4}, {4, 6, 5}});
  c = checkMesh(pinched);
  EXPECT_FALSE(c.manifold);
  EXPECT_EQ(c.boundaryEdges, 0u);
  // Two open fans at one vertex (a bow tie).
  TriangleMesh bowtie;
  bowtie.vertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {-1, 0, 0}, {-1, -1, 0}};
  bowtie.triangles = {{0, 1, 2}, {0, 3, 4}};
  c = checkMesh(bowtie);
  EXPECT_FALSE(c.manifold);
  EXPECT_EQ(c.boundaryEdges, 6u);
  // An edge in three triangles; two triangles the same way round an edge; a repeated vertex.
  TriangleMesh three = open;
  three.vertices.push_back({1, 1, 1});
  three.triangles.push_back({0, 1, 5});  // edge 0-1 is in {0, 2, 1} and {0, 1, 3} already
  c = checkMesh(three);
  EXPECT_FALSE(c.manifold);
  EXPECT_EQ(c.boundaryEdges, 5u);  // 1-2, 2-3, 3-1 of the open tetrahedron, 1-5 and 5-0
  TriangleMesh flipped = grid(1, 1.0f, 0.0f);
  std::swap(flipped.triangles[1].y, flipped.triangles[1].z);
  EXPECT_FALSE(checkMesh(flipped).manifold);
  TriangleMesh repeated = grid(1, 1.0f, 0.0f);
  repeated.triangles.push_back({0, 0, 2});
  EXPECT_FALSE(checkMesh(repeated).manifold);
  EXPECT_TRUE(checkMesh(TriangleMesh{}).manifold);
}

// Self-intersections as CGAL's does_self_intersect finds them, on open manifold meshes too (their
// border halfedges linked): two squares crossing each other and not when apart; triangles joined
// along an edge only when coplanar and folded onto each other; joined at a vertex when the
// opposite edge of one pierces the other; a triangle whose corners are collinear.
TEST(MeshCheck, FindsSelfIntersectionsAsCgalDoes) {
  TriangleMesh crossing = grid(2, 1.0f, 0.0f);
  TriangleMesh upright = grid(2, 1.0f, 0.0f);
  for (glm::vec3& p : upright.vertices) p = {p.x, 0.5f, p.y - 0.5f};  // the plane y = 0.5, across z = 0
  const auto offset = uint32_t(crossing.vertices.size());
  crossing.vertices.insert(crossing.vertices.end(), upright.vertices.begin(), upright.vertices.end());
  for (const glm::uvec3& t : upright.triangles) crossing.triangles.push_back(t + offset);
  MeshCheck c = checkMesh(crossing);
  EXPECT_TRUE(c.manifold);
  EXPECT_TRUE(c.selfIntersecting);
  EXPECT_EQ(c.boundaryEdges, 16u);  // 8 a square
  for (size_t i = offset; i < crossing.vertices.size(); ++i) crossing.vertices[i].z += 2.0f;  // apart
  c = checkMesh(crossing);
  EXPECT_TRUE(c.manifold);
  EXPECT_FALSE(c.selfIntersecting);
  // Joined along edge 0-1: the fourth corner on the side of the third folds them; across, flat.
  for (const float side : {0.5f, -1.0f}) {
    TriangleMesh pair;
    pair.vertices = {{0, 0, 0}, {1, 0, 0}, {0.5f, 1, 0}, {0.5f, side, 0}};
    pair.triangles = {{0, 1, 2}, {1, 0, 3}};
    c = checkMesh(pair);
    EXPECT_TRUE(c.manifold) << side;
    EXPECT_EQ(c.selfIntersecting, side > 0.0f) << side;
  }
  // A fan about vertex 0: its last triangle's edge 3-4 pierces the first (at (0.5, 0.5, 0)), or
  // stays above it.
  for (const float end : {-1.0f, 2.0f}) {
    TriangleMesh fan;
    fan.vertices = {{0, 0, 0}, {2, 0, 0}, {0, 2, 0}, {0.5f, 0.5f, 1}, {0.5f, 0.5f, end}};
    fan.triangles = {{0, 1, 2}, {0, 2, 3}, {0, 3, 4}};
    c = checkMesh(fan);
    EXPECT_TRUE(c.manifold) << end;
    EXPECT_EQ(c.boundaryEdges, 5u) << end;
    EXPECT_EQ(c.selfIntersecting, end < 0.0f) << end;
  }
  // Vertex 2 on edge 0-1: triangle (0, 1, 2) has no area, in a manifold fan about vertex 2.
  TriangleMesh flat;
  flat.vertices = {{0, 0, 0}, {2, 0, 0}, {1, 0, 0}, {1, 1, 0}};
  flat.triangles = {{0, 1, 2}, {0, 2, 3}, {2, 1, 3}};
  c = checkMesh(flat);
  EXPECT_TRUE(c.manifold);
  EXPECT_EQ(c.boundaryEdges, 3u);
  EXPECT_TRUE(c.selfIntersecting);
}

}  // namespace
}  // namespace hyb
