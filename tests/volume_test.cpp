#include "volume/volume.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "test_util.h"
#include "volume/core/file_util.h"
#include "volume/reader_util.h"

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

TEST(Volume, TypedSamplesReadExactlyAndCopiesShareThem) {
  const glm::ivec3 dims(3, 2, 2);
  const Volume v(dims, glm::dvec3(1.0), ScalarType::Int16, SampleArray(std::vector<int16_t>{-32768, -1024, 0, 1, 2, 3, 4, 5, 6, 7, 3071, 32767}));
  EXPECT_EQ(v.storedType(), ScalarType::Int16);
  EXPECT_EQ(v.bytesUsed(), 12 * 2 + sizeof(Volume));
  EXPECT_EQ(v.minValue(), -32768.0f);
  EXPECT_EQ(v.maxValue(), 32767.0f);
  EXPECT_EQ(v.at(1, 0, 0), -1024.0f);
  EXPECT_EQ(v.at(1, 1, 1), 3071.0f);
  float row[3];
  v.readRow(0, 1, 1, 3, row);
  EXPECT_EQ(row[0], 7.0f);
  EXPECT_EQ(row[2], 32767.0f);
  EXPECT_FLOAT_EQ(v.sample(glm::vec3(0.5f, 0.0f, 0.0f)), (-32768.0f - 1024.0f) / 2);
  const Volume copy = v;  // immutable: a copy shares the samples
  EXPECT_EQ(&copy.samples(), &v.samples());
  // Padding keeps the type when the padding value is one of its values, else holds float.
  EXPECT_EQ(paddedVolume(v, -2000.0f).storedType(), ScalarType::Int16);
  const Volume wide = paddedVolume(v, -40000.0f);
  EXPECT_EQ(wide.storedType(), ScalarType::Float32);
  EXPECT_EQ(wide.at(2, 1, 1), -1024.0f);
  EXPECT_EQ(wide.at(0, 0, 0), -40000.0f);
  EXPECT_THROW(Volume(dims, glm::dvec3(1.0), ScalarType::UInt8, SampleArray(std::vector<uint8_t>(11))), ValueError);
}

// Averaging a field linear in the patient over blocks gives the field at each block's centre:
// the averaged volume's frame puts each sample where its block's voxels lie (rotated, mirrored
// grids too). A block cut short at a far face averages the voxels it has.
TEST(Volume, BlockAveragesStandAtTheirBlocksCentresInThePatient) {
  PatientFrame frame;
  frame.direction = glm::dmat3(glm::dvec3(0, 1, 0), glm::dvec3(-1, 0, 0), glm::dvec3(0, 0, -1));  // (mirrored)
  frame.origin = {10.0, -20.0, 30.0};
  const glm::dvec3 spacing(0.5, 0.75, 2.0);
  auto field = [](const glm::dvec3& p) { return float(3.0 * p.x - 2.0 * p.y + 0.5 * p.z); };
  Volume v = test::makeVolume({8, 6, 5}, [&](int i, int j, int k) { return field(frame.toPatient(glm::dvec3(i, j, k) * spacing)); }, spacing);
  v.setFrame(frame);
  const Volume a = boxAveraged(v, {2, 3, 2});
  EXPECT_EQ(a.dims(), glm::ivec3(4, 2, 3));
  EXPECT_EQ(a.spacing(), glm::dvec3(1.0, 2.25, 4.0));
  EXPECT_EQ(a.frame().direction, frame.direction);
  for (int k = 0; k < 2; ++k)  // (whole blocks)
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 4; ++i) EXPECT_NEAR(a.at(i, j, k), field(a.frame().toPatient(glm::dvec3(i, j, k) * a.spacing())), 1e-4) << i << j << k;
  // The last block along k holds plane 4 alone: its value, though it stands half a plane further.
  EXPECT_NEAR(a.at(1, 1, 2), (v.at(2, 3, 4) + v.at(3, 3, 4) + v.at(2, 4, 4) + v.at(3, 4, 4) + v.at(2, 5, 4) + v.at(3, 5, 4)) / 6.0f, 1e-4);
  EXPECT_EQ(boxAveraged(v, {1, 1, 1}).dims(), v.dims());
  EXPECT_THROW(boxAveraged(v, {0, 1, 1}), ValueError);
}

TEST(Volume, RescaledSlicesStayIn16BitsUntilAValueIsNotOneOfItsIntegers) {
  SampleArray samples = detail::rescaleTarget(ScalarType::UInt16, 1.0, -1024.0, 6);
  ASSERT_EQ(storedType(samples), ScalarType::Int16);
  detail::rescaleSamples(&samples, 0, SampleArray(std::vector<uint16_t>{0, 1024, 4095}), 1.0, -1024.0);
  EXPECT_EQ(storedType(samples), ScalarType::Int16);
  // A later slice with a fractional slope: everything moves to float, the first slice's values kept.
  detail::rescaleSamples(&samples, 3, SampleArray(std::vector<uint16_t>{1, 2, 3}), 0.5, -1024.0);
  ASSERT_EQ(storedType(samples), ScalarType::Float32);
  EXPECT_EQ(std::get<std::vector<float>>(samples), (std::vector<float>{-1024, 0, 3071, -1023.5f, -1023, -1022.5f}));
  // Not rescaled: 8 and 16 bits stay as they are; a fractional slope is float from the start.
  EXPECT_EQ(storedType(detail::rescaleTarget(ScalarType::UInt8, 1.0, 0.0, 1)), ScalarType::UInt8);
  EXPECT_EQ(storedType(detail::rescaleTarget(ScalarType::Int16, 0.5, 0.0, 1)), ScalarType::Float32);
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

namespace hyb {
namespace {

// A volume over samples it does not own reads them in place, keeps their owner alive, and checks
// them as the owning constructor does.
TEST(Volume, ABorrowingVolumeReadsItsOwnersSamplesInPlace) {
  auto owner = std::make_shared<std::vector<int16_t>>(std::vector<int16_t>{-5, 3, 7, 100, 0, 1, 2, 9});
  {
    const Volume v = Volume::borrowing({{2, 2, 2}, glm::dvec3(1.0), ScalarType::Int16, ScalarType::Int16}, owner->data(), owner, "borrowed");
    EXPECT_EQ(owner.use_count(), 2);
    EXPECT_TRUE(v.hasSamples());
    EXPECT_EQ(v.at(1, 1, 0), 100.0f);
    EXPECT_EQ(v.minValue(), -5.0f);
    EXPECT_EQ(v.maxValue(), 100.0f);
    v.visitSamples([&](const auto* d) { EXPECT_EQ(static_cast<const void*>(d), static_cast<const void*>(owner->data())); });
    const Volume copy = v;  // copies share the owner
    EXPECT_EQ(owner.use_count(), 3);
  }
  EXPECT_EQ(owner.use_count(), 1);
  std::vector<float> bad{1.0f, std::nanf(""), 0, 0, 0, 0, 0, 0};
  EXPECT_THROW(Volume::borrowing({{2, 2, 2}, glm::dvec3(1.0), ScalarType::Float32, ScalarType::Float32}, bad.data(), nullptr, "nan"), ValueError);
  std::vector<double> wide(8, 0.0);
  EXPECT_THROW(Volume::borrowing({{2, 2, 2}, glm::dvec3(1.0), ScalarType::Float64, ScalarType::Float64}, wide.data(), nullptr, "f64"), ValueError);
  EXPECT_THROW(Volume::borrowing({{2, 2, 2}, glm::dvec3(-1.0), ScalarType::Int16, ScalarType::Int16}, owner->data(), owner, "spacing"), ValueError);
}

}  // namespace
}  // namespace hyb
