// User meshes drawn exactly in both renderers (render/user_meshes.h, docs/user-geometry.md).
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <numbers>

#include "cli_util.h"
#include "render/scene_renderer.h"
#include "render/user_meshes.h"
#include "surface/scan_convert.h"
#include "render_util.h"
#include "surface/mesh_io.h"
#include "test_util.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;


UserMesh userMesh(TriangleMesh mesh, const glm::vec4& color, const std::string& name = "mesh") {
  return UserMesh{name, std::make_shared<const TriangleMesh>(std::move(mesh)), color, nullptr};
}

TransferFunction warm() { return TransferFunction({{0.0f, {1, 1, 1}, 0.0f}, {2.0f, {1.0f, 0.6f, 0.3f}, 0.3f}, {15.0f, {0.3f, 0.6f, 1.0f}, 0.05f}}, "warm"); }

// The analytic sphere (value 13 − r, 40 × 36 × 32 voxels of 1 mm) with its translucent isosurface
// of radius 8 (value 5), a translucent sphere crossing it and an oblique translucent plate
// crossing both and the volume's slices.
Look meshLook() {
  Look look;
  look.tf = warm();
  look.iso = 5.0f;
  look.surfaceColor = glm::vec4(0.9f, 0.9f, 0.9f, 0.5f);
  look.meshes.push_back(userMesh(uvSphere({26.0, 19.0, 17.5}, 6.5, 24), glm::vec4(1.0f, 0.2f, 0.2f, 0.45f), "ball"));
  TriangleMesh plate;
  plate.vertices = {{3.0f, 4.0f, 9.0f}, {36.0f, 4.0f, 19.0f}, {36.0f, 31.0f, 22.0f}, {3.0f, 31.0f, 12.0f}};
  plate.triangles = {{0, 1, 2}, {0, 2, 3}};
  look.meshes.push_back(userMesh(plate, glm::vec4(0.2f, 0.9f, 0.3f, 0.35f), "plate"));
  return look;
}

View obliqueView(int pixels = 128) {
  View view;
  view.camera = test::perspective({-30.0, -45.0, 50.0}, {19.5, 17.5, 15.5}, {0, 0, 1}, 30.0, pixels);
  return view;
}

// Pixels (composited over black, 8 bits) that differ between two images by more than 2/255.
size_t differingPixels(const Image& a, const Image& b) {
  const std::vector<uint8_t> x = toRgba8(a, glm::vec3(0)), y = toRgba8(b, glm::vec3(0));
  size_t n = 0;
  for (size_t p = 0; p < x.size(); p += 4)
    for (size_t c = 0; c < 3; ++c)
      if (std::abs(int(x[p + c]) - int(y[p + c])) > 2) {
        ++n;
        break;
      }
  return n;
}

TEST(UserMesh, PolygonsMatchTheReferenceWhereMeshesCrossTheSurfaceAndTheSlices) {
  SceneRenderer r(test::sphereScene());
  const View view = obliqueView();
  const Look look = meshLook();
  Quality reference;
  reference.renderer = Renderer::Raycast;
  const RenderedFrame slices = r.render(view, look, Quality{});
  const RenderedFrame rays = r.render(view, look, reference);
  const double db = test::psnrOf(slices.image, rays.image);
  std::printf("user meshes, slices against the reference: %.2f dB\n", db);
  EXPECT_GE(db, 40.0);
  // The meshes are drawn: without them both images change over thousands of pixels, and the
  // slices' triangles drawn are the pieces of the meshes' (cut at the leaf cells) and the surface's.
  Look without = look;
  without.meshes.clear();
  const RenderedFrame plainSlices = r.render(view, without, Quality{});
  EXPECT_GT(differingPixels(slices.image, plainSlices.image), 2000u);
  EXPECT_GT(differingPixels(rays.image, r.render(view, without, reference).image), 2000u);
  EXPECT_GT(slices.stats.slices.surfaceTriangles, plainSlices.stats.slices.surfaceTriangles + uvSphere({}, 1.0, 24).triangles.size());
  EXPECT_EQ(slices.stats.meshTriangles, uvSphere({}, 1.0, 24).triangles.size() + 2);
  // Opaque meshes with an opaque surface: the same agreement.
  Look opaque = look;
  opaque.surfaceColor.a = 1.0f;
  for (UserMesh& m : opaque.meshes) m.color.a = 1.0f;
  const double opaqueDb = test::psnrOf(r.render(view, opaque, Quality{}).image, r.render(view, opaque, reference).image);
  std::printf("opaque: %.2f dB\n", opaqueDb);
  EXPECT_GE(opaqueDb, 40.0);
}

TEST(UserMesh, ASlicerRasFileLandsWhereItsLpsTwinDoes) {
  test::TempDir dir;
  const TriangleMesh lps = uvSphere({22.0, 15.0, 14.0}, 5.0, 12);
  TriangleMesh ras = lps;
  for (glm::vec3& p : ras.vertices) p = glm::vec3(-p.x, -p.y, p.z);
  writeMesh(dir.file("lps.ply"), lps, {.space = "LPS"});
  writeMesh(dir.file("ras.stl"), ras, {.space = "RAS"});
  writeMesh(dir.file("ras.obj"), ras, {.space = "RAS"});
  writeMesh(dir.file("plain.obj"), ras);  // no header: --mesh-space ras says it
  EXPECT_EQ(meshFileSpace(dir.file("ras.stl")), MeshSpace::RAS);
  EXPECT_EQ(meshFileSpace(dir.file("ras.obj")), MeshSpace::RAS);
  EXPECT_EQ(meshFileSpace(dir.file("lps.ply")), MeshSpace::LPS);
  EXPECT_EQ(meshFileSpace(dir.file("plain.obj")), std::nullopt);
  const glm::vec4 color(1.0f, 0.3f, 0.2f, 0.5f);
  const UserMesh twin = readUserMesh(dir.file("lps.ply"), color, MeshSpace::RAS);  // its header wins
  SceneRenderer r(test::sphereScene());
  Look look;
  look.tf = warm();
  look.meshes = {twin};
  const View view = obliqueView(64);
  const std::vector<uint8_t> want = toRgba8(r.render(view, look, Quality{}).image, glm::vec3(0));
  for (const auto& [file, space] : {std::pair{"ras.stl", MeshSpace::LPS}, {"ras.obj", MeshSpace::LPS}, {"plain.obj", MeshSpace::RAS}}) {
    SCOPED_TRACE(file);
    const UserMesh m = readUserMesh(dir.file(file), color, space);
    // (An STL is a soup of triangles: its reader merges the sphere's repeated pole vertices.)
    ASSERT_EQ(m.mesh->triangles.size(), twin.mesh->triangles.size());
    float worst = 0.0f;
    for (size_t t = 0; t < m.mesh->triangles.size(); ++t)
      for (int k = 0; k < 3; ++k)
        worst = std::max(worst, glm::length(m.mesh->vertices[m.mesh->triangles[t][k]] - twin.mesh->vertices[twin.mesh->triangles[t][k]]));
    EXPECT_LT(worst, 1e-5f);
    look.meshes = {m};
    EXPECT_EQ(toRgba8(r.render(view, look, Quality{}).image, glm::vec3(0)), want);
  }
}

TEST(UserMesh, BadMeshesAreRefusedWithOneLineNamingTheFile) {
  test::TempDir dir;
  auto refused = [](const std::function<void()>& f) -> std::string {
    try {
      f();
    } catch (const Error& e) {
      return e.what();
    }
    return "accepted";
  };
  const glm::vec4 c(1.0f);
  writeMesh(dir.file("empty.ply"), TriangleMesh{});
  EXPECT_EQ(refused([&] { readUserMesh(dir.file("empty.ply"), c, MeshSpace::LPS); }), dir.file("empty.ply") + ": the mesh has no triangles");
  EXPECT_EQ(refused([&] { readUserMesh(dir.file("none.stl"), c, MeshSpace::LPS); }), dir.file("none.stl") + ": file does not exist");
  std::ofstream(dir.file("mesh.xyz")) << "1 2 3\n";
  EXPECT_THAT(refused([&] { readUserMesh(dir.file("mesh.xyz"), c, MeshSpace::LPS); }),
              HasSubstr(dir.file("mesh.xyz") + ": not a mesh file (expected .ply, .obj, .stl or .off)"));
  std::ofstream(dir.file("junk.ply")) << "not a ply at all\n";
  EXPECT_THAT(refused([&] { readUserMesh(dir.file("junk.ply"), c, MeshSpace::LPS); }), HasSubstr(dir.file("junk.ply") + ": "));
  TriangleMesh nan = uvSphere({10, 10, 10}, 3, 4);
  nan.vertices[5].y = std::nanf("");
  EXPECT_THAT(refused([&] { checkUserMesh(nan, "nan.ply"); }), HasSubstr("nan.ply: vertex 5 is not finite"));
  TriangleMesh outOfRange = uvSphere({10, 10, 10}, 3, 4);
  outOfRange.triangles[7].z = 1000;
  EXPECT_EQ(refused([&] { checkUserMesh(outOfRange, "bad.off"); }),
            "bad.off: triangle 7 uses vertex 1000 (expected indices below " + std::to_string(outOfRange.vertices.size()) + ")");
  // In a file, an index out of range is refused by the reader, naming the file and the face.
  std::ofstream(dir.file("bad.off")) << "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
  EXPECT_EQ(refused([&] { readUserMesh(dir.file("bad.off"), c, MeshSpace::LPS); }),
            dir.file("bad.off") + ": face 0 uses vertex 7 (expected indices below 3)");

  // Odd but drawable: wholly outside the volume, a thousand times too small, or non-manifold.
  const Volume v = test::sphereVolume({40, 36, 32}, 13.0);
  EXPECT_TRUE(userMeshWarnings(userMesh(uvSphere({20, 18, 16}, 5, 6), c, "inside.stl"), v).empty());
  const std::vector<std::string> far = userMeshWarnings(userMesh(uvSphere({200, 18, 16}, 5, 6), c, "far.stl"), v);
  ASSERT_EQ(far.size(), 1u);
  EXPECT_EQ(far[0], "far.stl: the mesh lies wholly outside the volume's box (drawn where it is visible)");
  // A ball of 36 mm written in metres, and one of 0.8 mm: under one voxel (1 mm) both.
  for (const double radius : {0.018, 0.4}) {
    const std::vector<std::string> tiny = userMeshWarnings(userMesh(uvSphere({0.020, 0.018, 0.016}, radius, 6), c, "metres.stl"), v);
    ASSERT_EQ(tiny.size(), 1u) << radius;
    EXPECT_THAT(tiny[0], HasSubstr("metres.stl: the mesh spans 0."));
    EXPECT_THAT(tiny[0], HasSubstr("less than one voxel (1 mm): in metres? (expected millimetres)"));
  }
  EXPECT_TRUE(userMeshWarnings(userMesh(uvSphere({20, 18, 16}, 0.6, 6), c, "bead.stl"), v).empty());  // 1.2 mm
  // Two fins on one edge of a closed ball, one on another: two edges of three or four triangles.
  TriangleMesh finned = uvSphere({20, 18, 16}, 5, 6);
  EXPECT_EQ(nonManifoldEdges(finned), 0u);
  const glm::uvec3 t = finned.triangles[3], u = finned.triangles[finned.triangles.size() / 2];
  for (const glm::uvec3& edge : {t, t, u}) {
    finned.vertices.push_back({30.0f, 18.0f + float(finned.vertices.size() % 3), 16.0f});
    finned.triangles.push_back({edge.x, edge.y, uint32_t(finned.vertices.size() - 1)});
  }
  EXPECT_EQ(nonManifoldEdges(finned), 2u);
  const std::vector<std::string> fins = userMeshWarnings(userMesh(finned, c, "fins.off"), v);
  ASSERT_EQ(fins.size(), 1u);
  EXPECT_EQ(fins[0], "fins.off: 2 edges are shared by more than two triangles (non-manifold): drawn as given, but a solid label volume's inside may be wrong there");
  // Read from a file: three triangles on one edge (the reader gives the third vertices of its own).
  std::ofstream(dir.file("fan.off")) << "OFF\n5 3 0\n10 10 10\n20 10 10\n15 20 10\n15 0 10\n15 10 20\n3 0 1 2\n3 0 1 3\n3 0 1 4\n";
  const std::vector<std::string> fan = userMeshWarnings(readUserMesh(dir.file("fan.off"), c, MeshSpace::LPS), v);
  ASSERT_EQ(fan.size(), 1u);
  EXPECT_THAT(fan[0], HasSubstr("fan.off: 1 edge is shared by more than two triangles (non-manifold)"));
}

TEST(UserMesh, RenderDrawsTheMeshFilesGivenAndRefusesBadOnes) {
  test::TempDir dir;
  writeNrrd(test::sphereVolume({40, 36, 32}, 13.0), dir.file("ball.nrrd"));
  writeMesh(dir.file("ball.stl"), uvSphere({26.0, 19.0, 17.5}, 6.5, 16));
  const std::vector<std::string> common = {"render", dir.file("ball.nrrd"), "--eye", "-30,-45,50", "--center", "19.5,17.5,15.5", "--size", "96x96"};
  auto render = [&](std::vector<std::string> extra, const std::string& png) {
    std::vector<std::string> args = common;
    args.insert(args.end(), extra.begin(), extra.end());
    args.insert(args.end(), {"-o", dir.file(png)});
    const test::CliRun r = test::run(args);
    EXPECT_EQ(r.status, 0) << r.err;
    int w = 0, h = 0;
    return readPng(dir.file(png), &w, &h);
  };
  const std::vector<uint8_t> plain = render({}, "plain.png");
  const std::vector<uint8_t> red = render({"--mesh", dir.file("ball.stl") + ":1,0,0,0.6"}, "red.png");
  // Repeated: the second mesh (the same file in green) drawn over the first.
  const std::vector<uint8_t> both = render({"--mesh", dir.file("ball.stl") + ":1,0,0,0.6", "--mesh", dir.file("ball.stl") + ":0,1,0,0.6"}, "both.png");
  ASSERT_EQ(plain.size(), red.size());
  // Where the mesh is (the image's centre column about the ball) the pixels are redder; elsewhere equal.
  size_t redder = 0, changed = 0;
  for (size_t p = 0; p < plain.size(); p += 4) {
    changed += plain[p] != red[p] || plain[p + 1] != red[p + 1] || plain[p + 2] != red[p + 2];
    redder += int(red[p]) - int(red[p + 1]) > int(plain[p]) - int(plain[p + 1]) + 20;
  }
  EXPECT_GT(redder, 300u);
  EXPECT_LT(changed, plain.size() / 4 / 2);  // the ball covers less than half the image
  size_t greener = 0;
  for (size_t p = 0; p < plain.size(); p += 4) greener += both[p + 1] > red[p + 1] + 20;
  EXPECT_GT(greener, 300u);
  // Bad input: one line naming the flag or the file.
  test::expectBadInput({"render", dir.file("ball.nrrd"), "--mesh", dir.file("ball.stl") + ":1,0,0", "-o", dir.file("x.png")}, "--mesh");
  test::expectBadInput({"render", dir.file("ball.nrrd"), "--mesh", dir.file("missing.ply"), "-o", dir.file("x.png")}, dir.file("missing.ply"));
  test::expectBadInput({"render", dir.file("ball.nrrd"), "--mesh-space", "xyz", "-o", dir.file("x.png")}, "--mesh-space");
  // Far outside: a warning, and the frame is rendered.
  writeMesh(dir.file("far.ply"), uvSphere({500.0, 0.0, 0.0}, 5.0, 6));
  const test::CliRun far = test::run({"render", dir.file("ball.nrrd"), "--mesh", dir.file("far.ply"), "-o", dir.file("far.png")});
  EXPECT_EQ(far.status, 0) << far.err;
  EXPECT_THAT(far.err, HasSubstr("warning: " + dir.file("far.ply") + ": the mesh lies wholly outside the volume's box"));
  // Exported as a label volume: the same one warning (the scan-conversion does not repeat it).
  const test::CliRun label = test::run({"export", dir.file("ball.nrrd"), "--mesh", dir.file("far.ply"), "--label-volume", dir.file("far.nrrd")});
  EXPECT_EQ(label.status, 0) << label.err;
  size_t warnings = 0;
  for (size_t at = label.err.find("warning:"); at != std::string::npos; at = label.err.find("warning:", at + 1)) ++warnings;
  EXPECT_EQ(warnings, 1u) << label.err;
  EXPECT_THAT(label.err, HasSubstr("warning: " + dir.file("far.ply") + ": the mesh lies wholly outside the volume's box"));
}

}  // namespace
}  // namespace hyb
