#include "render/slab_polygons.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include "hybrid_octree/surface_octree.h"
#include "test_util.h"

namespace hyb {
namespace {

// The pieces of a stream: each a triangle of three positions (kind 1 vertices).
std::vector<std::array<glm::vec3, 3>> triangles(const std::vector<float>& stream) {
  std::vector<std::array<glm::vec3, 3>> out;
  for (size_t v = 0; v + 3 * kStreamFloats <= stream.size(); v += 3 * kStreamFloats) {
    std::array<glm::vec3, 3> t;
    for (int k = 0; k < 3; ++k) {
      const float* p = &stream[v + size_t(k) * kStreamFloats];
      EXPECT_EQ(p[6], 1.0f);  // a surface piece
      t[size_t(k)] = glm::vec3(p[0], p[1], p[2]);
    }
    out.push_back(t);
  }
  return out;
}

// One triangle from z = 0.5 to z = 2.5 against planes z = k (Δ = 1, seen along +z): it covers
// slabs 0, 1 and 2, and its pieces come far to near (slab 2 first), each cut exactly at the planes.
TEST(SlabPolygons, ATriangleIsCutIntoTheSlabsItCoversFarToNear) {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0.5f}, {2, 0, 2.5f}, {0, 2, 0.5f}};
  mesh.triangles = {{0, 1, 2}};
  const SurfacePolygons surface(mesh);
  const uint32_t polygons[] = {0};
  SlabPolygonList list;
  const ProxyDepth depth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)};
  list.build(surface, polygons, depth, 1.0, true);
  EXPECT_EQ(list.firstSlab(), 0);
  EXPECT_EQ(list.lastSlab(), 2);
  EXPECT_EQ(list.triangles(), 1u);
  std::vector<float> stream;
  list.emitDownTo(2, &stream);  // slab 2: the tip above z = 2, one triangle
  std::vector<std::array<glm::vec3, 3>> t = triangles(stream);
  ASSERT_EQ(t.size(), 1u);
  EXPECT_EQ(t[0][0], glm::vec3(1.5f, 0, 2));
  EXPECT_EQ(t[0][1], glm::vec3(2, 0, 2.5f));
  EXPECT_EQ(t[0][2], glm::vec3(1.5f, 0.5f, 2));
  stream.clear();
  list.emitDownTo(1, &stream);  // slab 1: the band 1 <= z < 2, a quadrilateral fanned in two
  t = triangles(stream);
  ASSERT_EQ(t.size(), 2u);
  EXPECT_EQ(t[0][0], glm::vec3(0.5f, 0, 1));
  EXPECT_EQ(t[0][1], glm::vec3(1.5f, 0, 2));
  EXPECT_EQ(t[0][2], glm::vec3(1.5f, 0.5f, 2));
  EXPECT_EQ(t[1][2], glm::vec3(0.5f, 1.5f, 1));
  stream.clear();
  list.emitRest(&stream);  // slab 0: the base, a quadrilateral
  t = triangles(stream);
  ASSERT_EQ(t.size(), 2u);
  EXPECT_EQ(t[0][0], glm::vec3(0, 0, 0.5f));
  EXPECT_EQ(t[0][1], glm::vec3(0.5f, 0, 1));
  EXPECT_EQ(t[0][2], glm::vec3(0.5f, 1.5f, 1));
  EXPECT_EQ(t[1][2], glm::vec3(0, 2, 0.5f));
  EXPECT_EQ(list.draws(), 3u);
  stream.clear();
  list.emitRest(&stream);
  EXPECT_TRUE(stream.empty());  // everything was emitted once
}

// Inside one slab the pieces go far to near by their centroid's depth; a brick without slices
// sorts its polygons only.
TEST(SlabPolygons, PiecesInOneSlabAreSortedByDepth) {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0.2f}, {1, 0, 0.2f}, {0, 1, 0.2f}, {0, 0, 0.8f}, {1, 0, 0.8f}, {0, 1, 0.8f}};
  mesh.triangles = {{0, 1, 2}, {3, 4, 5}};
  const SurfacePolygons surface(mesh);
  const uint32_t polygons[] = {0, 1};
  const ProxyDepth depth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)};
  for (const bool sliced : {true, false}) {
    SlabPolygonList list;
    list.build(surface, polygons, depth, 1.0, sliced);
    std::vector<float> stream;
    list.emitRest(&stream);
    const std::vector<std::array<glm::vec3, 3>> t = triangles(stream);
    ASSERT_EQ(t.size(), 2u);
    EXPECT_EQ(t[0][0].z, 0.8f);  // the farther first
    EXPECT_EQ(t[1][0].z, 0.2f);
  }
}

// Uncut (frames while the view moves): the triangle of the first test goes whole into the slab of
// its centroid's depth (z = 7/6, slab 1), one draw, its vertices unchanged; the polygons of a brick
// still come far to near by slab.
TEST(SlabPolygons, UncutPolygonsGoWholeIntoTheSlabOfTheirCentroid) {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0.5f}, {2, 0, 2.5f}, {0, 2, 0.5f}, {0, 0, 3.2f}, {1, 0, 3.2f}, {0, 1, 3.9f}};
  mesh.triangles = {{0, 1, 2}, {3, 4, 5}};
  const SurfacePolygons surface(mesh);
  const uint32_t polygons[] = {0, 1};
  SlabPolygonList list;
  list.build(surface, polygons, ProxyDepth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)}, 1.0, true, false);
  EXPECT_EQ(list.firstSlab(), 1);
  EXPECT_EQ(list.lastSlab(), 3);  // the second's centroid is at z = 3.43
  std::vector<float> stream;
  list.emitDownTo(2, &stream);
  std::vector<std::array<glm::vec3, 3>> t = triangles(stream);
  ASSERT_EQ(t.size(), 1u);
  EXPECT_EQ(t[0][2], glm::vec3(0, 1, 3.9f));
  stream.clear();
  list.emitDownTo(1, &stream);
  t = triangles(stream);
  ASSERT_EQ(t.size(), 1u);
  EXPECT_EQ(t[0][0], glm::vec3(0, 0, 0.5f));
  EXPECT_EQ(t[0][1], glm::vec3(2, 0, 2.5f));
  EXPECT_EQ(t[0][2], glm::vec3(0, 2, 0.5f));
  stream.clear();
  list.emitRest(&stream);
  EXPECT_TRUE(stream.empty());
  EXPECT_EQ(list.draws(), 2u);
}

// A convex polygon that spans slabs is cut whole (one piece a slab), its vertex normals
// interpolated where the planes cut its edges.
TEST(SlabPolygons, ConvexPolygonsAreCutWholeWithTheirNormalsInterpolated) {
  TriangleMesh mesh;  // the square x = 0, 0 <= y, z <= 2, normals tilting from -z to +z
  mesh.vertices = {{0, 0, 0}, {0, 2, 0}, {0, 2, 2}, {0, 0, 2}};
  mesh.normals = {{1, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 1, 0}};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  mesh.polygonStarts = {0, 2};
  mesh.loopStarts = {0, 4};
  mesh.loops = {0, 1, 2, 3};
  const SurfacePolygons surface(mesh);
  const uint32_t polygons[] = {0};
  SlabPolygonList list;
  list.build(surface, polygons, ProxyDepth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)}, 1.0, true);
  std::vector<float> stream;
  list.emitDownTo(1, &stream);  // slab 1 (1 <= z < 2; z = 2 falls in slab 2, which gets a sliver of nothing)
  std::vector<float> slabTwoAndOne = stream;
  ASSERT_FALSE(slabTwoAndOne.empty());
  // Every vertex at z = 1 carries the normal halfway between the bottom's and the top's.
  bool found = false;
  for (size_t v = 0; v < stream.size(); v += kStreamFloats)
    if (stream[v + 2] == 1.0f) {
      found = true;
      EXPECT_FLOAT_EQ(stream[v + 3], 0.5f);
      EXPECT_FLOAT_EQ(stream[v + 4], 0.5f);
    }
  EXPECT_TRUE(found);
  EXPECT_EQ(list.draws(), 2u);  // one piece in slab 2 (the edge at z = 2), one in slab 1
}

// Twice a triangle's area over its longest edge: the height of its apex, zero when it is flat.
double apexHeight(const std::array<glm::vec3, 3>& t) {
  const glm::dvec3 a(t[0]), b(t[1]), c(t[2]);
  const double longest = std::max({glm::length(b - a), glm::length(c - b), glm::length(a - c)});
  return longest > 0.0 ? glm::length(glm::cross(b - a, c - a)) / longest : 0.0;
}

// The Surface Octree's convex polygons carry T-junction vertices on their edges (where they meet
// finer neighbours). A piece fanned from a corner whose edges hold them had triangles of zero
// area, which llvmpipe rasterised as black specks: each slab's piece must keep every vertex (no
// crack at the T-junctions), cover exactly its part of the polygon, and have no flat triangle.
TEST(SlabPolygons, CollinearVerticesAreNeverFannedIntoFlatTriangles) {
  TriangleMesh mesh;  // the square 0 <= x, y <= 4 on the plane z = 0.3 + 0.5 x, with T-vertices at (2, 0) and (0, 2)
  auto at = [](float x, float y) { return glm::vec3(x, y, 0.3f + 0.5f * x); };
  mesh.vertices = {at(0, 0), at(2, 0), at(4, 0), at(4, 4), at(0, 4), at(0, 2)};
  mesh.triangles = {{0, 1, 5}, {1, 2, 3}, {1, 3, 5}, {5, 3, 4}};
  mesh.polygonStarts = {0, 4};
  mesh.loopStarts = {0, 6};
  mesh.loops = {0, 1, 2, 3, 4, 5};
  const SurfacePolygons surface(mesh);
  const uint32_t polygons[] = {0};
  SlabPolygonList list;
  list.build(surface, polygons, ProxyDepth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)}, 1.0, true);
  ASSERT_EQ(list.firstSlab(), 0);
  ASSERT_EQ(list.lastSlab(), 2);  // z from 0.3 to 2.3
  for (long long slab = 2; slab >= 0; --slab) {
    std::vector<float> stream;
    list.emitDownTo(slab, &stream);
    double area = 0.0;
    bool t1 = false, t2 = false;
    for (const std::array<glm::vec3, 3>& t : triangles(stream)) {
      EXPECT_GT(apexHeight(t), 0.05) << "slab " << slab;
      area += 0.5 * glm::length(glm::cross(glm::dvec3(t[1] - t[0]), glm::dvec3(t[2] - t[0])));
      for (const glm::vec3& p : t) t1 |= p == at(2, 0), t2 |= p == at(0, 2);
    }
    // Slab k holds 2k - 0.6 <= x < 2k + 1.4 of the square, 4 mm wide, tilted by sqrt(1.25).
    const double x0 = std::max(0.0, 2.0 * double(slab) - 0.6), x1 = std::min(4.0, 2.0 * double(slab) + 1.4);
    EXPECT_NEAR(area, (x1 - x0) * 4.0 * std::sqrt(1.25), 1e-5) << "slab " << slab;
    EXPECT_EQ(t1, slab == 1) << "slab " << slab;  // (2, 0) is at z = 1.3, (0, 2) at z = 0.3
    EXPECT_EQ(t2, slab == 0) << "slab " << slab;
  }
}

double shortestEdge(const std::array<glm::vec3, 3>& t) {
  return std::min({glm::length(t[1] - t[0]), glm::length(t[2] - t[1]), glm::length(t[0] - t[2])});
}

// The same on a real Surface Octree: a sphere's merged polygons, from many directions, leave no
// piece with a flat triangle (edges longer than 0.01 mm, its apex within 1e-4 mm of the longest).
TEST(SlabPolygons, TheSurfaceOctreesPiecesHaveNoFlatTriangle) {
  const Volume v = test::sphereVolume({64, 64, 64}, 26.5);
  const VolumeOctree octree = VolumeOctree::build(v);
  const SurfaceOctree so = SurfaceOctree::build(v, octree, 0.0f);
  const TriangleMesh mesh = fineMeshToTriangles(so.reconstruct(), v.spacing());
  ASSERT_FALSE(mesh.loops.empty());
  const SurfacePolygons surface(mesh);
  std::vector<uint32_t> all(surface.count());
  std::iota(all.begin(), all.end(), 0u);
  size_t pieces = 0;
  for (int d = 0; d < 24; ++d) {
    const double az = 0.7 + 0.9 * d, el = 0.3 * std::sin(1.7 * d);  // radians
    const glm::dvec3 forward(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    SlabPolygonList list;
    list.build(surface, all, ProxyDepth{false, forward, glm::dvec3(0.0)}, 0.5, true);
    std::vector<float> stream;
    list.emitRest(&stream);
    size_t flat = 0;
    for (const std::array<glm::vec3, 3>& t : triangles(stream)) flat += apexHeight(t) < 1e-4 && shortestEdge(t) > 1e-2;
    EXPECT_EQ(flat, 0u) << "direction " << d;
    pieces += list.draws();
  }
  EXPECT_GT(pieces, 24u * surface.count());  // polygons were cut
}

TEST(SlabPolygons, DistanceToATriangleFromEachRegion) {
  const glm::dvec3 a(0, 0, 0), b(4, 0, 0), c(0, 4, 0);
  EXPECT_DOUBLE_EQ(distanceToTriangle(glm::dvec3(1, 1, 3), a, b, c), 3.0);   // over the face
  EXPECT_DOUBLE_EQ(distanceToTriangle(glm::dvec3(-3, -4, 0), a, b, c), 5.0);  // nearest a corner
  EXPECT_DOUBLE_EQ(distanceToTriangle(glm::dvec3(2, -2, 0), a, b, c), 2.0);   // nearest an edge
  EXPECT_NEAR(distanceToTriangle(glm::dvec3(3, 3, 0), a, b, c), std::sqrt(2.0), 1e-12);  // beyond the hypotenuse
}

}  // namespace
}  // namespace hyb
