// The reference ray tracer's surface crossings (Embree): every crossing a brute-force scan of all
// triangles finds, at the same distances, in the same order, with the same normals.
#include "render/bvh.h"

#include <gtest/gtest.h>

#include <random>

#include "hybrid_octree/surface_octree.h"
#include "hybrid_octree/volume_octree.h"
#include "render_util.h"
#include "surface/mesh_ops.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

// Every crossing of @p mesh with tMin < t < tMax by testing each triangle (Möller–Trumbore in
// double precision), sorted, those at the same distance counted once: what the hand-written BVH
// Embree replaced returned.
std::vector<Hit> bruteForce(const TriangleMesh& mesh, const glm::dvec3& o, const glm::dvec3& d, double tMin, double tMax) {
  std::vector<Hit> hits;
  for (const glm::uvec3& tri : mesh.triangles) {
    const glm::dvec3 p0 = mesh.vertices[tri.x], p1 = mesh.vertices[tri.y], p2 = mesh.vertices[tri.z];
    const glm::dvec3 e1 = p1 - p0, e2 = p2 - p0, pv = glm::cross(d, e2);
    const double det = glm::dot(e1, pv);
    if (std::abs(det) < 1e-18) continue;
    const glm::dvec3 tv = o - p0, qv = glm::cross(tv, e1);
    const double u = glm::dot(tv, pv) / det, v = glm::dot(d, qv) / det, t = glm::dot(e2, qv) / det;
    if (u < 0.0 || v < 0.0 || u + v > 1.0 || t <= tMin || t >= tMax) continue;
    const glm::dvec3 n = (1.0 - u - v) * glm::dvec3(mesh.normals[tri.x]) + u * glm::dvec3(mesh.normals[tri.y]) + v * glm::dvec3(mesh.normals[tri.z]);
    hits.push_back({t, glm::normalize(n)});
  }
  std::sort(hits.begin(), hits.end(), [](const Hit& a, const Hit& b) { return a.t < b.t; });
  hits.erase(std::unique(hits.begin(), hits.end(), [](const Hit& a, const Hit& b) { return std::abs(a.t - b.t) < 1e-9 * (1 + std::abs(a.t)); }),
             hits.end());
  return hits;
}

// Rays from around @p mesh's box through random points of it (some starting halfway): the same
// crossings as the brute force, at the same distances, in the same order, with the same normals.
// Rays exactly through vertices along the grid's axes (through edges shared by several triangles,
// along faces; none of a frame's pixel rays is one): where the surface only touches such a ray,
// the inclusive brute force counts a crossing and Embree's watertight test may not; every
// crossing Embree reports is one of the brute force's.
void expectSameCrossings(const TriangleMesh& mesh, int rays, uint32_t seed) {
  glm::dvec3 lo(1e30), hi(-1e30);
  for (const glm::vec3& p : mesh.vertices) {
    lo = glm::min(lo, glm::dvec3(p));
    hi = glm::max(hi, glm::dvec3(p));
  }
  const Bvh bvh(mesh);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Hit> hits;
  size_t crossings = 0, grazed = 0;
  for (int r = 0; r < rays; ++r) {
    const bool throughVertex = r % 4 == 3;
    glm::dvec3 o, target;
    if (throughVertex) {
      target = mesh.vertices[size_t(u(rng) * double(mesh.vertices.size() - 1))];
      o = target;
      o[r % 3] = lo[r % 3] - 10.0;
    } else {
      const glm::dvec3 c = 0.5 * (lo + hi), half = 0.5 * (hi - lo);
      o = c + 3.0 * glm::length(half) * glm::normalize(glm::dvec3(u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5));
      target = lo + glm::dvec3(u(rng), u(rng), u(rng)) * (hi - lo);
    }
    const glm::dvec3 d = glm::normalize(target - o);
    const double tMin = r % 5 == 0 && !throughVertex ? glm::length(target - o) * 0.5 : 0.0;
    const double tMax = r % 3 == 0 ? 1e300 : r % 3 == 1 ? 1e30 : glm::length(target - o) * 1.2;  // beyond float's range, far, or inside the box
    bvh.allHits(o, d, tMin, tMax, &hits);
    const std::vector<Hit> expected = bruteForce(mesh, o, d, tMin, tMax);
    if (throughVertex) {
      for (const Hit& h : hits)
        ASSERT_TRUE(std::any_of(expected.begin(), expected.end(), [&](const Hit& e) { return std::abs(e.t - h.t) < 1e-9 * (1 + e.t); })) << "ray " << r;
      grazed += expected.size() - hits.size();
      continue;
    }
    ASSERT_EQ(hits.size(), expected.size()) << "ray " << r;
    for (size_t i = 0; i < hits.size(); ++i) {
      ASSERT_NEAR(hits[i].t, expected[i].t, 1e-9 * (1 + expected[i].t)) << "ray " << r << ", hit " << i;
      ASSERT_GT(glm::dot(hits[i].normal, expected[i].normal), 1.0 - 1e-9) << "ray " << r << ", hit " << i;
    }
    crossings += hits.size();
  }
  EXPECT_GT(crossings, size_t(rays));
  EXPECT_GT(grazed, 0u);  // the rays through vertices did meet such contacts
}

TEST(Bvh, EmbreesCrossingsAreEveryTrianglesOnTheSphere) {
  const Scene s = test::sphereScene();
  TriangleMesh mesh = fineMeshToTriangles(SurfaceOctree::build(s.volume, s.octree, 0.0f).reconstruct(), s.volume.spacing());
  setGradientNormals(s.volume, &mesh);
  expectSameCrossings(mesh, 2000, 5);
  const Bvh none(TriangleMesh{});
  std::vector<Hit> hits{{1.0, glm::dvec3(1.0)}};
  none.allHits(glm::dvec3(0.0), glm::dvec3(1, 0, 0), 0.0, 1e30, &hits);
  EXPECT_TRUE(none.empty());
  EXPECT_TRUE(hits.empty());
}

// firstHit walked from crossing to crossing (each search starting just past the last, as the
// moving frames' tracer does) finds allHits' crossings: the same count, each at Embree's float
// distance (within 1e-5 relative) with the same normal, the search past the last finding none.
TEST(Bvh, FirstHitWalksTheCrossingsOfAllHits) {
  const Scene s = test::sphereScene();
  TriangleMesh mesh = fineMeshToTriangles(SurfaceOctree::build(s.volume, s.octree, 0.0f).reconstruct(), s.volume.spacing());
  setGradientNormals(s.volume, &mesh);
  const Bvh bvh(mesh);
  const glm::dvec3 c = 0.5 * s.volume.extentMm();
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Hit> all;
  size_t crossings = 0;
  for (int r = 0; r < 500; ++r) {
    const glm::dvec3 o = c + 80.0 * glm::normalize(glm::dvec3(u(rng), u(rng), u(rng)));
    const glm::dvec3 d = glm::normalize(c + 12.0 * glm::dvec3(u(rng), u(rng), u(rng)) - o);
    bvh.allHits(o, d, 0.0, 1e300, &all);
    std::optional<Hit> h = bvh.firstHit(o, d, 0.0, 1e300);
    for (const Hit& expected : all) {
      ASSERT_TRUE(h.has_value()) << "ray " << r;
      EXPECT_NEAR(h->t, expected.t, 1e-5 * expected.t) << "ray " << r;
      EXPECT_GT(glm::dot(h->normal, expected.normal), 1.0 - 1e-5) << "ray " << r;
      h = bvh.firstHit(o, d, h->t + 1e-6 * (1.0 + h->t), 1e300);
    }
    EXPECT_FALSE(h.has_value()) << "ray " << r;
    crossings += all.size();
  }
  EXPECT_GT(crossings, size_t(500));  // most rays cross the sphere twice
  EXPECT_FALSE(Bvh(TriangleMesh{}).firstHit(c, glm::dvec3(1, 0, 0), 0.0, 1e300).has_value());
}

TEST(Bvh, EmbreesCrossingsAreEveryTrianglesOnTheCraniumsBone) {
  const Volume v = readVolume(kDefaultVolumePath);
  const VolumeOctree t = VolumeOctree::build(v);
  TriangleMesh mesh = fineMeshToTriangles(SurfaceOctree::build(v, t, 400.0f).reconstruct(), v.spacing());
  setGradientNormals(v, &mesh);
  ASSERT_GT(mesh.triangles.size(), size_t(300000));
  expectSameCrossings(mesh, 120, 9);
}

}  // namespace
}  // namespace hyb
