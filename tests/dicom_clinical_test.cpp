// DICOM as scanners and patient CDs deliver it: a DICOMDIR over nested extensionless files with two
// studies, a localizer and a structured report; gantry-tilted and unevenly spaced series of analytic
// objects at known patient positions; enhanced multi-frame CT; the refusals of what is not a volume.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <nifti1.h>

#include <cmath>
#include <cstring>
#include <filesystem>

#include "cli_util.h"
#include "dicom_writer.h"
#include "surface/mesh_io.h"
#include "test_util.h"
#include "volume/plane_source.h"
#include "volume/patient_frame.h"
#include "volume/plane_stack.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;
using test::DicomImage;
using test::DicomStudy;
using test::TempDir;

constexpr double kPi = 3.14159265358979323846;

// An analytic head: a ball of bone (1000 HU) of radius 10 mm at the origin and a capsule of radius
// 3 mm from (18, 0, -10) to (18, 0, 10), in air (-1000 HU); edges ramp over 1 mm so that every
// sample is a linear function of the distance near the surface.
struct Phantom {
  glm::dvec3 centre{0.0, 0.0, 0.0};
  double radius = 10.0;
  glm::dvec3 a{18.0, 0.0, -10.0}, b{18.0, 0.0, 10.0};
  double rod = 3.0;
  // Distance to the surface, negative inside.
  double distance(const glm::dvec3& p) const {
    const double ball = glm::length(p - centre) - radius;
    const glm::dvec3 ab = b - a;
    const double t = std::clamp(glm::dot(p - a, ab) / glm::dot(ab, ab), 0.0, 1.0);
    const double capsule = glm::length(p - (a + t * ab)) - rod;
    return std::min(ball, capsule);
  }
  double hu(const glm::dvec3& p) const { return 1000.0 * std::clamp(-distance(p), -1.0, 1.0); }
};

// The centroid (LPS mm) of the voxels above 0 HU within 14 mm of the ball's centre.
glm::dvec3 ballCentroid(const Volume& v, const Phantom& ph) {
  glm::dvec3 sum(0.0);
  double n = 0.0;
  for (int k = 0; k < v.dims().z; ++k)
    for (int j = 0; j < v.dims().y; ++j)
      for (int i = 0; i < v.dims().x; ++i) {
        const glm::dvec3 p = v.frame().toPatient(glm::dvec3(i, j, k) * v.spacing());
        if (glm::length(p - ph.centre) > 14.0 || v.at(i, j, k) <= 0.0f) continue;
        sum += p;
        n += 1.0;
      }
  return n > 0 ? sum / n : glm::dvec3(1e9);
}

// The samples of @p path read whole and plane by plane: they must agree bit for bit.
Volume readBothWays(const std::string& path) {
  const Volume whole = readVolume(path);
  const std::unique_ptr<PlaneSource> planes = openPlanes(path);
  EXPECT_FALSE(planes->whole()) << path;
  const Volume streamed = detail::readAllPlanes(*planes);
  EXPECT_EQ(streamed.dims(), whole.dims());
  EXPECT_EQ(streamed.spacing(), whole.spacing());
  EXPECT_TRUE(streamed.frame() == whole.frame());
  EXPECT_TRUE(streamed.samples() == whole.samples()) << path << ": streamed planes differ from the whole read";
  EXPECT_EQ(streamed.warnings(), whole.warnings());
  return whole;
}

// A series of @p count slices of 64x64 pixels of 1 mm, the image plane tilted by @p tiltDeg about
// the patient's x axis (a gantry tilt, as a GE head CT writes it: Image Orientation 1\0\0\0\cos\sin),
// the table advancing @p steps along z between slices.
std::vector<DicomImage> tiltedSeries(const std::string& dir, double tiltDeg, const std::vector<double>& zs, const Phantom& ph) {
  DicomImage model;
  model.size = {64, 64};
  model.spacing = {1.0, 1.0};
  const double t = tiltDeg * kPi / 180.0;
  const double cosines[6] = {1, 0, 0, 0, std::cos(t), std::sin(t)};
  std::copy(std::begin(cosines), std::end(cosines), model.cosines);
  model.tilt = tiltDeg;
  std::vector<glm::dvec3> positions;
  for (const double z : zs) positions.push_back({-32.0, -30.0, z});
  return test::writeSeries(dir, "I", DicomStudy{}, model, positions, [&](const glm::dvec3& p) { return ph.hu(p); });
}

std::vector<double> evenly(double first, double step, int count) {
  std::vector<double> z;
  for (int k = 0; k < count; ++k) z.push_back(first + step * k);
  return z;
}

// The largest distance of an exported mesh's vertices from the phantom's surface.
double meshError(const std::string& ply, const Phantom& ph) {
  const TriangleMesh m = readMesh(ply);
  EXPECT_GT(m.vertices.size(), 100u);
  double worst = 0.0;
  for (const glm::vec3& v : m.vertices) worst = std::max(worst, std::abs(ph.distance(glm::dvec3(v))));
  return worst;
}

// A head CT acquired with an 18.5° gantry tilt: resampled onto an orthogonal grid whose anatomy lies
// where the slices' positions put it (the ball's centroid within half a voxel), read whole or
// streamed alike, with a warning naming the tilt; the exported bone surface within a voxel of the
// truth. Read as if untilted (each slice on the normal through the first), the ball would lie 6 mm off.
TEST(ClinicalDicom, AGantryTiltedSeriesLandsWhereItsPositionsPutIt) {
  TempDir dir;
  const Phantom ph;
  const std::string d = dir.file("tilted");
  tiltedSeries(d, 18.5, evenly(-50.0, 2.0, 40), ph);
  const Volume v = readBothWays(d);
  const double cosT = std::cos(18.5 * kPi / 180.0);
  EXPECT_NEAR(v.spacing().z, 2.0 * cosT, 1e-6);  // the table's step along the slices' normal
  EXPECT_EQ(v.dims().x, 64);
  EXPECT_EQ(v.dims().y, 64 + 25);  // 39 slices shifted 2 sin(18.5°) = 0.63 mm each: 24.8 rows more
  ASSERT_EQ(v.warnings().size(), 1u);
  EXPECT_THAT(v.warnings()[0], HasSubstr("gantry tilt of 18.5 degrees (Gantry/Detector Tilt (0018,1120) says 18.5 degrees)"));
  EXPECT_THAT(v.warnings()[0], HasSubstr("resampled onto an orthogonal grid of 64x89x40"));
  const double voxel = std::max({v.spacing().x, v.spacing().y, v.spacing().z});
  const glm::dvec3 c = ballCentroid(v, ph);
  EXPECT_LT(glm::length(c - ph.centre), 0.5 * voxel) << c.x << " " << c.y << " " << c.z;
  // The exported surface (patient mm) within a voxel of the ball and the capsule.
  const test::CliRun r = test::run({"export", d, "--iso", "0", "-o", dir.file("bone.ply")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_LT(meshError(dir.file("bone.ply"), ph), voxel);
  // The same geometry without the tilt tag is resampled the same way (the positions decide).
}

// What dcm2niix writes for a tilted series: its slices as they are, the shear in the sform.
void writeShearedNifti(const std::string& path, const std::vector<DicomImage>& slices) {
  const DicomImage& s0 = slices.front();
  nifti_1_header h{};
  h.sizeof_hdr = 348;
  h.dim[0] = 3;
  h.dim[1] = short(s0.size.x);
  h.dim[2] = short(s0.size.y);
  h.dim[3] = short(slices.size());
  for (int d = 4; d < 8; ++d) h.dim[d] = 1;
  h.datatype = DT_INT16;
  h.bitpix = 16;
  h.vox_offset = 352;
  h.xyzt_units = NIFTI_UNITS_MM;
  std::memcpy(h.magic, "n+1", 4);
  const glm::dvec3 r(s0.cosines[0], s0.cosines[1], s0.cosines[2]), c(s0.cosines[3], s0.cosines[4], s0.cosines[5]);
  const glm::dmat3 columns(r * s0.spacing.x, c * s0.spacing.y, slices[1].position - s0.position);  // LPS
  h.pixdim[0] = 1.0f;
  for (int a = 0; a < 3; ++a) h.pixdim[a + 1] = float(glm::length(columns[a]));
  h.sform_code = NIFTI_XFORM_SCANNER_ANAT;
  float* rows[3] = {h.srow_x, h.srow_y, h.srow_z};
  const glm::dvec3 o = rasToLps(s0.position);
  for (int row = 0; row < 3; ++row) {
    for (int a = 0; a < 3; ++a) rows[row][a] = float(rasToLps(columns[a])[row]);
    rows[row][3] = float(o[row]);
  }
  std::vector<uint8_t> bytes(352, 0);
  std::memcpy(bytes.data(), &h, sizeof h);
  for (const DicomImage& s : slices)
    for (const int16_t p : s.pixels) {
      const int16_t hu = int16_t(p * s.slope + s.intercept);
      bytes.push_back(uint8_t(hu & 0xff));
      bytes.push_back(uint8_t((hu >> 8) & 0xff));
    }
  test::writeBytes(path, bytes);
}

// The tilted series as dcm2niix's NIfTI (the shear in the sform) is drawn where the DICOM series
// is: the same grid, the same samples (within a unit of rounding, the sform holding floats).
TEST(ClinicalDicom, ATiltedSeriesAsNiftiWithAShearedSformIsTheSameVolume) {
  TempDir dir;
  const Phantom ph;
  const std::string d = dir.file("tilted");
  const std::vector<DicomImage> slices = tiltedSeries(d, 18.5, evenly(-50.0, 2.0, 40), ph);
  writeShearedNifti(dir.file("tilted.nii"), slices);
  const Volume a = readVolume(d);
  const Volume b = readBothWays(dir.file("tilted.nii"));
  ASSERT_EQ(b.dims(), a.dims());
  EXPECT_LT(glm::length(b.spacing() - a.spacing()), 1e-5);
  EXPECT_LT(glm::length(b.frame().origin - a.frame().origin), 1e-4);
  for (int c = 0; c < 3; ++c) EXPECT_LT(glm::length(b.frame().direction[c] - a.frame().direction[c]), 1e-6);
  float worst = 0.0f;
  for (size_t i = 0; i < a.voxelCount(); ++i) worst = std::max(worst, std::abs(a.value(i) - b.value(i)));
  EXPECT_LE(worst, 1.0f);
  ASSERT_EQ(b.warnings().size(), 1u);
  EXPECT_THAT(b.warnings()[0], HasSubstr("gantry tilt of 18.5 degrees (a sheared sform)"));
  EXPECT_LT(glm::length(ballCentroid(b, ph) - ph.centre), 0.5 * b.spacing().z);
}

// The real CT (Debian's cranium) acquired again as a scanner with an 18.5° gantry tilt would: each
// tilted slice sampled from it where its pixels lie. The bone's centroid from the source slices (each
// pixel at its own patient position) and from the volume read agree within 2 mm; reading the slices
// as if they were stacked along their normal (the tilt ignored) puts it 10 mm or more away.
TEST(ClinicalDicom, TheRealCraniumTiltedLandsWhereItsSlicesPutIt) {
  if (!std::filesystem::exists(kDefaultVolumePath)) GTEST_SKIP() << "needs " << kDefaultVolumePath;
  const Volume ct = readVolume(kDefaultVolumePath);
  TempDir dir;
  DicomImage model;
  model.size = {ct.dims().x, ct.dims().y + 40};
  model.spacing = {ct.spacing().x, ct.spacing().y};
  const double t = 18.5 * kPi / 180.0;
  // Rows along the CT's i axis, columns along its j axis tilted towards its k axis (patient LPS).
  const glm::dvec3 r = ct.frame().direction[0], c = std::cos(t) * ct.frame().direction[1] + std::sin(t) * ct.frame().direction[2];
  const double cosines[6] = {r.x, r.y, r.z, c.x, c.y, c.z};
  std::copy(std::begin(cosines), std::end(cosines), model.cosines);
  model.tilt = 18.5;
  const auto hu = [&](const glm::dvec3& p) {
    const glm::dvec3 g = ct.frame().toGrid(p) / ct.spacing();
    if (glm::any(glm::lessThan(g, glm::dvec3(-0.5))) || glm::any(glm::greaterThan(g, glm::dvec3(ct.dims()) - 0.5))) return -1024.0;
    return double(ct.sample(glm::vec3(g)));
  };
  std::vector<glm::dvec3> positions;
  const glm::dvec3 first = ct.frame().toPatient(glm::dvec3(0.0, -20.0 * ct.spacing().y, -30.0));
  for (int k = 0; k < 60; ++k) positions.push_back(first + double(k) * 3.0 * ct.frame().direction[2]);  // the table, 3 mm a slice
  const std::vector<DicomImage> slices = test::writeSeries(dir.file("tilted"), "I", DicomStudy{}, model, positions, hu);
  // The bone (above 300 HU) of the source slices, each pixel where it lies; and as if untilted.
  glm::dvec3 truth(0.0), untilted(0.0);
  double n = 0.0;
  const glm::dvec3 normal = glm::cross(r, c);
  for (size_t k = 0; k < slices.size(); ++k)
    for (int j = 0; j < model.size.y; ++j)
      for (int i = 0; i < model.size.x; ++i) {
        const DicomImage& s = slices[k];
        if (s.pixels[size_t(i) + size_t(model.size.x) * size_t(j)] * s.slope + s.intercept <= 300.0) continue;
        truth += s.at(i, j);
        untilted += slices[0].at(i, j) + glm::dot(positions[k] - positions[0], normal) * normal;
        n += 1.0;
      }
  ASSERT_GT(n, 1000.0);
  truth /= n;
  untilted /= n;
  const Volume v = readVolume(dir.file("tilted"));
  glm::dvec3 read(0.0);
  double m = 0.0;
  for (int k = 0; k < v.dims().z; ++k)
    for (int j = 0; j < v.dims().y; ++j)
      for (int i = 0; i < v.dims().x; ++i)
        if (v.at(i, j, k) > 300.0f) {
          read += v.frame().toPatient(glm::dvec3(i, j, k) * v.spacing());
          m += 1.0;
        }
  read /= m;
  EXPECT_LT(glm::length(read - truth), 2.0) << "read " << read.x << " " << read.y << " " << read.z << ", truth " << truth.x << " " << truth.y << " " << truth.z;
  EXPECT_GT(glm::length(untilted - truth), 10.0);
  RecordProperty("centroid_error_mm", std::to_string(glm::length(read - truth)));
  RecordProperty("untilted_error_mm", std::to_string(glm::length(untilted - truth)));
}

// Slices 1.25 mm apart through the posterior fossa, then 5 mm apart above (a multi-block head CT):
// resampled at the smallest recurring step, the ball where it is, whole or streamed; a slice missing
// from a regular run is refused naming the gap, never interpolated across.
TEST(ClinicalDicom, UnevenSpacingIsResampledAndAMissingSliceRefused) {
  TempDir dir;
  const Phantom ph;
  std::vector<double> zs = evenly(-14.0, 1.25, 24);  // -14 .. 14.75 mm
  for (int k = 1; k <= 5; ++k) zs.push_back(14.75 + 5.0 * k);
  const std::string d = dir.file("uneven");
  tiltedSeries(d, 0.0, zs, ph);
  const Volume v = readBothWays(d);
  EXPECT_DOUBLE_EQ(v.spacing().z, 1.25);
  EXPECT_EQ(v.dims().z, 24 + 20);
  ASSERT_EQ(v.warnings().size(), 1u);
  EXPECT_THAT(v.warnings()[0], HasSubstr("slices 1.25 to 5 mm apart along their normal: resampled onto a regular grid 1.25 mm apart "
                                         "(the smallest step that recurs), 44 planes from 29 slices"));
  const glm::dvec3 c = ballCentroid(v, ph);
  EXPECT_LT(glm::length(c - ph.centre), 0.5 * 1.25);
  // Planes that fall on a slice are that slice, exactly.
  const Volume plain = readVolume(d, nullptr, "");
  EXPECT_EQ(plain.voxelCount(), v.voxelCount());

  std::vector<double> gap = evenly(-20.0, 2.0, 20);
  gap.erase(gap.begin() + 7);  // -6 mm missing
  const std::string g = dir.file("gap");
  tiltedSeries(g, 0.0, gap, ph);
  for (const bool stream : {false, true}) {
    try {
      if (stream) openPlanes(g);
      else readVolume(g);
      ADD_FAILURE() << "a series with a missing slice was read";
    } catch (const IoError& e) {
      EXPECT_THAT(e.what(), HasSubstr("a slice is missing between"));
      EXPECT_THAT(e.what(), HasSubstr("(slice 7 of 19) and "));
      EXPECT_THAT(e.what(), HasSubstr("4 mm apart where the slices beside them are 2 mm apart"));
    }
  }
}

// An Enhanced CT image (one file, per-frame positions and rescale in its functional groups) is the
// volume its frames make as single files.
TEST(ClinicalDicom, AnEnhancedMultiFrameImageEqualsItsSlicesAsFiles) {
  TempDir dir;
  const Phantom ph;
  const std::string single = dir.file("single");
  std::vector<DicomImage> frames = tiltedSeries(single, 0.0, evenly(-12.0, 2.0, 13), ph);
  // Another rescale on some frames: each frame's own Pixel Value Transformation applies.
  for (size_t k = 0; k < frames.size(); k += 3) {
    frames[k].intercept = -2048.0;
    test::sampleField(&frames[k], [&](const glm::dvec3& p) { return ph.hu(p); });
  }
  std::filesystem::remove_all(single);
  std::filesystem::create_directories(single);
  for (size_t k = 0; k < frames.size(); ++k) test::writeCtImage(single + "/F" + std::to_string(k), DicomStudy{}, frames[k]);
  const std::string multi = dir.file("multi");
  std::filesystem::create_directories(multi);
  std::vector<DicomImage> shuffled = frames;
  std::reverse(shuffled.begin(), shuffled.end());  // frames stored in another order than their positions
  test::writeEnhancedCt(multi + "/ENHANCED", DicomStudy{}, shuffled);
  const Volume a = readVolume(single), b = readBothWays(multi);
  EXPECT_EQ(b.dims(), a.dims());
  EXPECT_EQ(b.spacing(), a.spacing());
  EXPECT_TRUE(b.frame() == a.frame());
  EXPECT_TRUE(b.samples() == a.samples());
  EXPECT_EQ(b.dims().z, 13);
  const DicomListing l = listDicomSeries(multi);
  ASSERT_EQ(l.series.size(), 1u);
  EXPECT_EQ(l.series[0].slices, 13u);
  EXPECT_EQ(l.series[0].files, 1u);
}

// A patient CD: a DICOMDIR naming extensionless files in nested folders, two studies, a localizer
// series and a structured report. Listed by patient, study and series; the default is the largest
// axial series; the report is skipped and said; the same tree without its DICOMDIR lists alike.
TEST(ClinicalDicom, APatientCdListsItsStudiesAndOpensTheRightSeries) {
  TempDir dir;
  const Phantom ph;
  const std::string root = dir.file("CD");
  DicomStudy head, chest;
  chest.uid = "1.2.826.0.1.3680043.8.498.50";
  chest.date = "20240415";
  chest.description = "CT CHEST";
  DicomImage axial;
  axial.size = {32, 32};
  axial.spacing = {2.0, 2.0};
  std::vector<glm::dvec3> zs;
  for (int k = 0; k < 20; ++k) zs.push_back({-32.0, -32.0, -20.0 + 2.0 * k});
  const auto hu = [&](const glm::dvec3& p) { return ph.hu(p); };
  test::writeSeries(root + "/S100/S200", "I", head, axial, zs, hu);
  DicomImage scout = axial;  // one sagittal slice, ImageType LOCALIZER, in a series of its own
  scout.seriesUid = "1.2.826.0.1.3680043.8.498.3";
  scout.seriesNumber = 1;
  scout.seriesDescription = "SCOUT";
  scout.imageType = "ORIGINAL\\PRIMARY\\LOCALIZER";
  const double sagittal[6] = {0, 1, 0, 0, 0, -1};
  std::copy(std::begin(sagittal), std::end(sagittal), scout.cosines);
  test::writeSeries(root + "/S100/S201", "I", head, scout, {{0.0, -32.0, 20.0}}, hu);
  test::writeStructuredReport(root + "/S100/S202/I1", head, "1.2.826.0.1.3680043.8.498.4");
  DicomImage other = axial;
  other.seriesUid = "1.2.826.0.1.3680043.8.498.51";
  other.seriesDescription = "CHEST 5";
  zs.resize(12);
  test::writeSeries(root + "/S300/S400", "I", chest, other, zs, hu);
  // What a Philips CD also carries in each folder: a file that is not DICOM.
  for (const char* folder : {"/S100/S200", "/S300/S400"}) test::writeBytes(root + folder + "/DIRFILE", std::vector<uint8_t>(300, 0x4a));
  std::vector<std::string> files;
  for (const auto& e : std::filesystem::recursive_directory_iterator(root))
    if (e.is_regular_file() && e.path().filename() != "DIRFILE") files.push_back(e.path().lexically_relative(root).generic_string());
  test::writeDicomdir(root, files);

  for (const bool withDicomdir : {true, false}) {
    SCOPED_TRACE(withDicomdir ? "with its DICOMDIR" : "its tree");
    if (!withDicomdir) std::filesystem::remove(root + "/DICOMDIR");
    const DicomListing l = listDicomSeries(root);
    EXPECT_EQ(l.dicomdir, withDicomdir);
    ASSERT_EQ(l.series.size(), 3u);
    EXPECT_EQ(l.series[0].description, "HEAD 2.5");  // the default: the largest axial series
    EXPECT_EQ(l.series[0].slices, 20u);
    EXPECT_EQ(l.series[0].studyDescription, "CT HEAD");
    EXPECT_EQ(l.series[0].patientName, "TEST^PATIENT");
    EXPECT_EQ(l.series[1].description, "CHEST 5");
    EXPECT_EQ(l.series[1].studyDate, "20240415");
    EXPECT_EQ(l.series[2].description, "SCOUT");
    EXPECT_TRUE(l.series[2].localizer);
    // Files looked at: the DICOMDIR's 34 (20 + 1 + 1 + 12), or the tree's 36 with the two DIRFILEs.
    EXPECT_EQ(l.files, withDicomdir ? 34u : 36u);
    using Skipped = std::vector<std::pair<std::string, size_t>>;
    EXPECT_EQ(l.skipped, withDicomdir ? (Skipped{{"structured report", 1}}) : (Skipped{{"not DICOM", 2}, {"structured report", 1}}));
    const Volume v = readVolume(root);
    EXPECT_EQ(v.dims(), glm::ivec3(32, 32, 20));
    ASSERT_EQ(v.warnings().size(), 1u);
    EXPECT_THAT(v.warnings()[0], HasSubstr("3 series in 2 studies; reading the largest axial one that is not a localizer, "));
    const test::CliRun info = test::run({"info", root});
    ASSERT_EQ(info.status, 0) << info.err;
    EXPECT_THAT(info.out, HasSubstr("series   3 in 2 studies in " + root + (withDicomdir ? " (from its DICOMDIR)" : "")));
    EXPECT_THAT(info.out, HasSubstr("patient  TEST^PATIENT (ID HYB001)\n  study  20240301  CT HEAD  (1.2.826.0.1.3680043.8.498.1)\n"));
    EXPECT_THAT(info.out, HasSubstr("  study  20240415  CT CHEST  (1.2.826.0.1.3680043.8.498.50)\n"));
    EXPECT_THAT(info.out, HasSubstr("HEAD 2.5  (read by default)\n"));
    EXPECT_THAT(info.out, HasSubstr("SCOUT  (localizer)\n"));
    EXPECT_THAT(info.out, HasSubstr(withDicomdir ? "skipped  1 of 34 files: 1 structured report\n" : "skipped  3 of 36 files: 2 not DICOM, 1 structured report\n"));
    // The localizer is read when named.
    EXPECT_EQ(readVolume(root, nullptr, "1.2.826.0.1.3680043.8.498.3").dims(), glm::ivec3(32, 32, 1));
    // ... but one image has nothing between its samples to render or build.
    for (const std::string out : {"scout.png", "scout.hoct"}) {
      test::expectBadInput({out == "scout.png" ? "render" : "build", root, "--series", "1.2.826.0.1.3680043.8.498.3", "-o", dir.file(out)},
                           "a volume of 32x32x1 samples (expected at least 2 along each axis to render or mesh; a single image, such as a localizer");
      EXPECT_FALSE(std::filesystem::exists(dir.file(out)));
    }
  }
}

// Reading @p path (its series @p series) fails with one line holding @p what.
void expectOneLine(const std::string& path, const std::string& what, const std::string& series = "") {
  try {
    readVolume(path, nullptr, series);
    ADD_FAILURE() << path << " was read; expected " << what;
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr(what));
    EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
  }
}

// What is not one volume meets one line naming it: a DICOMDIR naming files that are not there, two
// sizes or two orientations in a series, a folder with nothing readable (saying what it found).
TEST(ClinicalDicom, WhatIsNotOneVolumeIsRefusedInOneLine) {
  TempDir dir;
  const Phantom ph;
  const auto hu = [&](const glm::dvec3& p) { return ph.hu(p); };
  DicomImage model;
  model.size = {16, 16};
  std::vector<glm::dvec3> zs;
  for (int k = 0; k < 4; ++k) zs.push_back({0.0, 0.0, 2.0 * k});
  const std::string cd = dir.file("cd");
  test::writeSeries(cd + "/A", "I", DicomStudy{}, model, zs, hu);
  test::writeDicomdir(cd, {"A/I1", "A/I2", "A/I3", "A/I4"});
  std::filesystem::remove(cd + "/A/I3");
  expectOneLine(cd, "DICOMDIR: names 1 of its 4 image files that are not there, 'A\\I3' first");
  // A record naming a file outside the CD's folder (a viewer's data folder must hold what it opens).
  const std::string escape = dir.file("escape");
  test::writeSeries(dir.file("outside"), "I", DicomStudy{}, model, zs, hu);
  std::filesystem::create_directories(escape);
  test::writeDicomdir(escape, {"../outside/I1", "../outside/I2"});
  expectOneLine(escape, "DICOMDIR: Referenced File ID '..\\outside\\I1' leaves its folder (expected backslash-separated names within ");
  const std::string sizes = dir.file("sizes");
  test::writeSeries(sizes, "I", DicomStudy{}, model, zs, hu);
  DicomImage big = model;
  big.size = {20, 16};
  test::writeSeries(sizes, "J", DicomStudy{}, big, {{0.0, 0.0, 8.0}}, hu);
  expectOneLine(sizes, "holds images of two sizes, ");
  const std::string mixed = dir.file("mixed");
  test::writeSeries(mixed, "I", DicomStudy{}, model, zs, hu);
  DicomImage turned = model;
  const double coronal[6] = {1, 0, 0, 0, 0, -1};
  std::copy(std::begin(coronal), std::end(coronal), turned.cosines);
  test::writeSeries(mixed, "J", DicomStudy{}, turned, {{0.0, 0.0, 8.0}}, hu);
  expectOneLine(mixed, "differs from");
  const std::string nothing = dir.file("nothing");
  std::filesystem::create_directories(nothing);
  test::writeBytes(nothing + "/README", std::vector<uint8_t>(40, 'x'));
  test::writeStructuredReport(nothing + "/SR", DicomStudy{}, "1.2.3.4");
  expectOneLine(nothing, "no DICOM image series found (2 files: 1 not DICOM, 1 structured report;");
}


// What a user points at on a CD opens its series: the DICOMDIR (the largest series, or the one
// named), or one image (its own series, from its folder's files alone, whatever else is beside).
TEST(ClinicalDicom, ADicomdirOrOneImageOpensItsSeries) {
  TempDir dir;
  const Phantom ph;
  const auto hu = [&](const glm::dvec3& p) { return ph.hu(p); };
  const std::string root = dir.file("CD");
  DicomImage head;
  head.size = {16, 16};
  std::vector<glm::dvec3> zs;
  for (int k = 0; k < 8; ++k) zs.push_back({0.0, 0.0, 2.0 * k});
  test::writeSeries(root + "/S1/A", "I", DicomStudy{}, head, zs, hu);
  DicomImage chest = head;
  chest.seriesUid = "1.2.826.0.1.3680043.8.498.60";
  zs.resize(5);
  test::writeSeries(root + "/S1/B", "I", DicomStudy{}, chest, zs, hu);
  test::writeSeries(root + "/S1/B/copy", "I", DicomStudy{}, chest, zs, hu);  // beside it, not read with it
  std::vector<std::string> files;
  for (int k = 1; k <= 8; ++k) files.push_back("S1/A/I" + std::to_string(k));
  test::writeDicomdir(root, files);
  EXPECT_EQ(readVolume(root + "/DICOMDIR").dims(), glm::ivec3(16, 16, 8));
  EXPECT_EQ(readVolume(root + "/S1/B/I2").dims(), glm::ivec3(16, 16, 5));
  EXPECT_EQ(readVolume(root + "/S1/B/I2", nullptr, chest.seriesUid).dims(), glm::ivec3(16, 16, 5));
  EXPECT_EQ(detail::readAllPlanes(*openPlanes(root + "/S1/B/I2")).dims(), glm::ivec3(16, 16, 5));
  expectOneLine(root + "/S1/B/I2", "is an image of series '1.2.826.0.1.3680043.8.498.60' (expected its folder with --series", head.seriesUid);
  // A Series Number stands for its series when no other has it.
  const std::string numbered = dir.file("numbered");
  test::writeSeries(numbered, "A", DicomStudy{}, head, zs, hu);
  DicomImage seventh = head;
  seventh.seriesUid = "1.2.826.0.1.3680043.8.498.61";
  seventh.seriesNumber = 7;
  test::writeSeries(numbered, "C", DicomStudy{}, seventh, {zs[0], zs[1], zs[2]}, hu);
  EXPECT_EQ(readVolume(numbered, nullptr, "7").dims().z, 3);
  EXPECT_EQ(readVolume(numbered, nullptr, "2").dims().z, 5);
  chest.seriesNumber = 7;
  test::writeSeries(numbered, "B", DicomStudy{}, chest, zs, hu);
  expectOneLine(numbered, "--series 7: several series in " + numbered + " are numbered 7 (expected a UID: ", "7");
  const test::CliRun info = test::run({"info", root + "/DICOMDIR"});
  ASSERT_EQ(info.status, 0) << info.err;
  EXPECT_THAT(info.out, HasSubstr("(from its DICOMDIR)"));
  EXPECT_THAT(info.out, HasSubstr("dims     16 x 16 x 8"));
}

// The messages name what a user must fix: a whole 64-character UID to copy into --series, the
// transfer syntax not decoded (a deflated one is read), the file skipped where a slice is
// missing, an enhanced image's frames its functional groups do not cover.
TEST(ClinicalDicom, MessagesNameTheSyntaxTheSkippedFileAndTheFrame) {
  TempDir dir;
  const Phantom ph;
  const auto hu = [&](const glm::dvec3& p) { return ph.hu(p); };
  DicomImage model;
  model.size = {16, 16};
  std::vector<glm::dvec3> zs;
  for (int k = 0; k < 6; ++k) zs.push_back({0.0, 0.0, 2.0 * k});
  const std::string plain = dir.file("plain"), deflated = dir.file("deflated");
  test::writeSeries(plain, "I", DicomStudy{}, model, zs, hu);
  DicomImage packed = model;
  packed.transferSyntax = "1.2.840.10008.1.2.1.99";
  test::writeSeries(deflated, "I", DicomStudy{}, packed, zs, hu);
  EXPECT_TRUE(readBothWays(deflated).samples() == readVolume(plain).samples());
  // A copy of a slice beside it is left out, said once.
  std::filesystem::copy_file(deflated + "/I2", deflated + "/I2 copy");
  std::filesystem::copy_file(deflated + "/I4", deflated + "/I4 copy");
  const Volume copied = readBothWays(deflated);
  EXPECT_TRUE(copied.samples() == readVolume(plain).samples());
  ASSERT_EQ(copied.warnings().size(), 1u);
  EXPECT_THAT(copied.warnings()[0], HasSubstr(" copy is a copy of " + deflated + "/I"));
  EXPECT_THAT(copied.warnings()[0], HasSubstr(" (the same SOP Instance UID and position): left out, and 1 more copies"));
  const std::string part2 = dir.file("part2");
  DicomImage labelled = model;
  labelled.transferSyntax = "1.2.840.10008.1.2.4.92";
  test::writeSeries(part2, "I", DicomStudy{}, labelled, zs, hu);
  expectOneLine(part2, "transfer syntax 1.2.840.10008.1.2.4.92 (JPEG 2000 part 2 multi-component lossless) unsupported (expected uncompressed");
  const std::string uid = "1.2.826.0.1.3680043.8.498.12345678901234567890123456789012345678";
  ASSERT_EQ(uid.size(), 64u);
  DicomImage longUid = model;
  longUid.seriesUid = uid;
  test::writeSeries(plain + "/long", "I", DicomStudy{}, longUid, zs, hu);
  expectOneLine(plain, "'" + uid + "' (CT, HEAD 2.5, 6 slices", "1.2.3");
  std::filesystem::resize_file(plain + "/I3", 0);
  expectOneLine(plain, "; skipped in the series' folder: " + plain + "/I3: not DICOM", model.seriesUid);
  // Five frames declared, four items in the Per-frame Functional Groups (Number of Frames patched).
  std::vector<DicomImage> frames;
  for (int k = 0; k < 4; ++k) {
    DicomImage f = model;
    f.position = {0.0, 0.0, 2.0 * k};
    test::sampleField(&f, hu);
    frames.push_back(f);
  }
  const std::string enhanced = dir.file("enhanced");
  test::writeEnhancedCt(enhanced + "/E1", DicomStudy{}, frames);
  std::vector<uint8_t> bytes = test::readBytes(enhanced + "/E1");
  const uint8_t numberOfFrames[] = {0x28, 0x00, 0x08, 0x00, 'I', 'S', 2, 0, '4'};
  const auto at = std::search(bytes.begin(), bytes.end(), std::begin(numberOfFrames), std::end(numberOfFrames));
  ASSERT_NE(at, bytes.end());
  at[8] = '5';
  test::writeBytes(enhanced + "/E1", bytes);
  expectOneLine(enhanced, "E1: Per-frame Functional Groups Sequence (5200,9230) holds 4 items (expected one per frame: Number of Frames (0028,0008) is 5)");
}

}  // namespace
}  // namespace hyb
