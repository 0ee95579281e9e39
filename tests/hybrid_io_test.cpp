#include "hybrid_octree/hybrid_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <zlib.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <optional>
#include <random>

#include "test_util.h"
#include "volume/plane_source.h"
#include "volume/volume_io.h"

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
  EXPECT_TRUE(std::ranges::equal(s.octree.errorData(), t.errorData()));
}

// A scene built from a file read plane by plane (two passes, a few planes held at a time, the
// store's blocks waiting in a temporary file) is, byte for byte, the scene of the volume read whole:
// for leaf edges 1 to 32 (the window of planes a row of leaves needs) and without prefiltering, for
// raw and gzip data. The temporary file is never seen in the directory.
TEST(SceneFile, AVolumeStreamedPlaneByPlaneBuildsTheSceneOfTheWholeVolume) {
  test::TempDir dir;
  const glm::ivec3 dims(37, 70, 71);
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> noise(-40, 40);
  std::vector<int16_t> samples;
  for (int k = 0; k < dims.z; ++k)
    for (int j = 0; j < dims.y; ++j)
      for (int i = 0; i < dims.x; ++i)
        samples.push_back(int16_t((glm::length(glm::vec3(i - 18, j - 35, k - 35)) < 16.0f ? 1200 : -800) + noise(rng)));
  test::writeBytes(dir.file("v.raw"), test::toBytes(samples));
  const std::string header = "NRRD0004\ntype: int16\ndimension: 3\nsizes: 37 70 71\nspacings: 0.5 0.6 1.25\nendian: little\n";
  test::writeText(dir.file("raw.nhdr"), header + "encoding: raw\ndata file: v.raw\n");
  {
    gzFile f = gzopen(dir.file("v.raw.gz").c_str(), "wb");
    gzwrite(f, samples.data(), unsigned(samples.size() * sizeof(int16_t)));
    gzclose(f);
  }
  test::writeText(dir.file("gz.nhdr"), header + "encoding: gzip\ndata file: v.raw.gz\n");
  for (const std::string input : {"raw.nhdr", "gz.nhdr"})
    for (const VolumeOctreeOptions options : {VolumeOctreeOptions{1}, VolumeOctreeOptions{4}, VolumeOctreeOptions{8},
                                              VolumeOctreeOptions{32}, VolumeOctreeOptions{8, false}}) {
      SCOPED_TRACE(input + ", leaf edge " + std::to_string(options.leafEdge) + (options.prefilter ? "" : ", not prefiltered"));
      const Volume v = readVolume(dir.file(input));
      saveScene(dir.file("whole.hoct"), v, VolumeOctree::build(v, options));
      const std::unique_ptr<PlaneSource> planes = openPlanes(dir.file(input));
      EXPECT_FALSE(planes->whole());
      KnotStoreWriter store = storeWriterFor(dir.file("streamed.hoct"), *planes);
      const VolumeOctree t = VolumeOctree::build(*planes, options, &store);
      const Volume description = planes->description().withRange(t.root().minValue, t.root().maxValue, planes->name());
      EXPECT_FALSE(description.hasSamples());
      EXPECT_EQ(description.minValue(), v.minValue());
      EXPECT_EQ(description.maxValue(), v.maxValue());
      saveScene(dir.file("streamed.hoct"), description, t, store);
      EXPECT_TRUE(test::readBytes(dir.file("streamed.hoct")) == test::readBytes(dir.file("whole.hoct")));
      // Rows held within 20 KB: the store is made in strips along y, a pass over the planes each.
      KnotStoreWriter strips(planes->dims(), planes->storedType(), dir.path().string(), 20000);
      const VolumeOctree again = VolumeOctree::build(*planes, options, &strips);
      EXPECT_EQ(strips.passes(), 3);  // as many as the samples have block rows
      saveScene(dir.file("strips.hoct"), description, again, strips);
      EXPECT_TRUE(test::readBytes(dir.file("strips.hoct")) == test::readBytes(dir.file("whole.hoct")));
      size_t files = 0;
      for (const auto& entry : std::filesystem::directory_iterator(dir.path())) files += entry.path().extension() != ".hoct";
      EXPECT_EQ(files, 4u) << "only the inputs and the scenes are in the directory";
    }
  // The streamed build refuses a range whose differences overflow float, naming the file.
  std::vector<float> wide(size_t(8), 0.0f);
  wide[0] = -3e38f;
  wide[7] = 3e38f;
  test::writeBytes(dir.file("w.raw"), test::toBytes(wide));
  test::writeText(dir.file("w.nhdr"), "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nendian: little\nencoding: raw\ndata file: w.raw\n");
  const std::unique_ptr<PlaneSource> planes = openPlanes(dir.file("w.nhdr"));
  const VolumeOctree t = VolumeOctree::build(*planes, VolumeOctreeOptions{});
  try {
    planes->description().withRange(t.root().minValue, t.root().maxValue, planes->name());
    ADD_FAILURE() << "a range of 6e38 was accepted";
  } catch (const ValueError& e) {
    EXPECT_THAT(e.what(), HasSubstr(dir.file("w.nhdr") + ": samples span"));
  }
}

TEST(SceneFile, SamplesRoundTripInTheirStoredType) {
  test::TempDir dir;
  const glm::ivec3 dims(9, 5, 4);
  const size_t n = size_t(dims.x) * dims.y * dims.z;
  auto series = [&](auto first, int step) {
    std::vector<decltype(first)> v(n);
    for (size_t i = 0; i < n; ++i) v[i] = decltype(first)(int(first) + step * int(i % 97));
    return v;
  };
  const std::vector<std::pair<ScalarType, SampleArray>> arrays = {
      {ScalarType::UInt8, series(uint8_t(3), 2)},      {ScalarType::Int8, series(int8_t(-100), 2)},
      {ScalarType::UInt16, series(uint16_t(100), 600)}, {ScalarType::Int32, series(int16_t(-30000), 600)},
      {ScalarType::Float64, series(-7.25f, 3)}};
  for (const auto& [source, samples] : arrays) {
    SCOPED_TRACE(scalarName(storedType(samples)));
    const Volume v(dims, glm::dvec3(0.5, 0.7, 1.25), source, samples, "typed");
    saveScene(dir.file("t.hoct"), v, VolumeOctree::build(v, VolumeOctreeOptions{4}));
    const Scene s = loadScene(dir.file("t.hoct"));
    EXPECT_EQ(s.volume.sourceType(), source);
    EXPECT_EQ(s.volume.samples(), samples);  // same type, bit-identical values
    // The file holds the samples in their stored type, not widened.
    EXPECT_LT(test::readBytes(dir.file("t.hoct")).size(), n * scalarSize(storedType(samples)) + 4096);
  }
  // A stored-type code that is not a storage type is refused by name.
  std::vector<uint8_t> bytes = test::readBytes(dir.file("t.hoct"));
  const uint32_t int32Code = uint32_t(ScalarType::Int32);
  std::memcpy(&bytes[16 + 16 + 12 + 24 + 4], &int32Code, 4);
  uint64_t volumeBytes = 0;  // the volume section's CRC made right again: the check under test is the type's
  std::memcpy(&volumeBytes, &bytes[16 + 4], 8);
  const uint32_t crc = uint32_t(crc32_z(crc32_z(0L, Z_NULL, 0), &bytes[32], size_t(volumeBytes)));
  std::memcpy(&bytes[16 + 12], &crc, 4);
  test::writeBytes(dir.file("bad.hoct"), bytes);
  expectLoadFails(dir.file("bad.hoct"), "stored sample type code 5 invalid");
}

TEST(SceneFile, KnotModeRoundTrips) {
  test::TempDir dir;
  const Volume v = test::randomVolume({33, 20, 9}, 5);
  for (const bool prefilter : {true, false}) {
    const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{8, prefilter});
    saveScene(dir.file("s.hoct"), v, t);
    const Scene s = loadScene(dir.file("s.hoct"));
    EXPECT_EQ(s.octree.prefiltered(), prefilter);
    EXPECT_TRUE(std::ranges::equal(s.octree.errorData(), t.errorData()));
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
  EXPECT_FALSE(loaded.volume.frame().assumed);
  EXPECT_EQ(loaded.volume.info(), v.info());
  // A frame the reader assumed (no orientation in the file) stays marked as assumed.
  PatientFrame assumed = v.frame();
  assumed.assumed = true;
  v.setFrame(assumed);
  saveScene(dir.file("a.hoct"), v, VolumeOctree::build(v));
  EXPECT_TRUE(loadScene(dir.file("a.hoct")).volume.frame().assumed);
  // Versions 1 and 2 knew no patient frame: refused, with what to do.
  std::vector<uint8_t> bytes = test::readBytes(dir.file("s.hoct"));
  for (uint32_t version : {1u, 2u, 3u, 4u}) {
    std::memcpy(&bytes[8], &version, 4);
    test::writeBytes(dir.file("old.hoct"), bytes);
    expectLoadFails(dir.file("old.hoct"), "version " + std::to_string(version) +
                                              (version < 3 ? " has no patient orientation" : version == 3 ? " does not tie" : " holds its samples as float"));
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
  EXPECT_EQ(s.surface->nodes(), so.nodes());
  EXPECT_EQ(s.surface->reconstruct().indices, so.reconstruct().indices);
  // Paged, its nodes stay in the file, each decoded when read: the same nodes, ranges, regions
  // and surface, none of them held.
  SceneLoadOptions paged;
  paged.samples = false;
  const Scene p = loadScene(dir.file("s.hoct"), paged);
  ASSERT_TRUE(p.surface.has_value());
  EXPECT_TRUE(p.surface->mapped());
  EXPECT_FALSE(s.surface->mapped());
  ASSERT_EQ(p.surface->nodeCount(), so.nodeCount());
  for (size_t i = 0; i < so.nodeCount(); ++i) EXPECT_EQ(p.surface->node(i), so.nodes()[i]) << i;
  EXPECT_EQ(p.surface->bytesUsed(), SurfaceOctree::bytesFor(0));
  for (int edge : {4, 8, 16})
    for (int z = 0; z < 16; z += edge)
      for (int y = 0; y < 16; y += edge)
        for (int x = 0; x < 16; x += edge) EXPECT_EQ(p.surface->rangeIn({x, y, z}, edge), so.rangeIn({x, y, z}, edge));
  EXPECT_EQ(p.surface->regions(50).size(), so.regions(50).size());
  EXPECT_EQ(p.surface->reconstruct().indices, so.reconstruct().indices);
  EXPECT_EQ(p.surface->reconstructIn(so.regions(50)[1]).indices, so.reconstructIn(so.regions(50)[1]).indices);
  // A scene without a surface loads without one.
  saveScene(dir.file("v.hoct"), v, t);
  EXPECT_FALSE(loadScene(dir.file("v.hoct")).surface.has_value());
  // A node pointing outside the grid is rejected.
  auto nodes = so.nodes();
  nodes.back().origin = glm::u16vec3(60000);
  EXPECT_THROW(SurfaceOctree::fromParts(v.dims(), 0.0f, so.cellCount(), so.mergeEdge(), nodes, "x"), IoError);
  EXPECT_THROW(SurfaceOctree::fromParts(v.dims(), 0.0f, so.cellCount(), 3, so.nodes(), "x"), IoError);
  // So is a plane count past the node's planes, their orientations never read (a fuzzer's find).
  nodes = so.nodes();
  nodes.front().planeCount = uint8_t(nodes.front().planes.size() + 200);
  EXPECT_THROW(SurfaceOctree::fromParts(v.dims(), 0.0f, so.cellCount(), so.mergeEdge(), nodes, "x"), IoError);
}

// A streamed build's Surface Octree, its nodes copied into the scene from their temporary file, makes
// the scene of the octree built in memory byte for byte; a write that fails (in the temporary file
// or in the scene) leaves nothing in the directory.
TEST(SceneFile, ASpooledSurfaceOctreeWritesTheSceneOfTheOctreeInMemory) {
  test::TempDir dir;
  const Volume v = test::sphereVolume(glm::ivec3(41, 37, 35), 15.3);
  writeNrrd(v, dir.file("v.nrrd"));
  const Volume read = readVolume(dir.file("v.nrrd"));
  const VolumeOctree wholeOctree = VolumeOctree::build(read);
  const SurfaceOctree so = SurfaceOctree::build(read, wholeOctree, 0.0f);
  saveScene(dir.file("whole.hoct"), read, wholeOctree, &so);
  const std::vector<std::string> before = test::namesIn(dir);
  const std::unique_ptr<PlaneSource> planes = openPlanes(dir.file("v.nrrd"));
  KnotStoreWriter store = storeWriterFor(dir.file("streamed.hoct"), *planes);
  const VolumeOctree t = VolumeOctree::build(*planes, VolumeOctreeOptions{}, &store);
  const Volume description = planes->description().withRange(t.root().minValue, t.root().maxValue, planes->name());
  const SpooledSurfaceOctree spooled = SpooledSurfaceOctree::build(*planes, t, 0.0f, spoolDirectoryFor(dir.file("streamed.hoct")));
  ASSERT_GT(spooled.nodeCount(), 200u);
  {  // the scene is larger than the disk takes
    const test::FileSizeLimit full(std::filesystem::file_size(dir.file("whole.hoct")) / 2);
    try {
      saveScene(dir.file("streamed.hoct"), description, t, store, spooled);
      ADD_FAILURE() << "wrote a scene past the file size limit";
    } catch (const IoError& e) {
      EXPECT_THAT(e.what(), HasSubstr(dir.file("streamed.hoct") + ": write failed (File too large)"));
    }
  }
  EXPECT_EQ(test::namesIn(dir), before);
  {  // the temporary file is: the surface's first slab does not fit
    const test::FileSizeLimit full(kSurfaceNodeBytes);
    try {
      SpooledSurfaceOctree::build(*planes, t, 0.0f, dir.path().string());
      ADD_FAILURE() << "spooled past the file size limit";
    } catch (const IoError& e) {
      EXPECT_THAT(e.what(), HasSubstr("surface octree: temporary file write failed (File too large)"));
    }
  }
  EXPECT_EQ(test::namesIn(dir), before);
  saveScene(dir.file("streamed.hoct"), description, t, store, spooled);
  EXPECT_TRUE(test::readBytes(dir.file("streamed.hoct")) == test::readBytes(dir.file("whole.hoct")));
  const Scene s = loadScene(dir.file("streamed.hoct"));
  ASSERT_TRUE(s.surface.has_value());
  EXPECT_EQ(s.surface->nodes(), so.nodes());
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

// A scene file's section records (tag, size, CRC, payload), after its 16-byte header.
std::vector<std::vector<uint8_t>> sectionRecords(const std::vector<uint8_t>& file) {
  std::vector<std::vector<uint8_t>> records;
  for (size_t pos = 16; pos < file.size();) {
    uint64_t size;
    std::memcpy(&size, &file[pos + 4], 8);
    records.emplace_back(file.begin() + ptrdiff_t(pos), file.begin() + ptrdiff_t(pos + 16 + size));
    pos += 16 + size_t(size);
  }
  return records;
}

TEST(SceneFile, SavedTwiceTheBytesAreTheSame) {
  test::TempDir dir;
  const Volume v = test::sphereVolume(glm::ivec3(21, 19, 17), 7.3);
  const VolumeOctree t = VolumeOctree::build(v);
  const SurfaceOctree a = SurfaceOctree::build(v, t, 0.0f), b = SurfaceOctree::build(v, t, 0.0f);
  saveScene(dir.file("a.hoct"), v, t, &a);
  saveScene(dir.file("b.hoct"), v, VolumeOctree::build(v), &b);
  EXPECT_EQ(test::readBytes(dir.file("a.hoct")), test::readBytes(dir.file("b.hoct")));
}

TEST(SceneFile, SectionsOfAnotherVolumeAreRefused) {
  test::TempDir dir;
  // Two volumes of one size: octree sections of either fit the other's shape.
  const Volume a = test::sphereVolume(glm::ivec3(21, 19, 17), 7.3), b = test::sphereVolume(glm::ivec3(21, 19, 17), 6.1);
  const VolumeOctree ta = VolumeOctree::build(a), tb = VolumeOctree::build(b);
  const SurfaceOctree sa = SurfaceOctree::build(a, ta, 0.0f), sb = SurfaceOctree::build(b, tb, 0.0f);
  saveScene(dir.file("a.hoct"), a, ta, &sa);
  saveScene(dir.file("b.hoct"), b, tb, &sb);
  const std::vector<uint8_t> fa = test::readBytes(dir.file("a.hoct")), fb = test::readBytes(dir.file("b.hoct"));
  const auto ra = sectionRecords(fa), rb = sectionRecords(fb);
  ASSERT_EQ(ra.size(), size_t(6));  // VOLM, KDAT, KIDX, ALGN, VOCT, SURF
  for (size_t swapped : {size_t(2), size_t(4), size_t(5)}) {
    std::vector<uint8_t> mixed(fa.begin(), fa.begin() + 16);
    for (size_t s = 0; s < ra.size(); ++s) {
      const bool store = swapped == 2 && s == 1;  // the knot store's data goes with its index
      const auto& r = s == swapped || store ? rb[s] : ra[s];
      mixed.insert(mixed.end(), r.begin(), r.end());
    }
    test::writeBytes(dir.file("mixed.hoct"), mixed);
    if (swapped == 2) {
      // Another volume's knot store: its samples disagree with the volume section, and paged,
      // its index changes the hash the octrees were tied to.
      expectLoadFails(dir.file("mixed.hoct"), "knot store disagrees with its volume section");
      try {
        loadScene(dir.file("mixed.hoct"), SceneLoadOptions{false, 0});
        ADD_FAILURE() << "paged load of a spliced store";
      } catch (const IoError& e) {
        EXPECT_THAT(e.what(), HasSubstr("the volume octree section was built from another volume"));
      }
      continue;
    }
    expectLoadFails(dir.file("mixed.hoct"), std::string("the ") + (swapped == 5 ? "surface octree" : "volume octree") +
                                                " section was built from another volume");
  }
}

// The octree's arrays are left in the file, mapped (the kernel pages in the nodes a frame reads),
// in memory and paged alike; a scene whose arrays are off their alignment (one byte more of
// padding before them) loads them copied, the same octree.
TEST(SceneFile, TheOctreeIsMappedInPlaceOrCopiedWhenMisaligned) {
  test::TempDir dir;
  const Volume v = test::randomVolume({33, 20, 9}, 3);
  const VolumeOctree t = VolumeOctree::build(v, VolumeOctreeOptions{4});
  saveScene(dir.file("s.hoct"), v, t);
  auto same = [&](const VolumeOctree& o) {
    return o.nodes().size() == t.nodes().size() &&
           std::memcmp(o.nodes().data(), t.nodes().data(), t.nodes().size() * sizeof(OctreeNode)) == 0 &&
           std::ranges::equal(o.errorData(), t.errorData());
  };
  EXPECT_FALSE(t.mapped());
  for (const bool inMemory : {true, false}) {
    std::optional<VolumeOctree> copy;
    {
      const Scene s = loadScene(dir.file("s.hoct"), SceneLoadOptions{inMemory, 1 << 20});
      EXPECT_TRUE(s.octree.mapped()) << inMemory;
      EXPECT_TRUE(same(s.octree)) << inMemory;
      copy = s.octree;  // shares the mapping, which outlives the scene
    }
    ASSERT_TRUE(copy->mapped());
    EXPECT_TRUE(same(*copy)) << inMemory;
    copy->releasePages();  // its pages given back are read again from the file
    EXPECT_TRUE(same(*copy)) << inMemory;
  }
  auto records = sectionRecords(test::readBytes(dir.file("s.hoct")));
  ASSERT_EQ(records.size(), size_t(5));  // VOLM, KDAT, KIDX, ALGN, VOCT
  ASSERT_EQ(std::string(records[3].begin(), records[3].begin() + 4), "ALGN");
  records[3].push_back(0);
  const uint64_t padding = records[3].size() - 16;
  std::memcpy(&records[3][4], &padding, 8);
  std::vector<uint8_t> shifted = test::readBytes(dir.file("s.hoct"));
  shifted.resize(16);
  for (const auto& r : records) shifted.insert(shifted.end(), r.begin(), r.end());
  test::writeBytes(dir.file("shifted.hoct"), shifted);
  const Scene s = loadScene(dir.file("shifted.hoct"));
  EXPECT_FALSE(s.octree.mapped());
  EXPECT_TRUE(same(s.octree));
}

TEST(SceneFile, AnOctreeThatDisagreesWithItsSamplesIsRefused) {
  const Volume v = test::randomVolume({17, 9, 5}, 4);
  const VolumeOctree t = VolumeOctree::build(v);
  EXPECT_NO_THROW(t.validateAgainst(v, "x"));
  const auto check = [&](std::vector<OctreeNode> nodes, std::vector<float> errors, const std::string& what) {
    const VolumeOctree bad = VolumeOctree::fromParts(v.dims(), 8, std::move(nodes), std::move(errors), "x");  // well formed
    try {
      bad.validateAgainst(v, "x.hoct");
      ADD_FAILURE() << what;
    } catch (const IoError& e) {
      EXPECT_THAT(e.what(), HasSubstr("x.hoct: octree node"));
      EXPECT_THAT(e.what(), HasSubstr(what));
    }
  };
  const size_t leaf = t.nodes().size() - 1;
  ASSERT_TRUE(t.nodes()[leaf].isLeaf());
  const std::vector<OctreeNode> allNodes(t.nodes().begin(), t.nodes().end());
  const std::vector<float> errorData(t.errorData().begin(), t.errorData().end());
  auto nodes = allNodes;
  nodes[leaf].minValue -= 1.0f;  // still a valid range, but not its samples'
  check(nodes, errorData, "min/max other than its samples'");
  nodes = allNodes;
  nodes[0].maxValue += 1.0f;
  check(nodes, errorData, "min/max other than its children's");
  auto errors = errorData;
  errors[t.nodes()[0].errorOffset + size_t(t.maxLevel(t.nodes()[0]))] = 0.5f;
  check(allNodes, errors, "non-zero error at full resolution");
}

TEST(SceneFile, FromPartsRejectsInconsistentOctrees) {
  const Volume v = test::randomVolume({17, 9, 5}, 4);
  const VolumeOctree t = VolumeOctree::build(v);
  const std::vector<OctreeNode> nodes(t.nodes().begin(), t.nodes().end());
  const std::vector<float> errors(t.errorData().begin(), t.errorData().end());
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
