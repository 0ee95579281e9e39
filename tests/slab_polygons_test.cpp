#include "render/slices/slab_polygons.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <vector>

#include <glm/gtc/matrix_transform.hpp>

#include "hybrid_octree/surface_octree.h"
#include "render/gl_objects.h"
#include "render_util.h"
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

// The depths [near, far) the fragments of each triangle of a stream must lie within.
std::vector<glm::vec2> slabsOf(const std::vector<float>& stream) {
  std::vector<glm::vec2> out;
  for (size_t v = 0; v + 3 * kStreamFloats <= stream.size(); v += 3 * kStreamFloats) {
    const glm::vec2 slab(stream[v + 7], stream[v + 8]);
    for (size_t k = 1; k < 3; ++k) EXPECT_EQ(glm::vec2(stream[v + k * kStreamFloats + 7], stream[v + k * kStreamFloats + 8]), slab);
    out.push_back(slab);
  }
  return out;
}

// One triangle from z = 0.5 to z = 2.5 against planes z = k (Δ = 1, seen along +z): it covers
// slabs 0, 1 and 2 and comes whole once in each, far to near (slab 2 first), with the slab's
// depths, open at the triangle's ends (a fragment just beyond its depth range is still drawn once).
TEST(SlabPolygons, ATriangleComesWholeOnceInEachSlabItCoversFarToNear) {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0.5f}, {2, 0, 2.5f}, {0, 2, 0.5f}};
  mesh.triangles = {{0, 1, 2}};
  const SurfacePolygons surface(mesh);
  const uint32_t polygons[] = {0};
  SlabPolygonList list;
  const ProxyDepth depth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)};
  list.build(surface, polygons, {depth, 1.0, true, true});
  EXPECT_EQ(list.firstSlab(), 0);
  EXPECT_EQ(list.lastSlab(), 2);
  EXPECT_EQ(list.triangles(), 1u);
  std::vector<float> stream;
  const std::array<glm::vec3, 3> whole{mesh.vertices[0], mesh.vertices[1], mesh.vertices[2]};
  const glm::vec2 expected[] = {{2.0f, 1e30f}, {1.0f, 2.0f}, {-1e30f, 1.0f}};
  for (long long slab = 2; slab >= 0; --slab) {
    list.emitDownTo(slab, &stream);
    const std::vector<std::array<glm::vec3, 3>> t = triangles(stream);
    ASSERT_EQ(t.size(), 1u) << "slab " << slab;
    EXPECT_EQ(t[0], whole) << "slab " << slab;
    EXPECT_EQ(slabsOf(stream)[0], expected[2 - slab]) << "slab " << slab;
    stream.clear();
  }
  EXPECT_EQ(list.draws(), 3u);
  list.emitRest(&stream);
  EXPECT_TRUE(stream.empty());  // everything was emitted once
}

// Inside one slab the triangles go far to near by their centroid's depth; a brick without slices
// sorts its polygons only.
TEST(SlabPolygons, TrianglesInOneSlabAreSortedByDepth) {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0.2f}, {1, 0, 0.2f}, {0, 1, 0.2f}, {0, 0, 0.8f}, {1, 0, 0.8f}, {0, 1, 0.8f}};
  mesh.triangles = {{0, 1, 2}, {3, 4, 5}};
  const SurfacePolygons surface(mesh);
  const uint32_t polygons[] = {0, 1};
  const ProxyDepth depth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)};
  for (const bool sliced : {true, false}) {
    SlabPolygonList list;
    list.build(surface, polygons, {depth, 1.0, sliced, true});
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
  list.build(surface, polygons, {ProxyDepth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)}, 1.0, true, false});
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

// Twice a triangle's area over its longest edge: the height of its apex, zero when it is flat.
double apexHeight(const std::array<glm::vec3, 3>& t) {
  const glm::dvec3 a(t[0]), b(t[1]), c(t[2]);
  const double longest = std::max({glm::length(b - a), glm::length(c - b), glm::length(a - c)});
  return longest > 0.0 ? glm::length(glm::cross(b - a, c - a)) / longest : 0.0;
}

// A Surface Octree polygon carries T-junction vertices on its edges (where it meets finer
// neighbours); its triangulation keeps them. Each slab takes exactly the polygon's triangles whose
// depth range reaches it, unchanged (no new vertex, so no crack where two triangles share an edge,
// and no flat triangle, which llvmpipe rasterised as black specks), with the mesh's normals.
TEST(SlabPolygons, EachSlabTakesThePolygonsOwnTrianglesThatReachIt) {
  TriangleMesh mesh;  // the square 0 <= x, y <= 4 on the plane z = 0.3 + 0.5 x, with T-vertices at (2, 0) and (0, 2)
  auto at = [](float x, float y) { return glm::vec3(x, y, 0.3f + 0.5f * x); };
  mesh.vertices = {at(0, 0), at(2, 0), at(4, 0), at(4, 4), at(0, 4), at(0, 2)};
  mesh.normals = {{1, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 1, 0}, {0, 0, 1}, {0, 0, 1}};
  mesh.triangles = {{0, 1, 5}, {1, 2, 3}, {1, 3, 5}, {5, 3, 4}};
  mesh.polygonStarts = {0, 4};
  const SurfacePolygons surface(mesh);
  const uint32_t polygons[] = {0};
  SlabPolygonList list;
  list.build(surface, polygons, {ProxyDepth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)}, 1.0, true, true});
  ASSERT_EQ(list.firstSlab(), 0);
  ASSERT_EQ(list.lastSlab(), 2);  // z from 0.3 to 2.3
  size_t draws = 0;
  for (long long slab = 2; slab >= 0; --slab) {
    std::vector<float> stream;
    list.emitDownTo(slab, &stream);
    std::vector<std::array<glm::vec3, 3>> expected;
    for (const glm::uvec3& tr : mesh.triangles) {
      const float z0 = std::min({mesh.vertices[tr.x].z, mesh.vertices[tr.y].z, mesh.vertices[tr.z].z});
      const float z1 = std::max({mesh.vertices[tr.x].z, mesh.vertices[tr.y].z, mesh.vertices[tr.z].z});
      if (std::floor(z0) <= float(slab) && float(slab) <= std::floor(z1)) expected.push_back({mesh.vertices[tr.x], mesh.vertices[tr.y], mesh.vertices[tr.z]});
    }
    EXPECT_EQ(triangles(stream), expected) << "slab " << slab;
    for (const std::array<glm::vec3, 3>& t : triangles(stream)) EXPECT_GT(apexHeight(t), 0.05) << "slab " << slab;
    for (size_t v = 0; v < stream.size(); v += kStreamFloats) {
      const glm::vec3 p(stream[v], stream[v + 1], stream[v + 2]), n(stream[v + 3], stream[v + 4], stream[v + 5]);
      const size_t i = size_t(std::find(mesh.vertices.begin(), mesh.vertices.end(), p) - mesh.vertices.begin());
      ASSERT_LT(i, mesh.vertices.size());
      EXPECT_EQ(n, mesh.normals[i]);
    }
    draws += expected.size();
  }
  EXPECT_EQ(list.draws(), draws);
  EXPECT_EQ(draws, 10u);  // the triangles reach 2, 2, 3 and 3 slabs
}

double shortestEdge(const std::array<glm::vec3, 3>& t) {
  return std::min({glm::length(t[1] - t[0]), glm::length(t[2] - t[1]), glm::length(t[0] - t[2])});
}

// The same on a real Surface Octree: a sphere's merged polygons, from many directions, put no
// flat triangle in the stream (edges longer than 0.01 mm, its apex within 1e-4 mm of the longest).
TEST(SlabPolygons, TheSurfaceOctreesStreamHasNoFlatTriangle) {
  const Volume v = test::sphereVolume({64, 64, 64}, 26.5);
  const VolumeOctree octree = VolumeOctree::build(v);
  const SurfaceOctree so = SurfaceOctree::build(v, octree, 0.0f);
  const TriangleMesh mesh = fineMeshToTriangles(so.reconstruct(), v.spacing());
  ASSERT_FALSE(mesh.polygonStarts.empty());
  const SurfacePolygons surface(mesh);
  std::vector<uint32_t> all(surface.count());
  std::iota(all.begin(), all.end(), 0u);
  size_t pieces = 0;
  for (int d = 0; d < 24; ++d) {
    const double az = 0.7 + 0.9 * d, el = 0.3 * std::sin(1.7 * d);  // radians
    const glm::dvec3 forward(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    SlabPolygonList list;
    list.build(surface, all, {ProxyDepth{false, forward, glm::dvec3(0.0)}, 0.5, true, true});
    std::vector<float> stream;
    list.emitRest(&stream);
    size_t flat = 0;
    for (const std::array<glm::vec3, 3>& t : triangles(stream)) flat += apexHeight(t) < 1e-4 && shortestEdge(t) > 1e-2;
    EXPECT_EQ(flat, 0u) << "direction " << d;
    pieces += list.draws();
  }
  EXPECT_GT(pieces, 24u * surface.count());  // triangles came in several slabs
}

// A 4x4 orthographic view of the square [0, 4]², one pixel a millimetre, slabs of 1 mm along z.
// Triangle 0 lies between the centres (around (1, 1)) and is left out; triangle 1 covers the
// centre (1.5, 1.5) only, where it is at z = 1.5: though it spans slabs 0 to 2 it goes to slab 1
// alone, whole, with no depths to keep. A polygon whose triangles are all left out has no
// instance; uncut, the one left keeps its centroid's slab.
TEST(SlabPolygons, TrianglesGoWhereThePixelCentresSeeThem) {
  TriangleMesh mesh;
  mesh.vertices = {{0.9f, 0.9f, 0.2f}, {1.1f, 0.95f, 2.8f}, {0.95f, 1.1f, 1.0f},  // between centres
                   {1.3f, 1.3f, 0.7f}, {1.8f, 1.35f, 2.7f}, {1.4f, 1.8f, 1.1f}};  // over (1.5, 1.5), z = 1.5 + 4 (x − 1.5)
  mesh.triangles = {{0, 1, 2}, {3, 4, 5}};
  const SurfacePolygons surface(mesh);
  const PixelCentres centres(glm::ortho(0.0f, 4.0f, 0.0f, 4.0f, -10.0f, 10.0f), 4, 4);
  const ProxyDepth depth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)};
  const PixelCentres::Cover over = centres.cover(mesh.vertices[3], mesh.vertices[4], mesh.vertices[5], &depth);
  ASSERT_TRUE(over.known);
  EXPECT_EQ(over.centres, 1);
  EXPECT_NEAR(over.nearest, 1.5 - 4.0 / 64.0, 1e-3);  // widened by 1/64 pixel of its slope
  EXPECT_NEAR(over.farthest, 1.5 + 4.0 / 64.0, 1e-3);
  const uint32_t both[] = {0, 1}, between[] = {0};
  SlabPolygonList list;
  list.build(surface, both, {depth, 1.0, true, true}, &centres);
  EXPECT_EQ(list.triangles(), 2u);
  EXPECT_EQ(list.unseen(), 1u);
  EXPECT_EQ(list.firstSlab(), 1);
  EXPECT_EQ(list.lastSlab(), 1);
  std::vector<float> stream;
  list.emitRest(&stream);
  ASSERT_EQ(triangles(stream).size(), 1u);
  EXPECT_EQ(triangles(stream)[0][0], mesh.vertices[3]);
  EXPECT_EQ(slabsOf(stream)[0], glm::vec2(-1e30f, 1e30f));
  EXPECT_EQ(list.draws(), 1u);
  list.build(surface, between, {depth, 1.0, true, true}, &centres);
  EXPECT_TRUE(list.empty());
  list.build(surface, both, {depth, 1.0, true, false}, &centres);  // uncut: triangle 1's centroid z = 1.5
  EXPECT_EQ(list.firstSlab(), 1);
  EXPECT_EQ(list.lastSlab(), 1);
  EXPECT_EQ(list.unseen(), 1u);
}

// Forty triangles spanning slabs 0 to 2 whose centroids (z from 1.2 to 1.6) lie beyond slab 0:
// there every instance sorts at its far bound, and they keep their order in the brick's polygon
// list (reversed here), whatever the sort does with equal keys.
TEST(SlabPolygons, InstancesOfEqualDepthKeepThePolygonsOrder) {
  TriangleMesh mesh;
  std::vector<uint32_t> order;
  for (uint32_t i = 0; i < 40; ++i) {
    const float x = 2.0f * float(i), z = 0.2f + 0.01f * float(i);
    mesh.vertices.insert(mesh.vertices.end(), {{x, 0, z}, {x + 1, 0, z + 2}, {x, 1, z + 1}});
    mesh.triangles.push_back({3 * i, 3 * i + 1, 3 * i + 2});
    order.insert(order.begin(), i);
  }
  const SurfacePolygons surface(mesh);
  SlabPolygonList list;
  list.build(surface, order, {ProxyDepth{false, glm::dvec3(0, 0, 1), glm::dvec3(0.0)}, 1.0, true, true});
  std::vector<float> stream;
  list.emitDownTo(1, &stream);
  stream.clear();
  list.emitRest(&stream);  // slab 0
  const std::vector<std::array<glm::vec3, 3>> t = triangles(stream);
  ASSERT_EQ(t.size(), order.size());
  for (size_t k = 0; k < t.size(); ++k) EXPECT_EQ(t[k][0], mesh.vertices[mesh.triangles[order[k]].x]) << k;
}

// What PixelCentres says a triangle covers is what llvmpipe draws: 3,000 random triangles from a
// tenth of a pixel to a few pixels, some beyond the image's edges, in a perspective 64x48 view,
// each drawn alone with a shader that writes its fragments' depth (along the view, and to the eye
// as shells take it). Where the cover is known, the triangle draws exactly that many pixels, each
// at a depth within the cover's range.
TEST(SlabPolygons, ACoverIsThePixelsATriangleDrawsAndTheirDepths) {
  test::gl();
  const int W = 64, H = 48;
  const gl::FloatTarget target(W, H);
  const gl::Program program = gl::linkProgram(R"(#version 450 core
layout(location = 0) in vec3 position;
uniform mat4 viewProj;
out vec3 world;
void main() { world = position; gl_Position = viewProj * vec4(position, 1.0); }
)",
                                              R"(#version 450 core
in vec3 world;
uniform vec3 eye, forward;
out vec4 colour;
void main() { colour = vec4(dot(forward, world), length(world - eye), 0.0, 1.0); }
)");
  glUseProgram(program.id());
  const glm::vec3 eye(30, -200, 40), centre(0, 0, 0);
  const glm::mat4 viewProj = glm::perspective(glm::radians(30.0f), float(W) / float(H), 1.0f, 500.0f) * glm::lookAt(eye, centre, glm::vec3(0, 0, 1));
  const PixelCentres centres(viewProj, W, H);
  const ProxyDepth planes{false, glm::normalize(glm::dvec3(centre - eye)), glm::dvec3(eye)}, shells{true, planes.forward, planes.eye};
  glUniformMatrix4fv(glGetUniformLocation(program.id(), "viewProj"), 1, GL_FALSE, &viewProj[0][0]);
  glUniform3fv(glGetUniformLocation(program.id(), "eye"), 1, &eye[0]);
  const glm::vec3 forward(planes.forward);
  glUniform3fv(glGetUniformLocation(program.id(), "forward"), 1, &forward[0]);
  const gl::VertexArray vao = gl::VertexArray::make();
  glBindVertexArray(vao.id());
  const gl::Buffer vbo = gl::Buffer::make();
  glBindBuffer(GL_ARRAY_BUFFER, vbo.id());
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 0, nullptr);
  glDisable(GL_DEPTH_TEST);
  glDisable(GL_BLEND);
  std::mt19937 random(7);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
  int known[PixelCentres::kMaxCentres + 1] = {}, unknown = 0;
  std::vector<glm::vec4> pixels(size_t(W) * H);
  for (int i = 0; i < 3000; ++i) {
    // A pixel of this view is about 1.5 mm at the centre: triangles of 0.15 to 6 mm.
    const float size = 0.15f + 6.0f * std::pow(0.5f + 0.5f * unit(random), 3.0f);
    const glm::vec3 c(80.0f * unit(random), 40.0f * unit(random), 60.0f * unit(random));
    const std::array<glm::vec3, 3> t{c + size * glm::vec3(unit(random), unit(random), unit(random)),
                                     c + size * glm::vec3(unit(random), unit(random), unit(random)),
                                     c + size * glm::vec3(unit(random), unit(random), unit(random))};
    const PixelCentres::Cover alongView = centres.cover(t[0], t[1], t[2], &planes), toEye = centres.cover(t[0], t[1], t[2], &shells);
    ASSERT_EQ(alongView.known, toEye.known);
    if (!alongView.known) {
      ++unknown;
      continue;
    }
    ASSERT_EQ(alongView.centres, toEye.centres);
    ++known[alongView.centres];
    glClearColor(0, 0, 0, 0);
    glClear(GL_COLOR_BUFFER_BIT);
    glBufferData(GL_ARRAY_BUFFER, sizeof(t), t.data(), GL_STREAM_DRAW);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glReadPixels(0, 0, W, H, GL_RGBA, GL_FLOAT, pixels.data());
    int drawn = 0;
    for (const glm::vec4& p : pixels) {
      if (p.a == 0.0f) continue;
      ++drawn;
      EXPECT_TRUE(p.r >= alongView.nearest && p.r <= alongView.farthest) << "triangle " << i << ": depth " << p.r << " outside [" << alongView.nearest << ", " << alongView.farthest << "]";
      EXPECT_TRUE(p.g >= toEye.nearest && p.g <= toEye.farthest) << "triangle " << i << ": distance " << p.g << " outside [" << toEye.nearest << ", " << toEye.farthest << "]";
    }
    EXPECT_EQ(drawn, alongView.centres) << "triangle " << i << " (" << size << " mm)";
  }
  EXPECT_GT(known[0], 1000);  // left out
  EXPECT_GT(known[1], 200);   // one pixel: one slab at most
  EXPECT_GT(known[2] + known[3] + known[4], 30);
  EXPECT_GT(unknown, 200);  // larger ones, or a centre on an edge
  EXPECT_EQ(glGetError(), GLenum(GL_NO_ERROR));
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
