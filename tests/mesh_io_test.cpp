#include "surface/mesh_io.h"

#include <fstream>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "surface/dmc.h"
#include "surface/mesh_ops.h"
#include "test_util.h"

namespace hyb {
namespace {

TEST(MeshIo, RoundTripEveryFormat) {
  test::TempDir dir;
  const Volume v = test::sphereVolume(glm::ivec3(15), 5.2);
  const TriangleMesh mesh = toTriangleMesh(extractDiscMC(v, 0.0f), glm::dvec3(0.5, 0.75, 1.25));
  ASSERT_GT(mesh.triangles.size(), size_t(100));
  for (const char* ext : {".ply", ".obj", ".stl", ".off"}) {
    const std::string path = dir.file(std::string("sphere") + ext);
    writeMesh(path, mesh);
    const TriangleMesh back = readMesh(path);
    EXPECT_EQ(back.triangles.size(), mesh.triangles.size()) << ext;
    EXPECT_EQ(back.vertices.size(), mesh.vertices.size()) << ext;
    // Millimetres: the extent along z is the sphere's diameter at 1.25 mm a voxel, within a cell.
    float zmin = 1e9f, zmax = -1e9f;
    for (const glm::vec3& p : back.vertices) {
      zmin = std::min(zmin, p.z);
      zmax = std::max(zmax, p.z);
    }
    EXPECT_NEAR(zmax - zmin, 2 * 5.2 * 1.25, 1.25) << ext;
  }
}

TEST(MeshIo, EmptyMeshesWriteValidFiles) {
  test::TempDir dir;
  for (const char* ext : {".ply", ".obj", ".stl", ".off"}) {
    const std::string path = dir.file(std::string("empty") + ext);
    writeMesh(path, TriangleMesh{});
    ASSERT_TRUE(std::filesystem::exists(path)) << ext;
    const TriangleMesh back = readMesh(path);
    EXPECT_EQ(back.triangles.size(), size_t(0)) << ext;
  }
}

// Classic marching cubes can put more than two triangles on one edge, which OpenMesh's half-edge
// structure rejects: every triangle is still written (with vertices of its own, at the right
// places), and quietly. (The copies once read points being moved by the copying: garbage.)
TEST(MeshIo, NonManifoldTrianglesAreWrittenWholeWithoutWarnings) {
  test::TempDir dir;
  TriangleMesh book;  // three pages on the spine (0,0,0)-(0,0,1)
  book.vertices = {{0, 0, 0}, {0, 0, 1}, {1, 0, 0}, {0, 1, 0}, {-1, -1, 0}};
  book.triangles = {{0, 1, 2}, {0, 1, 3}, {0, 1, 4}};
  const std::string path = dir.file("book.ply");
  testing::internal::CaptureStderr();
  testing::internal::CaptureStdout();
  writeMesh(path, book);
  EXPECT_EQ(testing::internal::GetCapturedStdout(), "");
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
  const TriangleMesh back = readMesh(path);
  ASSERT_EQ(back.triangles.size(), size_t(3));
  for (size_t i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) EXPECT_EQ(back.vertices[back.triangles[i][k]], book.vertices[book.triangles[i][k]]) << i << " " << k;
}

TEST(MeshIo, NormalsAndTheCoordinateSpaceAreRecorded) {
  test::TempDir dir;
  const Volume v = test::sphereVolume(glm::ivec3(13), 4.2);
  TriangleMesh mesh = toTriangleMesh(extractDiscMC(v, 0.0f), v.spacing());
  setGradientNormals(v, &mesh);
  for (const char* ext : {".ply", ".obj"}) {
    const std::string path = dir.file(std::string("n") + ext);
    writeMesh(path, mesh, MeshWriteOptions{true, "LPS"});
    const TriangleMesh back = readMesh(path);
    ASSERT_EQ(back.normals.size(), mesh.normals.size()) << ext;
    for (size_t i = 0; i < mesh.normals.size(); i += 17) EXPECT_LT(glm::length(back.normals[i] - mesh.normals[i]), 1e-5f) << ext;
    const std::string text = test::readText(path).substr(0, 200);
    EXPECT_NE(text.find(std::string(ext) == ".ply" ? "comment SPACE=LPS\n" : "# SPACE=LPS\n"), std::string::npos) << text;
  }
  writeMesh(dir.file("s.stl"), mesh, MeshWriteOptions{false, "LPS"});
  EXPECT_EQ(test::readText(dir.file("s.stl")).substr(0, 23), "hybrid-octree SPACE=LPS");
  EXPECT_EQ(readMesh(dir.file("s.stl")).triangles.size(), mesh.triangles.size());
  EXPECT_THROW(writeMesh(dir.file("n.stl"), mesh, MeshWriteOptions{true, ""}), IoError);
  EXPECT_THROW(writeMesh(dir.file("n.off"), mesh, MeshWriteOptions{true, ""}), IoError);
}

TEST(MeshIo, RejectsUnknownFormatsAndUnwritablePaths) {
  test::TempDir dir;
  TriangleMesh one;
  one.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  one.triangles = {{0, 1, 2}};
  EXPECT_THROW(writeMesh(dir.file("m.vtk"), one), IoError);
  EXPECT_THROW(writeMesh(dir.file("no/dir/m.ply"), one), IoError);
  EXPECT_THROW(readMesh(dir.file("absent.ply")), IoError);
  size_t files = 0;
  for (const auto& e : std::filesystem::recursive_directory_iterator(dir.path())) files += e.is_regular_file();
  EXPECT_EQ(files, size_t(0));  // nothing half-written
}

// One table of the formats: what export, the viewer's download and Python accept, and the bytes
// a download sends are the file writeMesh writes.
TEST(MeshIo, OneTableOfFormatsAndItsBytesAreTheFiles) {
  EXPECT_EQ(meshFormats().size(), size_t(4));
  EXPECT_EQ(meshExtensionsText(), ".ply, .obj, .stl or .off");
  EXPECT_EQ(meshExtensionsText(true), ".ply or .obj");
  EXPECT_EQ(meshExtensionsText(false, false), "ply, obj, stl or off");
  EXPECT_EQ(meshFormatOf("m.vtk"), nullptr);
  EXPECT_EQ(meshFormatOf("m"), nullptr);
  ASSERT_NE(meshFormatOf("dir.x/m.stl"), nullptr);
  EXPECT_EQ(meshFormatOf("dir.x/m.stl")->extension, ".stl");
  test::TempDir dir;
  const Volume v = test::sphereVolume(glm::ivec3(9), 3.2);
  const TriangleMesh mesh = toTriangleMesh(extractDiscMC(v, 0.0f), v.spacing());
  for (const MeshFormat& f : meshFormats()) {
    const std::string path = dir.file("m" + f.extension);
    writeMesh(path, mesh, MeshWriteOptions{false, "LPS"});
    std::ifstream in(path, std::ios::binary);
    const std::string file((std::istreambuf_iterator<char>(in)), {});
    EXPECT_EQ(meshBytes(mesh, f, MeshWriteOptions{false, "LPS"}), file) << f.extension;
    EXPECT_EQ(meshBytes(TriangleMesh{}, f).empty(), false) << f.extension;
    if (!f.normals) {
      EXPECT_THROW(meshBytes(mesh, f, MeshWriteOptions{true, ""}), IoError) << f.extension;
    }
  }
}

}  // namespace
}  // namespace hyb
