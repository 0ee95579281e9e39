// The surface at a frame's level of detail: the full-resolution surface's vertices clustered by
// cubes of s voxels, out of core, with no holes where the full surface has none.
#include "hybrid_octree/coarse_surface.h"

#include <gtest/gtest.h>

#include <cmath>
#include <tuple>

#include <omp.h>

#include "test_util.h"

namespace hyb {
namespace {

// Whether the ray from @p o along @p d crosses a triangle of @p m (Möller–Trumbore, both sides).
bool hits(const TriangleMesh& m, const glm::dvec3& o, const glm::dvec3& d) {
  for (const glm::uvec3& t : m.triangles) {
    const glm::dvec3 a(m.vertices[t.x]), b(m.vertices[t.y]), c(m.vertices[t.z]);
    const glm::dvec3 e1 = b - a, e2 = c - a, p = glm::cross(d, e2);
    const double det = glm::dot(e1, p);
    if (std::abs(det) < 1e-15) continue;
    const glm::dvec3 s = o - a;
    const double u = glm::dot(s, p) / det;
    if (u < 0.0 || u > 1.0) continue;
    const glm::dvec3 q = glm::cross(s, e1);
    const double v = glm::dot(d, q) / det;
    if (v < 0.0 || u + v > 1.0) continue;
    if (glm::dot(e2, q) / det > 0.0) return true;
  }
  return false;
}

TEST(CoarseSurface, ASphereStaysClosedOnItsCubesAtEverySpacing) {
  const glm::ivec3 dims(90, 90, 90);
  const double radius = 30.0;
  const glm::dvec3 spacing(0.8, 0.8, 1.2);
  const glm::dvec3 c = glm::dvec3(dims - 1) * 0.5;
  const Volume v = test::makeVolume(dims, [&](int i, int j, int k) { return radius - glm::length(glm::dvec3(i, j, k) - c); }, spacing);
  const VolumeOctree t = VolumeOctree::build(v);
  const VolumeKnots knots(v, t);
  size_t previous = 0;
  for (const int s : {2, 4, 8}) {
    SCOPED_TRACE("cubes of " + std::to_string(s) + " voxels");
    const TriangleMesh m = clusteredSurface(knots, t, s, 0.0f);
    ASSERT_EQ(m.normals.size(), m.vertices.size());
    // On the sphere (in voxels) within the sagitta of a cube's diagonal; normals along the radius.
    const double tolerance = 0.1 + 3.0 * s * s / (8.0 * radius);
    for (size_t i = 0; i < m.vertices.size(); ++i) {
      const glm::dvec3 r = glm::dvec3(m.vertices[i]) / spacing - c;
      ASSERT_NEAR(glm::length(r), radius, tolerance);
      const glm::dvec3 radial = glm::normalize(r / spacing);  // the sphere's outward normal in mm
      ASSERT_GT(glm::dot(glm::dvec3(m.normals[i]), radial), 0.98);
    }
    // No hole: rays from the centre in 2,000 directions (a Fibonacci sphere) all cross it.
    int missed = 0;
    for (int q = 0; q < 2000; ++q) {
      const double z = 1.0 - (q + 0.5) / 1000.0, r = std::sqrt(1.0 - z * z), phi = q * 2.399963229728653;
      missed += !hits(m, c * spacing, glm::dvec3(r * std::cos(phi), r * std::sin(phi), z));
    }
    EXPECT_EQ(missed, 0);
    // About a quarter of the triangles at each doubling.
    if (previous > 0) {
      EXPECT_GT(double(m.triangles.size()), 0.15 * double(previous));
      EXPECT_LT(double(m.triangles.size()), 0.35 * double(previous));
    }
    previous = m.triangles.size();
  }
}

TEST(CoarseSurface, ASheetThinnerThanACubeKeepsNoHole) {
  // One voxel thick, off every cube's faces: Marching Cubes of the knots 4 or 8 voxels apart would
  // not see it at all.
  const glm::ivec3 dims(41, 66, 66);
  const Volume v = test::makeVolume(dims, [&](int i, int j, int k) { return i == 21 && j >= 5 && j <= 60 && k >= 5 && k <= 60 ? 100.0 : 0.0; });
  const VolumeOctree t = VolumeOctree::build(v);
  const VolumeKnots knots(v, t);
  for (const int s : {4, 8}) {
    SCOPED_TRACE("cubes of " + std::to_string(s) + " voxels");
    const TriangleMesh m = clusteredSurface(knots, t, s, 50.0f);
    int missed = 0;
    for (int z = 8; z <= 56; z += 3)
      for (int y = 8; y <= 56; y += 3) missed += !hits(m, glm::dvec3(0.0, y + 0.61, z + 0.37), glm::dvec3(1, 0, 0));
    EXPECT_EQ(missed, 0);
    // Both faces collapse onto the sheet, their normals adding up along it away from its rim.
    for (size_t i = 0; i < m.vertices.size(); ++i) {
      ASSERT_NEAR(m.vertices[i].x, 21.0, 0.5 + 1e-4);
      const glm::vec3 p = m.vertices[i];
      if (p.y > 8 && p.y < 57 && p.z > 8 && p.z < 57) {
        ASSERT_GT(std::abs(m.normals[i].x), 0.99f);
      }
    }
  }
}

// A spherical shell one voxel thick collapses onto itself in cubes of 4 and 8 voxels: every
// triangle's corners' normals agree in sign (opposed ones would shade dark across the triangle;
// half-way summed normals gave 1,766 such corner pairs here), along the shell's radius.
TEST(CoarseSurface, ACollapsedShellKeepsItsNormalsOnOneSide) {
  const glm::ivec3 dims(64, 64, 64);
  const glm::dvec3 c(31.3, 32.1, 30.7);
  const Volume v = test::makeVolume(dims, [&](int i, int j, int k) { return std::abs(glm::length(glm::dvec3(i, j, k) - c) - 24.0) < 0.6 ? 100.0 : 0.0; });
  const VolumeOctree t = VolumeOctree::build(v);
  const VolumeKnots knots(v, t);
  for (const int s : {4, 8}) {
    SCOPED_TRACE("cubes of " + std::to_string(s) + " voxels");
    const TriangleMesh m = clusteredSurface(knots, t, s, 50.0f);
    ASSERT_GT(m.triangles.size(), 500u);
    size_t opposed = 0;
    for (const glm::uvec3& tri : m.triangles)
      for (int e = 0; e < 3; ++e) opposed += glm::dot(m.normals[tri[e]], m.normals[tri[(e + 1) % 3]]) < 0.0f;
    EXPECT_EQ(opposed, 0u);
    double worst = 1.0, mean = 0.0;
    for (size_t i = 0; i < m.vertices.size(); ++i) {
      const double d = std::abs(glm::dot(glm::dvec3(m.normals[i]), glm::normalize(glm::dvec3(m.vertices[i]) - c)));
      worst = std::min(worst, d);
      mean += d / double(m.vertices.size());
    }
    EXPECT_GT(mean, 0.97);  // 0.983 and 0.991: the voxelised shell's staircase tilts the gradient
    EXPECT_GT(worst, 0.7);  // 0.75 and 0.92
  }
}

// A gyroid of period 12 voxels: creases and sheets at every cube size. Where orientNormals'
// fronts met, or two surfaces a cube apart were joined, a triangle's corners' normals were opposed
// and interpolated through zero inside it (a dark line or speck on a skull's clustered preview):
// 9,873 and 2,006 such triangles in cubes of 4 and 8 here. Every triangle's corners now agree
// pairwise or lie on one side of its plane.
TEST(CoarseSurface, NoTrianglesNormalsInterpolateThroughZero) {
  const glm::ivec3 dims(72, 72, 72);
  const double w = 2.0 * M_PI / 12.0;
  const Volume v = test::makeVolume(
      dims, [&](int i, int j, int k) { return std::sin(w * i) * std::cos(w * j) + std::sin(w * j) * std::cos(w * k) + std::sin(w * k) * std::cos(w * i); });
  const VolumeOctree t = VolumeOctree::build(v);
  const VolumeKnots knots(v, t);
  for (const int s : {2, 4, 8}) {
    SCOPED_TRACE("cubes of " + std::to_string(s) + " voxels");
    const TriangleMesh m = clusteredSurface(knots, t, s, 0.0f);
    ASSERT_GT(m.triangles.size(), 3000u);
    ASSERT_EQ(m.normals.size(), m.vertices.size());
    size_t opposed = 0;
    for (const glm::uvec3& tri : m.triangles) {
      const glm::vec3 a = m.normals[tri.x], b = m.normals[tri.y], c = m.normals[tri.z];
      const glm::vec3 face = glm::cross(m.vertices[tri.y] - m.vertices[tri.x], m.vertices[tri.z] - m.vertices[tri.x]);
      const bool agree = glm::dot(a, b) >= 0.0f && glm::dot(b, c) >= 0.0f && glm::dot(a, c) >= 0.0f;
      const bool oneSide = glm::dot(a, face) >= 0.0f && glm::dot(b, face) >= 0.0f && glm::dot(c, face) >= 0.0f;
      opposed += !agree && !oneSide;
    }
    EXPECT_EQ(opposed, 0u);
  }
}

TEST(CoarseSurface, BlocksThreadsAndSkippedBlocksChangeNothing) {
  const glm::dvec3 spacing(0.7, 0.8, 1.1);
  const glm::ivec3 dims(61, 47, 39);
  const glm::dvec3 c = glm::dvec3(dims - 1) * glm::dvec3(0.4, 0.5, 0.5);
  const Volume v = test::makeVolume(dims, [&](int i, int j, int k) { return 14.0 - glm::length((glm::dvec3(i, j, k) - c) * spacing) + (i == 55 ? 20.0 : 0.0); },
                                    spacing);
  const VolumeOctree t = VolumeOctree::build(v);
  const VolumeKnots knots(v, t);
  // An octree of the same grid whose ranges skip nothing: the same surface from every block.
  const Volume checker = test::makeVolume(dims, [](int i, int j, int k) { return (i + j + k) % 2 ? 1e6 : -1e6; }, spacing);
  const VolumeOctree all = VolumeOctree::build(checker);
  for (const int s : {2, 4}) {
    SCOPED_TRACE("cubes of " + std::to_string(s) + " voxels");
    const TriangleMesh m = clusteredSurface(knots, t, s, 0.0f);
    ASSERT_GT(m.triangles.size(), 200u);
    for (const auto& [octree, block, threads] : {std::tuple{&t, 5, 1}, std::tuple{&all, kClusterBlockCells, 2}, std::tuple{&all, 3, 2}}) {
      omp_set_num_threads(threads);
      const TriangleMesh o = clusteredSurface(knots, *octree, s, 0.0f, nullptr, block);
      EXPECT_EQ(o.triangles, m.triangles);
      ASSERT_EQ(o.vertices.size(), m.vertices.size());
      for (size_t i = 0; i < m.vertices.size(); ++i) {
        ASSERT_LT(glm::length(o.vertices[i] - m.vertices[i]), 1e-4f);
        ASSERT_GT(glm::dot(o.normals[i], m.normals[i]), 0.999f);
      }
    }
    omp_set_num_threads(2);
  }
}

// The knots' Marching Cubes: a linear field's surface exactly where it lies, in the last cell too
// (its knot on the last sample, nearer than s); a sphere's within half a knot spacing of its radius,
// its normals outward, at the prefiltered spacings as well.
TEST(CoarseSurface, TheKnotsSurfaceLiesWhereTheSamplesPutIt) {
  const glm::dvec3 spacing(0.8, 1.0, 1.25);
  const Volume ramp = test::makeVolume({40, 12, 10}, [](int i, int, int) { return float(i); }, spacing);
  const VolumeOctree rampTree = VolumeOctree::build(ramp);
  const TriangleMesh plane = knotSurface(VolumeKnots(ramp, rampTree), 2, 38.5f);  // knots 0, 2, ..., 38 and 39
  ASSERT_FALSE(plane.triangles.empty());
  for (const glm::vec3& p : plane.vertices) EXPECT_NEAR(p.x, 38.5 * spacing.x, 1e-4);
  const glm::ivec3 dims(61, 58, 53);
  const glm::dvec3 c = glm::dvec3(dims - 1) / 2.0;
  const Volume ball = test::makeVolume(dims, [&](int i, int j, int k) { return float(20.0 - glm::length((glm::dvec3(i, j, k) - c) * spacing)); }, spacing);
  const VolumeOctree tree = VolumeOctree::build(ball);
  for (const int s : {2, 4, 8}) {
    const TriangleMesh m = knotSurface(VolumeKnots(ball, tree), s, 0.0f);
    ASSERT_FALSE(m.triangles.empty()) << s;
    ASSERT_EQ(m.normals.size(), m.vertices.size()) << s;
    double worst = 0.0, leastOutward = 1.0;
    for (size_t v = 0; v < m.vertices.size(); ++v) {
      const glm::dvec3 out = glm::dvec3(m.vertices[v]) - c * spacing;
      worst = std::max(worst, std::abs(glm::length(out) - 20.0));
      leastOutward = std::min(leastOutward, glm::dot(glm::normalize(out), glm::dvec3(m.normals[v])));
    }
    EXPECT_LT(worst, 0.5 * s * spacing.z) << s;
    EXPECT_GT(leastOutward, 0.9) << s;
  }
}

TEST(CoarseSurface, SpacingIsTheCoarsestWhoseCubesFitThePixels) {
  const glm::dvec3 spacing(0.5, 0.4, 2.0);  // the longest axis decides: no cube wider than asked
  EXPECT_EQ(clusterSpacingFor(0.0, spacing, 16), 1);
  EXPECT_EQ(clusterSpacingFor(3.99, spacing, 16), 1);
  EXPECT_EQ(clusterSpacingFor(4.0, spacing, 16), 2);
  EXPECT_EQ(clusterSpacingFor(16.0, spacing, 16), 8);
  EXPECT_EQ(clusterSpacingFor(15.99, spacing, 16), 4);
  EXPECT_EQ(clusterSpacingFor(1000.0, spacing, 16), 16);
  EXPECT_EQ(clusterSpacingFor(1000.0, spacing, 1), 1);
}

}  // namespace
}  // namespace hyb
