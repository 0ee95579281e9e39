#include "surface/mesh_io.h"

#include <algorithm>
#include <bit>
#include <cstring>
#include <fstream>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "surface/dmc.h"
#include "surface/mesh_ops.h"
#include "test_util.h"
#include "volume/core/memory_limit.h"

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

// A face naming a vertex the file does not hold (OpenMesh's importer would drop it without a word)
// refuses the file in one line naming the face and the index; the same files with every index in
// range read whole.
// A vertex that is not finite (OpenMesh's readers drop it, or stop there, quietly) is refused in
// every format, naming it; so is a file whose faces would take more than the memory limit to read.
TEST(MeshIo, AVertexThatIsNotFiniteOrAFileBeyondTheMemoryLimitIsRefusedNamingIt) {
  test::TempDir dir;
  auto said = [&dir](const std::string& name, const std::string& bytes) -> std::string {
    const std::string path = dir.file(name);
    test::writeText(path, bytes);
    try {
      return "read " + std::to_string(readMesh(path).triangles.size()) + " triangles";
    } catch (const IoError& e) {
      const std::string what = e.what();
      return what.rfind(path + ": ", 0) == 0 ? what.substr(path.size() + 2) : "unnamed: " + what;
    }
  };
  const std::string corners[2] = {"0 0 0\n5 0 0\n0 5 0\n0 0 5\n", "0 0 0\n5 0 0\n0 5 0\n0 nan 5\n"};
  const std::string faces = "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";
  EXPECT_EQ(said("t.off", "OFF\n4 4 0\n" + corners[0] + faces), "read 4 triangles");
  EXPECT_EQ(said("n.off", "OFF\n4 4 0\n" + corners[1] + faces), "vertex 3 is not finite (0, nan, 5)");
  EXPECT_EQ(said("i.off", "OFF\n4 4 0\n0 0 0\n5 -inf 0\n0 5 0\n0 0 5\n" + faces), "vertex 1 is not finite (5, -inf, 0)");
  EXPECT_EQ(said("n.obj", "v 0 0 0\nv 5 0 0\nv 0 5 0\nv 0 nan 5\nf 1 3 2\nf 1 2 4\n"), "vertex 3 (line 4) is not finite (0, nan, 5)");
  EXPECT_EQ(said("i.obj", "v 0 0 0\nv +inf 0 0\nv 0 5 0\nf 1 3 2\n"), "vertex 1 (line 2) is not finite (inf, 0, 0)");
  const std::string ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                          "element face 4\nproperty list uchar int vertex_indices\nend_header\n";
  EXPECT_EQ(said("t.ply", ply + corners[0] + faces), "read 4 triangles");
  EXPECT_EQ(said("n.ply", ply + corners[1] + faces), "vertex 3 is not finite (0, nan, 5)");
  // Binary PLY and STL: a NaN float among the corners.
  std::string bply = "ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                     "element face 4\nproperty list uchar int vertex_indices\nend_header\n";
  auto put = [](std::string* b, const auto value) { b->append(reinterpret_cast<const char*>(&value), sizeof value); };
  const float xyz[4][3] = {{0, 0, 0}, {5, 0, 0}, {0, std::nanf(""), 0}, {0, 0, 5}};
  for (const auto& p : xyz)
    for (const float x : p) put(&bply, x);
  for (int k = 0; k < 4; ++k) {
    const int32_t f[4][3] = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    put(&bply, uint8_t(3));
    for (const int32_t i : f[k]) put(&bply, i);
  }
  EXPECT_EQ(said("n_bin.ply", bply), "vertex 2 is not finite (0, nan, 0)");
  // @p facets separate triangles, the last one's third corner at y = @p bad.
  auto stl = [&](uint32_t facets, float bad) {
    std::string b(80, ' ');
    put(&b, facets);
    for (uint32_t k = 0; k < facets; ++k) {
      const float x = 10.0f * float(k), y = k + 1 == facets ? bad : 5.0f;
      for (const float v : {0.0f, 0.0f, 1.0f, x, 0.0f, 0.0f, x + 5.0f, 0.0f, 0.0f, x, y, 0.0f}) put(&b, v);
      put(&b, uint16_t(0));
    }
    return b;
  };
  EXPECT_EQ(said("t.stl", stl(2, 5.0f)), "read 2 triangles");
  EXPECT_EQ(said("n.stl", stl(2, std::numeric_limits<float>::infinity())), "vertex 5 (corner 2 of facet 1) is not finite (10, inf, 0)");
  EXPECT_EQ(said("n_text.stl", "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 5 0 0\nvertex 0 NaN 0\nendloop\nendfacet\nendsolid s\n"),
            "vertex 2 (corner 2 of facet 0) is not finite (0, nan, 0)");
  // Within a memory limit of 1000 bytes, four faces (about 512 bytes to read) are read and eight are not.
  setMemoryLimit(1000);
  EXPECT_EQ(said("t4.off", "OFF\n4 4 0\n" + corners[0] + faces), "read 4 triangles");
  EXPECT_EQ(said("t8.off", "OFF\n4 8 0\n" + corners[0] + faces + faces),
            "its 8 faces need about 1.0 KiB to read, more than the memory limit of 1000 bytes (--memory-limit MB on the command line; by default half the physical memory)");
  EXPECT_THAT(said("t8.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                             "element face 8\nproperty list uchar int vertex_indices\nend_header\n" + corners[0] + faces + faces),
              testing::StartsWith("its 8 faces need"));
  EXPECT_THAT(said("t8.obj", "v 0 0 0\nv 5 0 0\nv 0 5 0\nf 1 2 3\nf 1 2 3\nf 1 2 3\nf 1 2 3\nf 1 2 3\nf 1 2 3\nf 1 2 3\nf 1 2 3\n"),
              testing::StartsWith("its 8 faces need"));
  const std::string big = stl(8, 5.0f);
  EXPECT_THAT(said("t8.stl", big), testing::StartsWith("its 8 faces need"));
  setMemoryLimit(0);
  EXPECT_EQ(said("t8.stl", big), "read 8 triangles");
}

TEST(MeshIo, AFaceNamingAVertexTheFileDoesNotHoldIsRefusedNamingIt) {
  test::TempDir dir;
  // Reads @p name holding @p text: its triangle count, or -1 after checking the one-line message
  // "<path>: <said>" and that nothing was printed.
  auto read = [&dir](const std::string& name, const std::string& text, const std::string& said = "") -> long {
    const std::string path = dir.file(name);
    test::writeText(path, text);
    testing::internal::CaptureStderr();
    testing::internal::CaptureStdout();
    try {
      const size_t triangles = readMesh(path).triangles.size();
      testing::internal::GetCapturedStdout();
      testing::internal::GetCapturedStderr();
      EXPECT_EQ(said, "") << name << " read";
      return long(triangles);
    } catch (const IoError& e) {
      EXPECT_EQ(testing::internal::GetCapturedStdout(), "") << name;
      EXPECT_EQ(testing::internal::GetCapturedStderr(), "") << name;
      EXPECT_EQ(std::string(e.what()), path + ": " + said);
      return -1;
    }
  };
  const std::string tetra = "0 0 0\n5 0 0\n0 5 0\n0 0 5\n";  // four corners, then faces 012, 143... below
  // OFF, and COFF whose vertices and faces carry colours.
  EXPECT_EQ(read("t.off", "OFF\n4 4 0\n" + tetra + "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n"), 4);
  EXPECT_EQ(read("b.off", "OFF\n4 4 0\n" + tetra + "3 0 2 1\n3 0 1 4\n3 0 3 2\n3 1 2 3\n", "face 1 uses vertex 4 (expected indices below 4)"), -1);
  EXPECT_EQ(read("n.off", "OFF\n4 4 0\n" + tetra + "3 0 2 1\n3 0 1 3\n3 0 3 -1\n3 1 2 3\n", "face 2 uses vertex -1 (expected indices below 4)"), -1);
  const std::string coff = "COFF\n4 4 0\n0 0 0 255 0 0 255\n5 0 0 0 255 0 255\n0 5 0 0 0 255 255\n0 0 5 9 9 9 255\n";
  EXPECT_EQ(read("t.coff.off", coff + "3 0 2 1 1 0 0\n3 0 1 3 1 0 0\n3 0 3 2 1 0 0\n3 1 2 3 1 0 0\n"), 4);
  EXPECT_EQ(read("b.coff.off", coff + "3 0 2 1 1 0 0\n3 0 1 3 1 0 0\n3 0 3 2 1 0 0\n3 1 2 30 1 0 0\n", "face 3 uses vertex 30 (expected indices below 4)"), -1);
  // OBJ: indices from 1 over the whole file (a face may name a vertex defined below it), or counted
  // back from the last vertex above the face; texture and normal references after '/'.
  const std::string obj = "# SPACE=LPS\nv 0 0 0\nv 5 0 0\nv 0 5 0\nf 1 3 2\nf 2 3 4\nv 0 0 5\nvn 0 0 1\n";
  EXPECT_EQ(read("t.obj", obj + "f -4 -3 -1\nf 1//1 4//1 3//1\n"), 4);
  EXPECT_EQ(read("b.obj", obj + "f -4 -3 -1\nf 1//1 5//1 3//1\n",
                 "face 3 (line 10) uses vertex 5 (expected 1 to 4, or -1 to -4 counting back from the last vertex above it)"), -1);
  EXPECT_EQ(read("n.obj", "v 0 0 0\nv 5 0 0\nv 0 5 0\nf -1 -2 -4\nv 0 0 5\nf 1 2 4\n",
                 "face 0 (line 4) uses vertex -4 (expected 1 to 4, or -1 to -3 counting back from the last vertex above it)"), -1);
  EXPECT_EQ(read("z.obj", "f 0 1 2\nv 0 0 0\nv 5 0 0\nv 0 5 0\n", "face 0 (line 1) uses vertex 0 (expected 1 to 3)"), -1);
  // A "v" line without three numbers adds no vertex (OpenMesh, given the face's normal, would write
  // it past the end of its vertices).
  EXPECT_EQ(read("s.obj", "v 0 0 0\nv 5 0 0\nv 0 5\nv 0 0 5\nvn 0 0 1\nf 1//1 2//1 4//1\n",
                 "face 0 (line 6) uses vertex 4 (expected 1 to 3, or -1 to -4 counting back from the last vertex above it)"), -1);
  // PLY, ASCII.
  const std::string ply = "ply\nformat ascii 1.0\ncomment SPACE=LPS\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                          "element face 4\nproperty list uchar int vertex_indices\nend_header\n" + tetra;
  EXPECT_EQ(read("t.ply", ply + "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n"), 4);
  EXPECT_EQ(read("b.ply", ply + "3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 312\n", "face 3 uses vertex 312 (expected indices below 4)"), -1);
  EXPECT_EQ(read("n.ply", ply + "3 0 2 1\n3 -7 1 3\n3 0 3 2\n3 1 2 3\n", "face 1 uses vertex -7 (expected indices below 4)"), -1);
  // A header declaring more rows than the file has bytes (OpenMesh would reserve or step through them).
  EXPECT_EQ(read("h.off", "OFF\n999999999999999 2 0\n0 0 0\n", "the header declares 999999999999999 vertices (expected at most the file's 30 bytes)"), -1);
  EXPECT_EQ(read("h.ply", "ply\nformat ascii 1.0\nelement junk 999999999999\nend_header\n",
                 "the header declares 999999999999 'junk' rows (expected at most the file's 58 bytes)"), -1);
  // PLY, binary in either byte order, with a colour on each vertex, a flag on each face and an edge
  // element after the faces: every property is stepped over by its type.
  for (const bool big : {false, true}) {
    auto binary = [big](int badIndex) {
      std::string b = std::string("ply\nformat ") + (big ? "binary_big_endian" : "binary_little_endian") +
                      " 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\n"
                      "element face 4\nproperty list uchar int vertex_indices\nproperty ushort flags\n"
                      "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n";
      auto put = [&b, big](const auto value) {
        char bytes[sizeof value];
        std::memcpy(bytes, &value, sizeof value);
        if (big != (std::endian::native == std::endian::big)) std::reverse(bytes, bytes + sizeof value);
        b.append(bytes, sizeof value);
      };
      const float corners[4][3] = {{0, 0, 0}, {5, 0, 0}, {0, 5, 0}, {0, 0, 5}};
      for (const auto& c : corners) {
        for (const float x : c) put(x);
        put(uint8_t(200));
      }
      const int32_t faces[4][3] = {{0, 2, 1}, {0, 1, 3}, {0, 3, badIndex}, {1, 2, 3}};
      for (const auto& f : faces) {
        put(uint8_t(3));
        for (const int32_t i : f) put(i);
        put(uint16_t(0xffff));
      }
      put(int32_t(0));
      put(int32_t(1));
      return b;
    };
    EXPECT_EQ(read(big ? "tb.ply" : "tl.ply", binary(2)), 4);
    EXPECT_EQ(read(big ? "bb.ply" : "bl.ply", binary(1000), "face 2 uses vertex 1000 (expected indices below 4)"), -1);
  }
}

}  // namespace
}  // namespace hyb
