#include "volume/volume.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "test_util.h"
#include "volume/file_util.h"

namespace hyb {
namespace {

TEST(Volume, GradientsAreVoxelCentralDifferencesInterpolated) {
  // A linear field: every estimate is exact, on the faces too, in data units per mm.
  const Volume lin = test::makeVolume({5, 4, 3}, [](int i, int j, int k) { return 2.0f * i + 3.0f * j - k; }, glm::dvec3(0.5, 1, 2));
  for (const glm::ivec3 p : {glm::ivec3(0, 0, 0), glm::ivec3(2, 1, 1), glm::ivec3(4, 3, 2)}) {
    const glm::vec3 g = lin.gradientAt(p.x, p.y, p.z);
    EXPECT_FLOAT_EQ(g.x, 4.0f);
    EXPECT_FLOAT_EQ(g.y, 3.0f);
    EXPECT_FLOAT_EQ(g.z, -0.5f);
  }
  EXPECT_NEAR(lin.sampleGradient(glm::vec3(1.3f, 2.7f, 0.4f)).x, 4.0f, 1e-5f);
  // f = i²: central differences 2i inside, one-sided (f(1) − f(0)) = 1 on the face, interpolated
  // linearly between voxels; an axis of one sample has no gradient.
  const Volume sq = test::makeVolume({6, 2, 1}, [](int i, int, int) { return float(i * i); });
  EXPECT_FLOAT_EQ(sq.gradientAt(0, 0, 0).x, 1.0f);
  EXPECT_FLOAT_EQ(sq.gradientAt(3, 1, 0).x, 6.0f);
  EXPECT_FLOAT_EQ(sq.gradientAt(5, 0, 0).x, 9.0f);  // (25 − 16) / 1, one-sided
  EXPECT_FLOAT_EQ(sq.gradientAt(3, 1, 0).z, 0.0f);
  EXPECT_FLOAT_EQ(sq.sampleGradient(glm::vec3(2.5f, 0.5f, 0.0f)).x, 5.0f);
  EXPECT_FLOAT_EQ(sq.sampleGradient(glm::vec3(-3.0f, 0.0f, 0.0f)).x, 1.0f);  // clamped to the grid
}

TEST(FileUtil, AtomicWriteLeavesNothingBehindOnFailure) {
  test::TempDir dir;
  const std::string path = dir.file("out.bin");
  writeFileAtomically(path, [](std::ostream& o) { o << "complete"; });
  EXPECT_EQ(test::readBytes(path).size(), size_t(8));
  EXPECT_THROW(writeFileAtomically(path, [](std::ostream& o) {
                 o << "half";
                 throw IoError("simulated failure");
               }),
               IoError);
  EXPECT_EQ(test::readBytes(path).size(), size_t(8));  // old content intact
  size_t files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir.path())) files += e.is_regular_file();
  EXPECT_EQ(files, size_t(1));  // no temporary left behind
  EXPECT_THROW(writeFileAtomically(dir.file("no/such/dir/x.bin"), [](std::ostream& o) { o << "x"; }), IoError);
  EXPECT_EQ(fileExtension("/a/b/Scan.NII.GZ"), ".nii.gz");
  EXPECT_EQ(fileExtension("/a/b.c/scan"), "");
}

}  // namespace
}  // namespace hyb
