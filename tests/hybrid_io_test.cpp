#include "hybrid_octree/hybrid_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <zlib.h>

#include <cmath>
#include <cstring>

#include "test_util.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;

void expectLoadFails(const std::string& path, const std::string& what) {
  try {
    loadScene(path);
    ADD_FAILURE() << "loaded " << path;
  } catch (const IoError& e) {
    EXPECT_THAT(e.what(), HasSubstr(path));
    EXPECT_THAT(e.what(), HasSubstr(what));
  }
}

TEST(SceneFile, RoundTripIsExact) {
  test::TempDir dir;
  const Volume v = test::randomVolume({33, 20, 9}, 3);
  const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{4});
  saveScene(dir.file("s.hoct"), v, t);
  EXPECT_TRUE(isSceneFile(dir.file("s.hoct")));
  const Scene s = loadScene(dir.file("s.hoct"));
  EXPECT_EQ(s.volume.dims(), v.dims());
  EXPECT_EQ(s.volume.spacing(), v.spacing());
  EXPECT_EQ(s.volume.samples(), v.samples());
  EXPECT_EQ(s.octree.leafEdge(), 4);
  ASSERT_EQ(s.octree.nodes().size(), t.nodes().size());
  EXPECT_EQ(std::memcmp(s.octree.nodes().data(), t.nodes().data(), t.nodes().size() * sizeof(OctreeNode)), 0);
  EXPECT_EQ(s.octree.errorData(), t.errorData());
}

TEST(SceneFile, KnotModeRoundTrips) {
  test::TempDir dir;
  const Volume v = test::randomVolume({33, 20, 9}, 5);
  for (const bool prefilter : {true, false}) {
    const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{8, prefilter});
    saveScene(dir.file("s.hoct"), v, t);
    const Scene s = loadScene(dir.file("s.hoct"));
    EXPECT_EQ(s.octree.prefiltered(), prefilter);
    EXPECT_EQ(s.octree.errorData(), t.errorData());
    for (const glm::ivec3 knot : {glm::ivec3(0, 0, 0), glm::ivec3(8, 16, 8), glm::ivec3(32, 19, 8)})
      EXPECT_EQ(s.octree.knotValue(s.volume, 8, knot), t.knotValue(v, 8, knot));
  }
}

TEST(SceneFile, PatientFrameAndInfoRoundTripAndOlderVersionsAreRefused) {
  test::TempDir dir;
  Volume v = test::randomVolume({9, 8, 7}, 11);
  const double c = std::cos(0.3), s = std::sin(0.3);
  v.setFrame(makePatientFrame(glm::dmat3(glm::dvec3(c, s, 0), glm::dvec3(0, 0, -1), glm::dvec3(-s, c, 0)), glm::dvec3(-12.5, 40, 3), "t"));
  v.addInfo("modality", "CT");
  v.addInfo("series", "'1.2.3' (CT, head)");
  saveScene(dir.file("s.hoct"), v, VolumeOctree::build(v));
  const Scene loaded = loadScene(dir.file("s.hoct"));
  EXPECT_EQ(loaded.volume.frame(), v.frame());
  EXPECT_EQ(loaded.volume.info(), v.info());
  // Versions 1 and 2 knew no patient frame: refused, with what to do.
  std::vector<uint8_t> bytes = test::readBytes(dir.file("s.hoct"));
  for (uint32_t version : {1u, 2u}) {
    std::memcpy(&bytes[8], &version, 4);
    test::writeBytes(dir.file("old.hoct"), bytes);
    expectLoadFails(dir.file("old.hoct"), "version " + std::to_string(version) + " has no patient orientation");
    expectLoadFails(dir.file("old.hoct"), "hybrid-octree build");
  }
}

TEST(SceneFile, SurfaceOctreeRoundTrip) {
  test::TempDir dir;
  const Volume v = test::sphereVolume(glm::ivec3(21, 19, 17), 7.3);
  const VolumeOctree t = VolumeOctree::build(v);
  const SurfaceOctree so = SurfaceOctree::build(v, t, 0.0f);
  saveScene(dir.file("s.hoct"), v, t, &so);
  const Scene s = loadScene(dir.file("s.hoct"));
  ASSERT_TRUE(s.surface.has_value());
  EXPECT_EQ(s.surface->isovalue(), 0.0f);
  EXPECT_EQ(s.surface->cellCount(), so.cellCount());
  ASSERT_EQ(s.surface->nodes().size(), so.nodes().size());
  EXPECT_EQ(std::memcmp(s.surface->nodes().data(), so.nodes().data(), so.nodes().size() * sizeof(SurfaceNode)), 0);
  EXPECT_EQ(s.surface->reconstruct().indices, so.reconstruct().indices);
  // A scene without a surface loads without one.
  saveScene(dir.file("v.hoct"), v, t);
  EXPECT_FALSE(loadScene(dir.file("v.hoct")).surface.has_value());
  // A node pointing outside the grid is rejected.
  auto nodes = so.nodes();
  nodes.back().origin = glm::u16vec3(60000);
  EXPECT_THROW(SurfaceOctree::fromParts(v.dims(), 0.0f, so.cellCount(), so.mergeEdge(), nodes, "x"), IoError);
  EXPECT_THROW(SurfaceOctree::fromParts(v.dims(), 0.0f, so.cellCount(), 3, so.nodes(), "x"), IoError);
}

TEST(SceneFile, RejectsForeignTruncatedCorruptAndNewer) {
  test::TempDir dir;
  const Volume v = test::randomVolume({17, 9, 5}, 4);
  saveScene(dir.file("s.hoct"), v, VolumeOctree::build(v));
  const std::vector<uint8_t> good = test::readBytes(dir.file("s.hoct"));

  test::writeText(dir.file("foreign.hoct"), "NRRD0004\nnot a scene at all");
  expectLoadFails(dir.file("foreign.hoct"), "not a hybrid-octree scene file");
  EXPECT_FALSE(isSceneFile(dir.file("foreign.hoct")));

  for (size_t cut : {size_t(10), size_t(20), good.size() / 3, good.size() - 1}) {
    test::writeBytes(dir.file("cut.hoct"), std::vector<uint8_t>(good.begin(), good.begin() + ptrdiff_t(cut)));
    expectLoadFails(dir.file("cut.hoct"), cut < 16 ? "not a hybrid-octree scene file" : "truncated");
  }
  std::vector<uint8_t> corrupt = good;
  corrupt[good.size() / 2] ^= 0x40;
  test::writeBytes(dir.file("corrupt.hoct"), corrupt);
  expectLoadFails(dir.file("corrupt.hoct"), "checksum mismatch");

  std::vector<uint8_t> newer = good;
  newer[8] = uint8_t(kSceneVersion + 1);
  test::writeBytes(dir.file("newer.hoct"), newer);
  expectLoadFails(dir.file("newer.hoct"), "version " + std::to_string(kSceneVersion + 1) + " unsupported");
}

TEST(SceneFile, FromPartsRejectsInconsistentOctrees) {
  const Volume v = test::randomVolume({17, 9, 5}, 4);
  const VolumeOctree t = VolumeOctree::build(v);
  auto nodes = t.nodes();
  auto errors = t.errorData();
  EXPECT_NO_THROW(VolumeOctree::fromParts(v.dims(), 8, nodes, errors, "x"));
  EXPECT_THROW(VolumeOctree::fromParts({18, 9, 5}, 8, nodes, errors, "x"), IoError);  // other grid, other shape
  EXPECT_THROW(VolumeOctree::fromParts(v.dims(), 4, nodes, errors, "x"), IoError);
  auto badChild = nodes;
  badChild[0].firstChild = 1000;
  EXPECT_THROW(VolumeOctree::fromParts(v.dims(), 8, badChild, errors, "x"), IoError);
  auto badRange = nodes;
  badRange[1].minValue = badRange[1].maxValue + 1;
  EXPECT_THROW(VolumeOctree::fromParts(v.dims(), 8, badRange, errors, "x"), IoError);
  auto badError = errors;
  badError[3] = -1.0f;
  EXPECT_THROW(VolumeOctree::fromParts(v.dims(), 8, nodes, badError, "x"), IoError);
  badError.pop_back();
  EXPECT_THROW(VolumeOctree::fromParts(v.dims(), 8, nodes, badError, "x"), IoError);
}

}  // namespace
}  // namespace hyb
