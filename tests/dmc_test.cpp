#include "surface/dmc.h"

#include <gtest/gtest.h>

#include <map>
#include <numbers>
#include <set>

#include "hybrid_octree/volume_octree.h"
#include "surface/cgal_geometry.h"
#include "surface/dmc_table.h"
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
