#include "surface/mesh_simplify.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <tuple>

#include "hybrid_octree/surface_octree.h"
#include "surface/cgal_geometry.h"
#include "surface/dmc.h"
#include "surface/mesh_ops.h"
#include "test_util.h"

namespace hyb {
namespace {

// Every triangle of @p m lies inside the block (edge @p block) holding its centroid.
void expectInsideBlocks(const TriangleMesh& m, const glm::dvec3& block) {
  constexpr double kSlack = 1e-4;  // mm: float positions on a block's face
  for (const glm::uvec3& t : m.triangles) {
    const glm::dvec3 a(m.vertices[t.x]), b(m.vertices[t.y]), c(m.vertices[t.z]);
    const glm::dvec3 lo = glm::floor((a + b + c) / 3.0 / block) * block, hi = lo + block;
    for (const glm::dvec3& p : {a, b, c})
      ASSERT_TRUE(glm::all(glm::greaterThanEqual(p, lo - kSlack)) && glm::all(glm::lessThanEqual(p, hi + kSlack)))
          << "a vertex at " << p.x << "," << p.y << "," << p.z << " outside its triangle's block";
  }
}

// How many triangles of @p m are flat (flatTriangle): drawn, llvmpipe makes NaN colours of them.
size_t flatTriangles(const TriangleMesh& m) {
  size_t flat = 0;
  for (const glm::uvec3& t : m.triangles) flat += flatTriangle(glm::dvec3(m.vertices[t.x]), glm::dvec3(m.vertices[t.y]), glm::dvec3(m.vertices[t.z]));
  return flat;
}

// The enclosed volume of a closed mesh (divergence theorem), whatever its self-intersections.
double enclosedVolume(const TriangleMesh& m) {
  double v = 0.0;
  for (const glm::uvec3& t : m.triangles) v += glm::dot(glm::dvec3(m.vertices[t.x]), glm::cross(glm::dvec3(m.vertices[t.y]), glm::dvec3(m.vertices[t.z]))) / 6.0;
  return v;
}

// The Surface Octree's mesh of a sphere of radius 8 mm (anisotropic spacing), over blocks of 8
// voxels. Within a quarter of a voxel it stays closed with its volume; within a voxel, closed with
// fewer than half the triangles. Every triangle lies inside its block, every vertex is one of the
// input's, and the surface moves by about the error (Hausdorff: the quadric error is no bound).
TEST(MeshSimplify, ASphereStaysClosedWithEachTriangleInsideItsBlock) {
  const glm::dvec3 spacing(0.8, 0.8, 1.5);
  const Volume v = test::makeVolume({40, 40, 24}, [&](int i, int j, int k) {
    return 10.0 - glm::length((glm::dvec3(i, j, k) - glm::dvec3(19.5, 19.5, 11.5)) * spacing / 0.8);
  }, spacing);
  const TriangleMesh in = fineMeshToTriangles(SurfaceOctree::build(v, VolumeOctree::build(v), 0.0f).reconstruct(0), v.spacing());
  const MeshCheck before = checkMesh(in);
  ASSERT_TRUE(before.closed);
  std::set<std::tuple<float, float, float>> inputs;
  for (const glm::vec3& p : in.vertices) inputs.insert({p.x, p.y, p.z});
  const glm::dvec3 block = 8.0 * spacing;

  const TriangleMesh fine = simplifyWithinBlocks(in, block, 0.2);
  EXPECT_LT(fine.triangles.size() * 5, in.triangles.size() * 4);
  EXPECT_TRUE(checkMesh(fine).closed);
  EXPECT_NEAR(enclosedVolume(fine), before.volume, 2e-3 * before.volume);
  EXPECT_LT(hausdorffDistance(in, fine, 0.02).upper, 0.5);

  const TriangleMesh coarse = simplifyWithinBlocks(in, block, 0.8);
  EXPECT_LT(coarse.triangles.size() * 2, in.triangles.size());
  EXPECT_TRUE(checkMesh(coarse).closed);
  EXPECT_LT(hausdorffDistance(in, coarse, 0.02).upper, 1.5 * 0.8);
  EXPECT_EQ(flatTriangles(in), 0u);
  for (const TriangleMesh* out : {&fine, &coarse}) {
    expectInsideBlocks(*out, block);
    EXPECT_EQ(flatTriangles(*out), 0u);
    for (const glm::vec3& p : out->vertices) EXPECT_TRUE(inputs.count({p.x, p.y, p.z}));
  }
}

// A bumpy ball (bone-like: curvature at every scale) over blocks of 8 voxels. Two blocks that
// collapse onto the same three vertices of their common border make a triangle and its mirror
// image there; both are dropped, where the blocks used to be simplified again with those vertices
// fixed (nearly every block of a CT's bone, twice the time), a pair coming back beside a block
// done again. The result is as sound: closed (on this input no vertex is left between two fans; a
// pair stays where dropping it would leave one), its volume kept, each triangle inside its block,
// no flat triangle, no triangle over its mirror image.
TEST(MeshSimplify, MirroredPairsOverABlockBorderAreDroppedNotSimplifiedAgain) {
  const glm::dvec3 spacing(0.7, 0.7, 0.9);
  const glm::dvec3 c(23.3, 24.1, 22.7);
  const Volume v = test::makeVolume({48, 48, 46}, [&](int i, int j, int k) {
    const glm::dvec3 p = glm::dvec3(i, j, k) - c;
    return 17.0 - glm::length(p) + 1.6 * std::sin(0.9 * p.x) * std::cos(0.7 * p.y) + 1.2 * std::sin(0.8 * p.z + 0.5 * p.x);
  }, spacing);
  const TriangleMesh in = fineMeshToTriangles(SurfaceOctree::build(v, VolumeOctree::build(v), 0.0f).reconstruct(0), v.spacing());
  const MeshCheck before = checkMesh(in);
  ASSERT_TRUE(before.closed);
  const glm::dvec3 block = 8.0 * spacing;
  size_t restored = 0;
  for (const double error : {0.35, 0.7, 1.4}) {
    SCOPED_TRACE("error " + std::to_string(error) + " mm");
    SimplifyStats stats;
    const TriangleMesh out = simplifyWithinBlocks(in, block, error, nullptr, &stats);
    EXPECT_LT(out.triangles.size() * 2, in.triangles.size());
    EXPECT_GT(stats.mirroredPairs, 0u);            // 15, 42, 50
    EXPECT_LT(stats.blocksRedone * 4, stats.blocks);  // 2, 2, 8 of 105 (simplified again: 25, 56, 63)
    restored += stats.pairsRestored;  // 0, 0, 5
    EXPECT_TRUE(checkMesh(out).closed);
    EXPECT_NEAR(enclosedVolume(out), before.volume, 0.025 * before.volume);  // 0.3, 1.1, 1.9 %
    EXPECT_LT(hausdorffDistance(in, out, 0.02).upper, 1.5 * error + 0.5);   // 0.89, 1.14, 2.10 mm
    expectInsideBlocks(out, block);
    EXPECT_EQ(flatTriangles(out), 0u);
    std::set<std::tuple<uint32_t, uint32_t, uint32_t>> sets;
    for (glm::uvec3 t : out.triangles) {
      std::sort(&t.x, &t.x + 3);
      EXPECT_TRUE(sets.insert({t.x, t.y, t.z}).second) << "a triangle over its mirror image";
    }
  }
  EXPECT_GT(restored, 0u);  // the checks above saw pairs given back beside blocks done again
}

// A box's surface (planes, chamfered edges) over blocks of 4 voxels: within a thousandth of a voxel
// only planar parts collapse, onto their blocks' borders, which stay where they were, so the
// enclosed volume is the input's.
TEST(MeshSimplify, PlanarPiecesCollapseToTheirBlocksBorders) {
  const Volume v = test::boxVolume({20, 20, 20}, {3, 3, 3}, {15, 15, 15}, 1.0f, 0.0f);
  const TriangleMesh in = toTriangleMesh(extractDiscMC(v, 0.5f), v.spacing());
  const TriangleMesh out = simplifyWithinBlocks(in, glm::dvec3(4.0), 1e-3);
  EXPECT_LT(out.triangles.size() * 3, in.triangles.size() * 2);  // 1,026 of 2,024
  expectInsideBlocks(out, glm::dvec3(4.0));
  EXPECT_EQ(flatTriangles(out), 0u);  // three border vertices in a line are not spanned by one triangle
  const MeshCheck before = checkMesh(in), after = checkMesh(out);
  EXPECT_TRUE(after.closed);
  EXPECT_NEAR(enclosedVolume(out), before.volume, 1e-6 * before.volume);
  // Nothing to simplify: an empty mesh stays empty.
  EXPECT_TRUE(simplifyWithinBlocks(TriangleMesh{}, glm::dvec3(4.0), 1.0).triangles.empty());
}

// A progress callback that stops the work part way (as a closing viewer would) is heard as an
// exception from the call, though the blocks are simplified on OpenMP's threads.
TEST(MeshSimplify, AProgressCallbackThatThrowsStopsTheWork) {
  const Volume v = test::boxVolume({20, 20, 20}, {3, 3, 3}, {15, 15, 15}, 1.0f, 0.0f);
  const TriangleMesh in = toTriangleMesh(extractDiscMC(v, 0.5f), v.spacing());
  struct Stop {};
  int heard = 0;
  const Progress stop([&](const std::string& task, double fraction) {
    EXPECT_EQ(task, "simplified surface");
    ++heard;
    if (fraction > 0.0 && fraction < 1.0) throw Stop{};
  });
  EXPECT_THROW(simplifyWithinBlocks(in, glm::dvec3(4.0), 1e-3, &stop), Stop);
  EXPECT_GE(heard, 2);  // the start, then the percent that threw
}

TEST(MeshSimplify, ImpossibleParametersAreRefused) {
  const TriangleMesh none;
  EXPECT_THROW(simplifyWithinBlocks(none, glm::dvec3(0.0, 1.0, 1.0), 1.0), ValueError);
  EXPECT_THROW(simplifyWithinBlocks(none, glm::dvec3(NAN, 1.0, 1.0), 1.0), ValueError);
  EXPECT_THROW(simplifyWithinBlocks(none, glm::dvec3(1.0), 0.0), ValueError);
  EXPECT_THROW(simplifyWithinBlocks(none, glm::dvec3(1.0), INFINITY), ValueError);
}

}  // namespace
}  // namespace hyb
