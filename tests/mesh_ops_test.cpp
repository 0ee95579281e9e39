#include "surface/mesh_ops.h"

#include <gtest/gtest.h>

#include <cmath>

#include "hybrid_octree/surface_octree.h"
#include "surface/cgal_geometry.h"
#include "surface/dmc.h"
#include "test_util.h"

namespace hyb {
namespace {

TEST(MeshOps, UnreferencedVerticesAreDroppedAndIndicesFollow) {
  TriangleMesh m;
  m.vertices = {{0, 0, 0}, {9, 9, 9}, {1, 0, 0}, {0, 1, 0}, {8, 8, 8}, {1, 1, 0}};
  m.normals = {{0, 0, 1}, {1, 0, 0}, {0, 0, 1}, {0, 0, 1}, {1, 0, 0}, {0, 0, 1}};
  m.triangles = {{0, 2, 3}, {2, 5, 3}};
  m.polygonStarts = {0, 2};
  removeUnreferencedVertices(&m);
  ASSERT_EQ(m.vertices.size(), 4u);
  EXPECT_EQ(m.vertices[2], glm::vec3(0, 1, 0));
  EXPECT_EQ(m.triangles[0], glm::uvec3(0, 1, 2));
  EXPECT_EQ(m.triangles[1], glm::uvec3(1, 3, 2));
  EXPECT_EQ(m.normals.size(), 4u);
  EXPECT_EQ(m.normals[3], glm::vec3(0, 0, 1));
}

TEST(MeshOps, SurfaceOctreeMeshesKeepNoUnusedVertices) {
  const Volume v = test::sphereVolume({24, 22, 20}, 8.3);
  const VolumeOctree t = VolumeOctree::build(v);
  const SurfaceOctree so = SurfaceOctree::build(v, t, 0.0f);
  for (const TriangleMesh& mesh : {fineMeshToTriangles(so.reconstruct(), v.spacing()), fineMeshToTriangles(so.reconstruct(kMaxDim), v.spacing()),
                                   toTriangleMesh(extractDiscMC(v, 0.0f), v.spacing()), extractMarchingCubes(v, 0.0f)}) {
    std::vector<bool> used(mesh.vertices.size(), false);
    for (const glm::uvec3& tr : mesh.triangles)
      for (int k = 0; k < 3; ++k) used[tr[k]] = true;
    EXPECT_EQ(std::count(used.begin(), used.end(), false), 0);
  }
}

TEST(MeshOps, GradientNormalsOfASphereAreRadial) {
  const Volume v = test::sphereVolume({31, 31, 31}, 10.0);  // radius − distance: the gradient points inwards
  TriangleMesh m = toTriangleMesh(extractDiscMC(v, 0.0f), v.spacing());
  setGradientNormals(v, &m);
  ASSERT_EQ(m.normals.size(), m.vertices.size());
  const glm::dvec3 c(15.0);
  double worst = 0;
  for (size_t i = 0; i < m.vertices.size(); ++i) {
    const glm::dvec3 radial = glm::normalize(glm::dvec3(m.vertices[i]) - c);
    worst = std::max(worst, glm::length(glm::dvec3(m.normals[i]) - radial));
  }
  // Central differences of a distance field interpolated: within a few degrees of radial.
  EXPECT_LT(worst, 0.06);
  // A constant field has no gradient: the faces' normal is used.
  const Volume flat = test::makeVolume({4, 4, 4}, [](int i, int, int) { return i < 2 ? 1.0 : -1.0; });
  TriangleMesh f = toTriangleMesh(extractDiscMC(flat, 0.0f), flat.spacing());
  setGradientNormals(test::makeVolume({4, 4, 4}, [](int, int, int) { return 0.0; }), &f);
  for (const glm::vec3& n : f.normals) EXPECT_NEAR(n.x, 1.0f, 1e-6f);
}

TEST(MeshOps, PatientSpaceKeepsTheMeshClosedAndOutward) {
  const Volume v = test::sphereVolume({16, 15, 14}, 5.2);
  TriangleMesh m = toTriangleMesh(extractDiscMC(v, 0.0f), v.spacing());
  setGradientNormals(v, &m);
  const glm::dmat3 las(glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1));
  const PatientFrame frame = makePatientFrame(las, glm::dvec3(100, -50, 3), "t");
  TriangleMesh p = m;
  toPatientSpace(frame, &p);
  EXPECT_EQ(p.vertices[7], glm::vec3(frame.toPatient(glm::dvec3(m.vertices[7]))));
  EXPECT_EQ(p.normals[7], glm::vec3(m.normals[7].x, -m.normals[7].y, m.normals[7].z));
  const MeshCheck c = checkMesh(p);
  EXPECT_TRUE(c.closed);
  EXPECT_TRUE(c.outward);  // the winding was reversed with the mirror
}

}  // namespace
}  // namespace hyb
