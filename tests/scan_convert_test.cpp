// Filtered 3D scan-conversion against closed forms: the box fraction of a half-space by
// inclusion–exclusion, a ball by fine quadrature, a polyhedron's volume by the divergence theorem;
// a rotating sheet filtered and point-sampled; malformed meshes; the NRRD export's grid.
#include "surface/closest_point.h"
#include "surface/scan_convert.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <numbers>
#include <random>

#include <glm/gtc/matrix_transform.hpp>

#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;

// Coverage fractions of a result, x fastest.
std::vector<double> fractions(const ScanResult& r) {
  const double scale = r.coverage.storedType() == ScalarType::UInt8 ? 1.0 / 255.0 : 1.0;
  std::vector<double> out(r.coverage.voxelCount());
  for (size_t n = 0; n < out.size(); ++n) out[n] = r.coverage.value(n) * scale;
  return out;
}
double total(const ScanResult& r) {
  double s = 0.0;
  for (const double v : fractions(r)) s += v;
  return s;
}

// The fraction of [−½, ½]³ where m·u ≤ t by the textbook inclusion–exclusion over the cube's
// corners (well conditioned when no |m_i| is small): independent of boxHalfSpaceFraction's pieces.
double inclusionExclusion(const glm::dvec3& m, double t) {
  const glm::dvec3 a = glm::abs(m);
  const double shifted = t + 0.5 * (a.x + a.y + a.z);
  double sum = 0.0;
  for (int c = 0; c < 8; ++c) {
    const glm::dvec3 v(c & 1, (c >> 1) & 1, (c >> 2) & 1);
    const double r = std::max(0.0, shifted - glm::dot(a, v));
    sum += ((c == 0 || c == 3 || c == 5 || c == 6) ? 1.0 : -1.0) * r * r * r;
  }
  return std::clamp(sum / (6.0 * a.x * a.y * a.z), 0.0, 1.0);
}

// A rotated, mirrored frame with an origin away from 0.
PatientFrame obliqueFrame() {
  const glm::dmat3 r(glm::rotate(glm::dmat4(1.0), 0.6, glm::normalize(glm::dvec3(1, -2, 0.5))));
  glm::dmat3 d = r;
  d[2] = -d[2];
  return makePatientFrame(d, glm::dvec3(-40.0, 12.5, 300.0), "test frame");
}

// The fraction of the cell of @p cell (grid mm, sides @p sides) inside the ball: a 64 × 64 midpoint
// rule over x and y of the ball's exact chord along z within the cell.
double ballFraction(const glm::dvec3& cell, const glm::dvec3& sides, const glm::dvec3& centre, double radius) {
  constexpr int kN = 64;
  double sum = 0.0;
  for (int a = 0; a < kN; ++a)
    for (int b = 0; b < kN; ++b) {
      const double x = cell.x + sides.x * ((a + 0.5) / kN - 0.5), y = cell.y + sides.y * ((b + 0.5) / kN - 0.5);
      const double h2 = radius * radius - (x - centre.x) * (x - centre.x) - (y - centre.y) * (y - centre.y);
      if (h2 <= 0.0) continue;
      const double h = std::sqrt(h2);
      const double lo = std::max(centre.z - h, cell.z - 0.5 * sides.z), hi = std::min(centre.z + h, cell.z + 0.5 * sides.z);
      sum += std::max(0.0, hi - lo) / sides.z;
    }
  return sum / (kN * kN);
}

TEST(ScanConvert, BoxFractionMatchesInclusionExclusionAndLowerDimensions) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int checked = 0;
  for (int n = 0; n < 20000; ++n) {
    const glm::dvec3 m(u(rng), u(rng), u(rng));
    if (std::min({std::abs(m.x), std::abs(m.y), std::abs(m.z)}) < 0.05) continue;  // where the textbook form is well conditioned
    const double t = 1.2 * u(rng);
    ASSERT_NEAR(boxHalfSpaceFraction(m, t), inclusionExclusion(m, t), 1e-10) << m.x << " " << m.y << " " << m.z << " t " << t;
    EXPECT_NEAR(boxHalfSpaceFraction(m, t) + boxHalfSpaceFraction(m, -t), 1.0, 1e-12);
    ++checked;
  }
  EXPECT_GT(checked, 15000);
  // On an axis the fraction is linear; on a face diagonal it is the square's corner triangle.
  for (const double t : {-0.7, -0.5, -0.2, 0.0, 0.3, 0.5, 0.9}) {
    EXPECT_NEAR(boxHalfSpaceFraction({0, 0, -2.0}, 2.0 * t), std::clamp(t + 0.5, 0.0, 1.0), 1e-15);
    const double s = t + 1.0;  // (u + v) ≤ s on the unit square
    const double square = s <= 0 ? 0 : s <= 1 ? 0.5 * s * s : s <= 2 ? 1 - 0.5 * (2 - s) * (2 - s) : 1;
    EXPECT_NEAR(boxHalfSpaceFraction({1, 1, 0}, t), square, 1e-15);
    // Normals a hair off an axis or a diagonal: continuous, no cancellation.
    EXPECT_NEAR(boxHalfSpaceFraction({1, 1e-9, 1e-13}, t), std::clamp(t + 0.5, 0.0, 1.0), 1e-8);
    EXPECT_NEAR(boxHalfSpaceFraction({1, 1, 1e-12}, t), square, 1e-10);
  }
}

TEST(ScanConvert, HalfSpaceIsTheExactCellFractionInAnObliqueFrame) {
  const VoxelGrid grid{{16, 14, 12}, {1.0, 1.5, 0.75}, obliqueFrame()};
  const glm::dvec3 q = grid.frame.toPatient(glm::dvec3(7.3, 9.1, 4.4)), n(0.3, -0.5, 0.8);  // patient space
  ScanOptions o;
  o.type = CoverageType::Float32;
  const ScanResult r = scanConvertHalfSpace(q, n, grid, o);
  const std::vector<double> v = fractions(r);
  const glm::dvec3 qg = grid.frame.toGrid(q), ng = glm::normalize(grid.frame.vectorToGrid(n));
  double worst = 0.0;
  size_t partial = 0;
  for (int k = 0; k < 12; ++k)
    for (int j = 0; j < 14; ++j)
      for (int i = 0; i < 16; ++i) {
        const glm::dvec3 p = glm::dvec3(i, j, k) * grid.spacing;
        const double exact = inclusionExclusion(ng * grid.spacing, -glm::dot(ng, p - qg));
        worst = std::max(worst, std::abs(v[r.coverage.index(i, j, k)] - exact));
        partial += exact > 0.0 && exact < 1.0;
      }
  EXPECT_LT(worst, 1e-6);  // float storage
  EXPECT_GT(partial, 200u);
  EXPECT_EQ(r.bandVoxels + r.insideVoxels, size_t(std::count_if(v.begin(), v.end(), [](double x) { return x > 0.0; })));
}

TEST(ScanConvert, SphereMatchesFineQuadratureOfTheBall) {
  const VoxelGrid grid{{24, 24, 24}, {1.0, 1.0, 1.0}, {}};
  const glm::dvec3 c(11.3, 12.1, 11.7);
  for (const double radius : {4.0, 7.5}) {
    ScanOptions o;
    o.space = ScanSpace::Grid;
    o.type = CoverageType::Float32;
    const ScanResult r = scanConvertSphere(c, radius, grid, o);
    const std::vector<double> v = fractions(r);
    double worst = 0.0, sum = 0.0;
    for (int k = 0; k < 24; ++k)
      for (int j = 0; j < 24; ++j)
        for (int i = 0; i < 24; ++i) {
          const double got = v[r.coverage.index(i, j, k)];
          sum += got;
          if (std::abs(glm::length(glm::dvec3(i, j, k) - c) - radius) < 1.0)
            worst = std::max(worst, std::abs(got - ballFraction(glm::dvec3(i, j, k), glm::dvec3(1.0), c, radius)));
        }
    // The curvature-corrected tangent plane: measured 0.0118 (R = 4) and 0.0068 (R = 7.5).
    EXPECT_LT(worst, radius < 5 ? 0.015 : 0.008) << "radius " << radius;
    EXPECT_NEAR(sum, 4.0 / 3.0 * std::numbers::pi * radius * radius * radius, 0.002 * sum) << "radius " << radius;
  }
}

TEST(ScanConvert, MeshSphereVolumeMatchesThePolyhedron) {
  const VoxelGrid grid{{48, 48, 48}, {1.0, 1.0, 1.0}, {}};
  const glm::dvec3 c(23.4, 23.7, 24.1);
  const double radius = 20.0;
  const TriangleMesh mesh = geodesicSphere(c, radius, 24);
  ASSERT_EQ(mesh.triangles.size(), 20u * 24u * 24u);
  const double polyhedron = enclosedVolume(mesh), ball = 4.0 / 3.0 * std::numbers::pi * radius * radius * radius;
  EXPECT_GT(polyhedron, 0.0);                     // wound outward
  EXPECT_NEAR(polyhedron, ball, 0.01 * ball);     // inscribed: a little smaller
  ScanOptions o;
  o.space = ScanSpace::Grid;
  o.type = CoverageType::Float32;
  const ScanResult r = scanConvertMesh(mesh, grid, o);
  EXPECT_TRUE(r.warnings.empty()) << r.warnings.front();
  EXPECT_NEAR(total(r), polyhedron, 0.001 * polyhedron);
  // Against the analytic ball: the polyhedron lies within its sagitta (≈ 0.005 voxels) of the sphere.
  const ScanResult analytic = scanConvertSphere(c, radius, grid, o);
  const std::vector<double> a = fractions(analytic), m = fractions(r);
  double worst = 0.0;
  for (size_t n = 0; n < a.size(); ++n) worst = std::max(worst, std::abs(a[n] - m[n]));
  EXPECT_LT(worst, 0.03);

  // Point sampling: exactly the voxel centres inside, away from the thin shell between polyhedron and sphere.
  o.filter = ScanFilter::None;
  const std::vector<double> point = fractions(scanConvertMesh(mesh, grid, o));
  size_t wrong = 0, shell = 0;
  for (int k = 0; k < 48; ++k)
    for (int j = 0; j < 48; ++j)
      for (int i = 0; i < 48; ++i) {
        const double rho = glm::length(glm::dvec3(i, j, k) - c);
        if (std::abs(rho - radius) < 0.01) {
          ++shell;
          continue;
        }
        wrong += point[size_t(i) + 48 * (size_t(j) + 48 * size_t(k))] != (rho < radius ? 1.0 : 0.0);
      }
  EXPECT_EQ(wrong, 0u);
  EXPECT_LT(shell, 150u);  // 4πR² · 0.02 ≈ 100 voxels in the shell left out
}

TEST(ScanConvert, MeshInPatientSpaceOnAnAnisotropicGrid) {
  const VoxelGrid grid{{40, 32, 26}, {0.8, 1.0, 1.3}, obliqueFrame()};
  const glm::dvec3 centre = grid.frame.toPatient(glm::dvec3(16.1, 15.8, 16.6));
  const TriangleMesh mesh = geodesicSphere(centre, 12.0, 20);
  const double polyhedron = std::abs(enclosedVolume(mesh));  // mm³
  ScanOptions o;  // patient space, box of one cell, uint8
  const ScanResult r = scanConvertMesh(mesh, grid, o);
  EXPECT_TRUE(r.warnings.empty());
  const double cell = grid.spacing.x * grid.spacing.y * grid.spacing.z;
  EXPECT_NEAR(total(r) * cell, polyhedron, 0.005 * polyhedron);
  EXPECT_EQ(r.coverage.frame(), grid.frame);
}

// Rotates a sheet about an axis in it by 1° at a time; returns the largest change of a voxel within
// 7 mm of the axis' centre between steps.
template <class Convert>
double largestStep(const VoxelGrid& grid, const glm::dvec3& centre, const Convert& convert) {
  const glm::dvec3 axis = glm::normalize(glm::dvec3(1, 2, 3));
  const glm::dvec3 n0 = glm::normalize(glm::cross(axis, glm::dvec3(1, 0, 0)));
  std::vector<double> previous;
  double worst = 0.0;
  for (int step = 0; step <= 30; ++step) {
    const glm::dvec3 n = glm::dmat3(glm::rotate(glm::dmat4(1.0), glm::radians(double(step)), axis)) * n0;
    const std::vector<double> v = fractions(convert(n, glm::cross(axis, n)));
    if (!previous.empty())
      for (int k = 0; k < grid.dims.z; ++k)
        for (int j = 0; j < grid.dims.y; ++j)
          for (int i = 0; i < grid.dims.x; ++i) {
            if (glm::length(glm::dvec3(i, j, k) - centre) > 7.0) continue;
            const size_t at = size_t(i) + size_t(grid.dims.x) * (size_t(j) + size_t(grid.dims.y) * size_t(k));
            worst = std::max(worst, std::abs(v[at] - previous[at]));
          }
    previous = v;
  }
  return worst;
}

TEST(ScanConvert, RotatingSheetChangesBoundedWhenFilteredAndFlipsWhenPointSampled) {
  const VoxelGrid grid{{32, 32, 32}, {1.0, 1.0, 1.0}, {}};
  const glm::dvec3 c(15.6, 15.3, 15.8);
  // A voxel at distance r from the axis sees the sheet's two faces sweep by at most (r + √3/2)·δ
  // across its cell, whose sections are at most √2: |Δ| ≤ 2√2 (7 + √3/2) · π/180 ≈ 0.39.
  const double bound = 2.0 * std::sqrt(2.0) * (7.0 + std::sqrt(3.0) / 2.0) * std::numbers::pi / 180.0;
  for (const ScanFilter filter : {ScanFilter::Box, ScanFilter::None}) {
    ScanOptions o;
    o.space = ScanSpace::Grid;
    o.filter = filter;
    o.thickness = 1.0;
    o.type = CoverageType::Float32;
    const double plane = largestStep(grid, c, [&](const glm::dvec3& n, const glm::dvec3&) { return scanConvertPlane(c, n, grid, o); });
    // The same sheet as a 24 mm square polygon (a mesh): its rim is beyond the voxels compared.
    const double polygon = largestStep(grid, c, [&](const glm::dvec3& n, const glm::dvec3& inPlane) {
      const glm::dvec3 e1 = glm::normalize(inPlane) * 12.0, e2 = glm::normalize(glm::cross(n, inPlane)) * 12.0;
      const std::vector<glm::dvec3> corners = {c - e1 - e2, c + e1 - e2, c + e1 + e2, c - e1 + e2};
      return scanConvertPolygon(corners, grid, o);
    });
    if (filter == ScanFilter::Box) {
      EXPECT_LT(plane, bound);
      EXPECT_LT(polygon, bound);
      EXPECT_LT(plane, 0.2);  // the bound is loose
    } else {
      EXPECT_EQ(plane, 1.0);  // a voxel jumps from empty to full: aliasing
      EXPECT_EQ(polygon, 1.0);
    }
  }
}

TEST(ScanConvert, MalformedInputIsRefusedWithOneMessage) {
  const VoxelGrid grid{{8, 8, 8}, {1.0, 1.0, 1.0}, {}};
  auto message = [&](const TriangleMesh& mesh, const ScanOptions& o = {}) {
    try {
      scanConvertMesh(mesh, grid, o);
    } catch (const ValueError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  TriangleMesh mesh = geodesicSphere(glm::dvec3(4.0), 3.0, 2);
  EXPECT_THAT(message(TriangleMesh{}), HasSubstr("mesh: no triangles"));
  TriangleMesh nan = mesh;
  nan.vertices[5].y = std::nanf("");
  EXPECT_THAT(message(nan), HasSubstr("mesh: vertex 5 is not finite"));
  TriangleMesh out = mesh;
  out.triangles[3].z = 9999;
  EXPECT_THAT(message(out), HasSubstr("mesh: triangle 3 refers to vertex 9999 but the mesh has"));
  ScanOptions o;
  o.width = 0.0;
  EXPECT_THAT(message(mesh, o), HasSubstr("width 0 must be a positive number of voxels"));
  o = {};
  o.thickness = -1.0;
  EXPECT_THAT(message(mesh, o), HasSubstr("thickness -1"));
  o = {};
  EXPECT_THROW(scanConvertPlane(glm::dvec3(1.0), glm::dvec3(0, 0, 1), grid, o), ValueError);  // no thickness
  o.thickness = 1.0;
  EXPECT_THROW(scanConvertPlane(glm::dvec3(1.0), glm::dvec3(0.0), grid, o), ValueError);
  EXPECT_THROW(scanConvertSphere(glm::dvec3(1.0), -2.0, grid, o), ValueError);
  const std::vector<glm::dvec3> two = {{0, 0, 0}, {1, 0, 0}};
  EXPECT_THROW(scanConvertPolygon(two, grid, o), ValueError);
  const std::vector<glm::dvec3> bent = {{0, 0, 0}, {4, 0, 0}, {4, 4, 1}, {0, 4, 0}};
  EXPECT_THROW(scanConvertPolygon(bent, grid, o), ValueError);
  const std::vector<glm::dvec3> concave = {{0, 0, 0}, {4, 0, 0}, {4, 4, 0}, {3, 1, 0}};  // the fan from corner 0 folds
  EXPECT_THROW(scanConvertPolygon(concave, grid, o), ValueError);
}

TEST(ScanConvert, TinyOutsideAndOpenMeshesAreReportedNotFatal) {
  const VoxelGrid grid{{32, 32, 32}, {0.5, 0.5, 0.5}, {}};
  ScanOptions o;
  o.space = ScanSpace::Grid;
  // A sphere of 10 mm radius given in metres: 1000× too small.
  const ScanResult tiny = scanConvertMesh(geodesicSphere(glm::dvec3(8.0), 0.01, 4), grid, o);
  ASSERT_EQ(tiny.warnings.size(), 1u);
  EXPECT_THAT(tiny.warnings[0], HasSubstr("smaller than one voxel"));
  EXPECT_LT(total(tiny), 8.0);  // not resolved: at most the few voxels within the box's reach of it
  const ScanResult far = scanConvertMesh(geodesicSphere(glm::dvec3(1000.0), 5.0, 4), grid, o);
  ASSERT_EQ(far.warnings.size(), 1u);
  EXPECT_THAT(far.warnings[0], HasSubstr("wholly outside the grid"));
  EXPECT_EQ(far.coverage.maxValue(), 0.0f);
  // A sphere with a hole, as a solid: rows through the hole cross it once.
  TriangleMesh open = geodesicSphere(glm::dvec3(8.0), 5.0, 8);
  open.triangles.resize(open.triangles.size() - 64);
  const ScanResult holed = scanConvertMesh(open, grid, o);
  ASSERT_EQ(holed.warnings.size(), 1u);
  EXPECT_THAT(holed.warnings[0], HasSubstr("mesh is not closed"));
  // The same mesh as a sheet needs no closure.
  o.thickness = 0.5;
  EXPECT_TRUE(scanConvertMesh(open, grid, o).warnings.empty());
}

TEST(ScanConvert, SheetOfAClosedMeshHasItsAreaTimesThickness) {
  const VoxelGrid grid{{40, 40, 40}, {1.0, 1.0, 1.0}, {}};
  const double radius = 14.0, thickness = 1.0;
  ScanOptions o;
  o.space = ScanSpace::Grid;
  o.thickness = thickness;
  o.type = CoverageType::Float32;
  // A shell between radius ∓ τ/2: 4π/3 ((R + τ/2)³ − (R − τ/2)³).
  const double shell = 4.0 / 3.0 * std::numbers::pi * (std::pow(radius + 0.5 * thickness, 3) - std::pow(radius - 0.5 * thickness, 3));
  EXPECT_NEAR(total(scanConvertMesh(geodesicSphere(glm::dvec3(19.6), radius, 32), grid, o)), shell, 0.01 * shell);
}

TEST(ScanConvert, BandNormalsAreTheClosestTrianglesFollowingTheWinding) {
  // A geodesic sphere (R = 12 mm, 20 480 triangles of about 2° each) in patient space, a 1 mm sheet
  // on a 0.8 × 1 × 1.3 mm grid in a rotated, mirrored frame.
  const VoxelGrid grid{{40, 40, 40}, {0.8, 1.0, 1.3}, obliqueFrame()};
  const glm::dvec3 centre(16.1, 19.7, 25.9);  // grid mm
  TriangleMesh mesh = geodesicSphere(grid.frame.toPatient(centre), 12.0, 32);
  ScanOptions o;
  o.thickness = 1.0;
  EXPECT_TRUE(scanConvertMesh(mesh, grid, o).normals.empty());  // only when asked
  o.normals = true;
  const ScanResult r = scanConvertMesh(mesh, grid, o);
  ASSERT_EQ(r.normals.size(), r.bandVoxels);  // one per band voxel
  // Each the unit normal of a facet near the voxel: within 3° of its radial direction (grid frame),
  // outward as the mesh is wound in patient space, so inward in the grid frame this frame mirrors.
  const double cos3 = std::cos(3.0 * std::numbers::pi / 180.0), mirror = glm::determinant(grid.frame.direction) < 0.0 ? -1.0 : 1.0;
  double worst = 1.0;
  std::vector<std::pair<uint64_t, glm::vec3>> forward;
  for (const VoxelNormal& v : r.normals) {
    const size_t i = v.voxel % 40, j = (v.voxel / 40) % 40, k = v.voxel / 1600;
    const glm::dvec3 radial = mirror * glm::normalize(glm::dvec3(i, j, k) * grid.spacing - centre);
    EXPECT_NEAR(glm::length(v.normal), 1.0f, 1e-5f);
    worst = std::min(worst, glm::dot(glm::dvec3(v.normal), radial));
    forward.emplace_back(v.voxel, v.normal);
  }
  std::printf("band normals: %zu, the worst %.3f° off the radial direction\n", r.normals.size(), std::acos(std::min(worst, 1.0)) * 180.0 / std::numbers::pi);
  EXPECT_GT(worst, cos3);
  // Wound the other way: the same voxels, each normal turned over (a tie between neighbours may pick the other).
  for (glm::uvec3& t : mesh.triangles) std::swap(t.y, t.z);
  const ScanResult turned = scanConvertMesh(mesh, grid, o);
  ASSERT_EQ(turned.normals.size(), forward.size());
  std::vector<std::pair<uint64_t, glm::vec3>> back;
  for (const VoxelNormal& v : turned.normals) back.emplace_back(v.voxel, v.normal);
  auto byVoxel = [](const auto& a, const auto& b) { return a.first < b.first; };
  std::sort(forward.begin(), forward.end(), byVoxel);
  std::sort(back.begin(), back.end(), byVoxel);
  for (size_t n = 0; n < back.size(); ++n) {
    ASSERT_EQ(back[n].first, forward[n].first);
    EXPECT_LT(glm::dot(back[n].second, forward[n].second), -cos3);
  }
}

// Checks the sheet @p o makes of @p mesh (grid mm) against every voxel's distance to every
// triangle (closestOnTriangle in double, not the converter's branch-free float search): the band
// holds exactly the voxels within the reach (but those within 10⁻⁴ mm of it), each once, with the closest triangle's normal and, where no other
// triangle is within 10⁻⁴ mm as close, the box fraction of the tangent plane at the closest point;
// the others are 0. Adds to @p compared and raises @p worst (the largest coverage difference).
void expectBruteForceBand(const TriangleMesh& mesh, const VoxelGrid& grid, const ScanOptions& o, size_t* compared, double* worst) {
  const ScanResult r = scanConvertMesh(mesh, grid, o);
  const double half = 0.5 * o.thickness, reach = 0.5 * glm::length(grid.spacing) + half;
  std::map<uint64_t, glm::vec3> normals;
  for (const VoxelNormal& v : r.normals) normals[v.voxel] = v.normal;
  ASSERT_EQ(normals.size(), r.normals.size());  // each voxel once
  // Every voxel against every triangle: the closest and the second closest distance.
  size_t band = 0;
  for (int k = 0; k < grid.dims.z; ++k)
    for (int j = 0; j < grid.dims.y; ++j)
      for (int i = 0; i < grid.dims.x; ++i) {
        const uint64_t voxel = uint64_t(i) + uint64_t(grid.dims.x) * (uint64_t(j) + uint64_t(grid.dims.y) * uint64_t(k));
        const glm::dvec3 p = glm::dvec3(i, j, k) * grid.spacing;
        double best = 1e30, second = 1e30;
        glm::dvec3 closest(0.0), normal(0.0);
        for (const glm::uvec3& t : mesh.triangles) {
          const glm::dvec3 a(mesh.vertices[t.x]), b(mesh.vertices[t.y]), c(mesh.vertices[t.z]);
          const glm::dvec3 q = closestOnTriangle(p, a, b, c);
          const double dist = glm::length(p - q);
          if (dist < best) {
            second = best;
            best = dist;
            closest = q;
            normal = glm::normalize(glm::cross(b - a, c - a));
          } else {
            second = std::min(second, dist);
          }
        }
        const auto found = normals.find(voxel);
        if (std::abs(best - reach) < 1e-4) continue;  // at the reach: either way
        ASSERT_EQ(found != normals.end(), best < reach) << "voxel " << i << ", " << j << ", " << k << " at " << best << " mm (reach " << reach << ")";
        if (best >= reach) {
          ASSERT_EQ(r.coverage.value(voxel), 0.0f);
          continue;
        }
        ++band;
        if (second - best < 1e-4) continue;  // two triangles as close: either may be kept
        ++*compared;
        // The box fraction between the planes ±τ/2 from the closest point, across the direction to it.
        const glm::dvec3 dir = best > 1e-6 ? (p - closest) / best : normal;
        const glm::dvec3 m = glm::abs(dir) * grid.spacing;
        const double expected = boxHalfSpaceFraction(m, half - best) - boxHalfSpaceFraction(m, -half - best);
        *worst = std::max(*worst, std::abs(r.coverage.value(voxel) - expected));
        // The kept triangle is the closest: its normal, from its corners in float.
        EXPECT_NEAR(glm::dot(glm::dvec3(found->second), normal), 1.0, 1e-5) << "voxel " << i << ", " << j << ", " << k << " at " << best << " mm";
      }
  EXPECT_EQ(r.normals.size(), r.bandVoxels);
  EXPECT_GE(r.bandVoxels, band);  // (and those at the reach)
}

TEST(ScanConvert, SheetBandMatchesABruteForceSearchOverAwkwardTriangles) {
  // Triangles the band's row search must not cut short: small and large, slivers and needles, an
  // edge along each axis, normals along each axis and on the diagonals, some crossing the grid's
  // faces; a 1.1 mm sheet on a 0.8 × 1 × 1.3 mm grid, triangles in grid mm.
  const VoxelGrid grid{{22, 18, 14}, {0.8, 1.0, 1.3}, {}};
  const glm::dvec3 extent = glm::dvec3(grid.dims - 1) * grid.spacing;
  TriangleMesh mesh;
  auto add = [&](const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c) {
    const uint32_t v = uint32_t(mesh.vertices.size());
    for (const glm::dvec3& p : {a, b, c}) mesh.vertices.emplace_back(p);
    mesh.triangles.emplace_back(v, v + 1, v + 2);
  };
  std::mt19937 rng(54);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  auto point = [&] { return glm::dvec3(unit(rng), unit(rng), unit(rng)) * (extent + 4.0) - 2.0; };
  for (int n = 0; n < 60; ++n) {  // anywhere, any size (up to the grid's)
    const glm::dvec3 a = point();
    add(a, a + (point() - a) * unit(rng), a + (point() - a) * unit(rng));
  }
  for (int n = 0; n < 20; ++n) {  // slivers: the third corner within 10⁻³ mm of the first edge
    const glm::dvec3 a = point(), b = point(), off = glm::dvec3(unit(rng), unit(rng), unit(rng)) * 1e-3;
    add(a, b, a + (b - a) * unit(rng) + off);
  }
  for (int n = 0; n < 20; ++n) {  // needles: one edge under 0.05 mm
    const glm::dvec3 a = point();
    add(a, a + glm::dvec3(unit(rng), unit(rng), unit(rng)) * 0.05, point());
  }
  for (int axis = 0; axis < 3; ++axis)
    for (int n = 0; n < 6; ++n) {  // an edge along the axis, and a triangle facing along it
      glm::dvec3 a = point(), b = a, c = point();
      b[axis] += 3.0 + 4.0 * unit(rng);
      add(a, b, c);
      c = a;
      c[(axis + 1) % 3] += 2.0 + 3.0 * unit(rng);
      b[(axis + 2) % 3] = a[(axis + 2) % 3] + 0.5 + 2.0 * unit(rng);
      b[axis] = a[axis];
      b[(axis + 1) % 3] = a[(axis + 1) % 3];
      add(a, b, c);
    }
  for (int n = 0; n < 8; ++n) {  // normals on the diagonals: (1, ±1, ±1)
    const glm::dvec3 a = point(), d = glm::dvec3(1.0, n & 1 ? 1.0 : -1.0, n & 2 ? 1.0 : -1.0);
    const glm::dvec3 e1 = glm::normalize(glm::cross(d, glm::dvec3(0.0, 0.0, 1.0))), e2 = glm::normalize(glm::cross(d, e1));
    add(a, a + e1 * (1.0 + 5.0 * unit(rng)), a + e2 * (1.0 + 5.0 * unit(rng)));
  }
  ScanOptions o;
  o.space = ScanSpace::Grid;
  o.thickness = 1.1;
  o.type = CoverageType::Float32;
  o.normals = true;
  size_t compared = 0;
  double worst = 0.0;
  expectBruteForceBand(mesh, grid, o, &compared, &worst);
  EXPECT_GT(compared, size_t(4000));
  // Each triangle alone, so that none hides a row another's search would have missed.
  size_t alone = 0;
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    SCOPED_TRACE(::testing::Message() << "triangle " << t << " alone");
    TriangleMesh one;
    for (int c = 0; c < 3; ++c) one.vertices.push_back(mesh.vertices[mesh.triangles[t][c]]);
    one.triangles.emplace_back(0u, 1u, 2u);
    expectBruteForceBand(one, grid, o, &alone, &worst);
  }
  EXPECT_GT(alone, size_t(10000));
  // A sheet thicker than a batch of candidates is long: a square across a 6 × 5 × 300 grid, 280 mm thick.
  const VoxelGrid tall{{6, 5, 300}, {1.0, 1.0, 1.0}, {}};
  TriangleMesh square;
  for (const glm::vec3& p : {glm::vec3(-1, -1, 150.3f), glm::vec3(7, -1, 150.3f), glm::vec3(7, 6, 150.3f), glm::vec3(-1, 6, 150.3f)}) square.vertices.push_back(p);
  square.triangles = {{0, 1, 2}, {0, 2, 3}};
  ScanOptions thick = o;
  thick.thickness = 280.0;
  size_t across = 0;
  expectBruteForceBand(square, tall, thick, &across, &worst);
  EXPECT_GT(across, size_t(8000));  // of about 8 400 (those as near both triangles left out)
  // The converter's closest points are in float (about 10⁻⁶ mm here), so the direction to one very
  // near the voxel turns by up to 10⁻⁶ mm over its distance.
  EXPECT_LT(worst, 1e-3);
  std::printf("voxels compared: %zu with the whole mesh, %zu with each triangle alone, %zu across the thick sheet; the worst coverage %.2g off\n",
              compared, alone, across, worst);
}

TEST(ScanConvert, CoverageNrrdReadsBackOnTheSameGrid) {
  const test::TempDir dir;
  const VoxelGrid grid{{20, 18, 16}, {0.8, 1.0, 1.3}, obliqueFrame()};
  for (const CoverageType type : {CoverageType::UInt8, CoverageType::Float32}) {
    ScanOptions o;
    o.type = type;
    const ScanResult r = scanConvertSphere(grid.frame.toPatient(glm::dvec3(8.0, 9.0, 10.0)), 6.0, grid, o);
    const std::string path = dir.file(type == CoverageType::UInt8 ? "u8.nrrd" : "f32.nrrd");
    writeNrrd(r.coverage, path);
    const Volume back = readNrrd(path);
    EXPECT_EQ(back.dims(), grid.dims);
    EXPECT_EQ(back.storedType(), r.coverage.storedType());
    for (int a = 0; a < 3; ++a) {
      EXPECT_NEAR(back.spacing()[a], grid.spacing[a], 1e-12);
      EXPECT_NEAR(back.frame().origin[a], grid.frame.origin[a], 1e-12);
      for (int b = 0; b < 3; ++b) EXPECT_NEAR(back.frame().direction[a][b], grid.frame.direction[a][b], 1e-12);
    }
    EXPECT_FALSE(back.frame().assumed);
    EXPECT_EQ(test::floatSamples(back), test::floatSamples(r.coverage));
    EXPECT_GT(back.maxValue(), 0.0f);
  }
  EXPECT_THROW(writeNrrd(Volume({2, 2, 2}, glm::dvec3(1.0), ScalarType::UInt8, std::vector<float>(8, 0.0f)), dir.file("no/such/dir.nrrd")), IoError);
}

}  // namespace
}  // namespace hyb

namespace hyb {
namespace {

// The UV sphere's counts are exact and it closes outward: its enclosed volume approaches the ball's
// from below (an inscribed polyhedron) within 1 % at 24 rings.
TEST(ScanConvert, AUvSphereHasItsCountsAndEnclosesTheBall) {
  const TriangleMesh m = uvSphere(glm::dvec3(1.0, 2.0, 3.0), 5.0, 24);
  EXPECT_EQ(m.vertices.size(), size_t(25 * 48));
  EXPECT_EQ(m.triangles.size(), size_t(4 * 24 * 24 - 4 * 24));
  const double ball = 4.0 / 3.0 * std::numbers::pi * 125.0;
  EXPECT_LT(enclosedVolume(m), ball);
  EXPECT_GT(enclosedVolume(m), 0.99 * ball);
}

}  // namespace
}  // namespace hyb
