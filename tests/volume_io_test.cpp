#include "volume/volume_io.h"

#include <archive.h>
#include <archive_entry.h>
#include <gdcmAttribute.h>
#include <gdcmImageChangeTransferSyntax.h>
#include <gdcmImageWriter.h>
#include <gdcmMediaStorage.h>
#include <gdcmTrace.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nifti1.h>
#include <nifti2_io.h>
#include <zlib.h>

#include <functional>
#include <iomanip>
#include <sstream>

#include "cli_util.h"
#include "test_util.h"
#include "volume/core/file_util.h"
#include "volume/plane_source.h"
#include "volume/reader_util.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;
using test::TempDir;
using test::toBytes;
using test::writeBytes;
using test::writeText;

// A small int16 volume with distinct, signed values: v(i,j,k) = 100k + 10j + i − 300.
constexpr glm::ivec3 kDims(4, 3, 5);
int16_t expectedValue(int i, int j, int k) { return int16_t(100 * k + 10 * j + i - 300); }
std::vector<int16_t> expectedSamples() {
  std::vector<int16_t> s;
  for (int k = 0; k < kDims.z; ++k)
    for (int j = 0; j < kDims.y; ++j)
      for (int i = 0; i < kDims.x; ++i) s.push_back(expectedValue(i, j, k));
  return s;
}

void expectExpectedVolume(const Volume& v, glm::dvec3 spacing, ScalarType type = ScalarType::Int16) {
  ASSERT_EQ(v.dims(), kDims);
  EXPECT_EQ(v.sourceType(), type);
  EXPECT_EQ(v.storedType(), ScalarType::Int16);  // two bytes a sample, as in the file
  EXPECT_EQ(v.bytesUsed(), v.voxelCount() * 2 + sizeof(Volume));
  EXPECT_DOUBLE_EQ(v.spacing().x, spacing.x);
  EXPECT_DOUBLE_EQ(v.spacing().y, spacing.y);
  EXPECT_DOUBLE_EQ(v.spacing().z, spacing.z);
  for (int k = 0; k < kDims.z; ++k)
    for (int j = 0; j < kDims.y; ++j)
      for (int i = 0; i < kDims.x; ++i) ASSERT_EQ(v.at(i, j, k), float(expectedValue(i, j, k))) << i << "," << j << "," << k;
  EXPECT_EQ(v.minValue(), -300.0f);
  EXPECT_EQ(v.maxValue(), float(expectedValue(3, 2, 4)));
}

std::vector<uint8_t> gzipBytes(const std::vector<uint8_t>& raw, const TempDir& dir) {
  const std::string tmp = dir.file("tmp.gz");
  gzFile f = gzopen(tmp.c_str(), "wb");
  gzwrite(f, raw.data(), unsigned(raw.size()));
  gzclose(f);
  return test::readBytes(tmp);
}

std::vector<uint8_t> zlibBytes(const std::vector<uint8_t>& raw) {
  uLongf size = compressBound(uLong(raw.size()));
  std::vector<uint8_t> out(size);
  compress2(out.data(), &size, raw.data(), uLong(raw.size()), 6);
  out.resize(size);
  return out;
}

std::vector<uint8_t> concat(const std::string& header, const std::vector<uint8_t>& data) {
  std::vector<uint8_t> b(header.size() + data.size());
  std::memcpy(b.data(), header.data(), header.size());
  if (!data.empty()) std::memcpy(b.data() + header.size(), data.data(), data.size());
  return b;
}

// The volume at @p path as a streamed build reads it: openPlanes(), every plane read in pieces of
// one, two, three … planes, twice (the second pass after rewind() must read the same samples).
Volume streamed(const std::string& path, const RawLayout* raw = nullptr) {
  const std::unique_ptr<PlaneSource> planes = openPlanes(path, raw);
  const size_t count = planes->planeSize() * size_t(planes->dims().z);
  std::vector<SampleArray> passes;
  for (int pass = 0; pass < 2; ++pass) {
    planes->rewind();
    SampleArray all = detail::allocateSamples(planes->storedType(), count);
    for (int z = 0, piece = 1; z < planes->dims().z; z += piece, ++piece) {
      piece = std::min(piece, planes->dims().z - z);
      planes->read(piece, &all, size_t(z) * planes->planeSize());
    }
    passes.push_back(std::move(all));
  }
  EXPECT_TRUE(passes[0] == passes[1]) << path << ": the second pass read other samples";
  return detail::filled(planes->description(), std::move(passes[0]), path);
}

// readVolume(@p path), checking that the streamed planes hold the same volume: samples, types,
// frame, info and warnings. @p streams: whether openPlanes() streams it rather than reading it whole.
Volume readBoth(const std::string& path, bool streams = true, const RawLayout* raw = nullptr) {
  Volume whole = readVolume(path, raw);
  EXPECT_EQ(!openPlanes(path, raw)->whole(), streams) << path;
  const Volume s = streamed(path, raw);
  EXPECT_EQ(s.dims(), whole.dims());
  EXPECT_EQ(s.sourceType(), whole.sourceType());
  EXPECT_TRUE(s.samples() == whole.samples()) << path;
  EXPECT_EQ(s.spacing(), whole.spacing());
  EXPECT_EQ(s.frame().direction, whole.frame().direction);
  EXPECT_EQ(s.frame().origin, whole.frame().origin);
  EXPECT_EQ(s.frame().assumed, whole.frame().assumed);
  EXPECT_EQ(s.info(), whole.info());
  EXPECT_EQ(s.warnings(), whole.warnings());
  return whole;
}

// Expects readVolume(path), and reading it plane by plane, to throw an hyb::Error whose message
// names @p named and contains @p what.
void expectRejected(const std::string& path, const std::string& named, const std::string& what,
                    const RawLayout* raw = nullptr) {
  for (const bool stream : {false, true}) {
    try {
      if (stream) streamed(path, raw);
      else readVolume(path, raw);
      ADD_FAILURE() << path << " was accepted" << (stream ? " plane by plane" : "") << "; expected an error containing '" << what << "'";
    } catch (const Error& e) {
      const std::string msg = e.what();
      EXPECT_THAT(msg, HasSubstr(named));
      EXPECT_THAT(msg, HasSubstr(what));
      EXPECT_EQ(msg.find('\n'), std::string::npos) << "message must be one line: " << msg;
    }
  }
}

// Patient space: every reader keeps the index-to-patient transform (LPS), from files written by
// the tests with known directions and origins: a flip, a permutation and an oblique rotation.
struct Geometry {
  const char* name;
  glm::dmat3 direction;  // columns: the i, j, k axes in LPS
  glm::dvec3 origin;     // LPS mm
};

glm::dmat3 rotation(double xDeg, double zDeg) {
  const double a = glm::radians(xDeg), b = glm::radians(zDeg);
  const glm::dmat3 rx(glm::dvec3(1, 0, 0), glm::dvec3(0, std::cos(a), std::sin(a)), glm::dvec3(0, -std::sin(a), std::cos(a)));
  const glm::dmat3 rz(glm::dvec3(std::cos(b), std::sin(b), 0), glm::dvec3(-std::sin(b), std::cos(b), 0), glm::dvec3(0, 0, 1));
  return rx * rz;
}

std::vector<Geometry> geometries() {
  return {{"flip (LAS)", glm::dmat3(glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1)), {10, -20, 30}},
          {"permutation (SLP)", glm::dmat3(glm::dvec3(0, 0, 1), glm::dvec3(1, 0, 0), glm::dvec3(0, 1, 0)), {-5, 7.5, 100}},
          {"oblique", rotation(20, 30), {1.25, 2.5, -3.75}}};
}

const glm::dvec3 kSpacing(0.5, 0.75, 2.5);

void expectFrame(const Volume& v, const Geometry& g, double tolerance) {
  for (int c = 0; c < 3; ++c) {
    for (int r = 0; r < 3; ++r) EXPECT_NEAR(v.frame().direction[c][r], g.direction[c][r], tolerance) << g.name << " axis " << c;
    EXPECT_NEAR(v.frame().origin[c], g.origin[c], tolerance * 100) << g.name;
    EXPECT_NEAR(v.spacing()[c], kSpacing[c], tolerance) << g.name;
  }
}

std::string vec(const glm::dvec3& v, const char* open = "(", const char* sep = ",", const char* close = ")") {
  std::ostringstream s;
  s << std::setprecision(17) << open << v.x << sep << v.y << sep << v.z << close;
  return s.str();
}

const char* kNrrdHeader =
    "NRRD0004\n# a comment\ntype: short\ndimension: 3\nsizes: 4 3 5\nspacings: 0.5 0.75 2.5\n";

std::vector<uint8_t> niftiFile(float slope, float inter, const std::vector<uint8_t>& data) {
  nifti_1_header h{};
  h.sizeof_hdr = 348;
  h.dim[0] = 3;
  h.dim[1] = short(kDims.x);
  h.dim[2] = short(kDims.y);
  h.dim[3] = short(kDims.z);
  for (int d = 4; d < 8; ++d) h.dim[d] = 1;
  h.datatype = DT_INT16;
  h.bitpix = 16;
  h.pixdim[0] = 1.0f;
  h.pixdim[1] = 0.5f;
  h.pixdim[2] = 0.75f;
  h.pixdim[3] = 2.5f;
  h.vox_offset = 352.0f;
  h.scl_slope = slope;
  h.scl_inter = inter;
  std::memcpy(h.magic, "n+1\0", 4);
  std::vector<uint8_t> b(352 + data.size(), 0);
  std::memcpy(b.data(), &h, sizeof h);
  if (!data.empty()) std::memcpy(b.data() + 352, data.data(), data.size());
  return b;
}

void writeInv3(const std::string& path, const std::string& plist, const std::vector<uint8_t>& matrix) {
  archive* a = archive_write_new();
  archive_write_add_filter_gzip(a);
  archive_write_set_format_pax_restricted(a);
  archive_write_open_filename(a, path.c_str());
  auto add = [&](const std::string& name, const void* data, size_t size) {
    archive_entry* e = archive_entry_new();
    archive_entry_set_pathname(e, name.c_str());
    archive_entry_set_size(e, la_int64_t(size));
    archive_entry_set_filetype(e, AE_IFREG);
    archive_entry_set_perm(e, 0644);
    archive_write_header(a, e);
    archive_write_data(a, data, size);
    archive_entry_free(e);
  };
  add("proj/main.plist", plist.data(), plist.size());
  add("proj/matrix.dat", matrix.data(), matrix.size());
  archive_write_close(a);
  archive_write_free(a);
}

std::string inv3Plist(const std::string& shape) {
  return "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<plist version=\"1.0\">\n<dict>\n"
         "<key>matrix</key><dict><key>dtype</key><string>int16</string><key>filename</key><string>matrix.dat</string>"
         "<key>shape</key><array>" + shape + "</array></dict>\n"
         "<key>modality</key><string>CT</string>\n"
         "<key>spacing</key><array><real>0.5</real><real>0.75</real><real>2.5</real></array>\n</dict>\n</plist>\n";
}

// The pixel module and rescale of a synthetic DICOM slice (by default a CT's: int16, HU + 1024).
struct DicomPixels {
  gdcm::PixelFormat::ScalarType type = gdcm::PixelFormat::INT16;
  unsigned short bitsStored = 16;
  double slope = 1.0, intercept = -1024.0;
  bool rle = false;  // RLE Lossless (encapsulated) rather than Implicit VR Little Endian
};

// One CT slice of kDims.x x kDims.y pixels (@p bytes, little-endian, of @p format) at Image
// Position @p position with Image Orientation @p cosines (rows' direction, then columns').
void writeDicomImage(const std::string& path, const std::vector<uint8_t>& bytes, const DicomPixels& format, const glm::dvec3& position,
                     const std::string& seriesUid, const double (&cosines)[6] = {1, 0, 0, 0, 1, 0}, const std::string& description = "") {
  gdcm::Trace::WarningOff();  // the writer warns of the tags it fills in itself
  gdcm::ImageWriter w;
  gdcm::Image& im = w.GetImage();
  im.SetNumberOfDimensions(2);
  im.SetDimension(0, unsigned(kDims.x));
  im.SetDimension(1, unsigned(kDims.y));
  im.SetSpacing(0, 0.5);
  im.SetSpacing(1, 0.75);
  for (unsigned a = 0; a < 3; ++a) im.SetOrigin(a, position[int(a)]);
  im.SetDirectionCosines(cosines);
  gdcm::PixelFormat pf(format.type);
  pf.SetBitsStored(format.bitsStored);
  pf.SetHighBit(uint16_t(format.bitsStored - 1));
  im.SetPixelFormat(pf);
  im.SetPhotometricInterpretation(gdcm::PhotometricInterpretation::MONOCHROME2);
  im.SetSlope(format.slope);
  im.SetIntercept(format.intercept);
  gdcm::DataElement pixelData(gdcm::Tag(0x7fe0, 0x0010));
  pixelData.SetByteValue(reinterpret_cast<const char*>(bytes.data()), uint32_t(bytes.size()));
  im.SetDataElement(pixelData);
  if (format.rle) {
    gdcm::ImageChangeTransferSyntax change;
    change.SetTransferSyntax(gdcm::TransferSyntax::RLELossless);
    change.SetInput(im);
    ASSERT_TRUE(change.Change()) << path;
    im = change.GetOutput();
  }
  gdcm::DataSet& ds = w.GetFile().GetDataSet();
  gdcm::Attribute<0x0008, 0x0016> sopClass;
  sopClass.SetValue(gdcm::MediaStorage::GetMSString(gdcm::MediaStorage::CTImageStorage));
  ds.Replace(sopClass.GetAsDataElement());
  gdcm::Attribute<0x0008, 0x0060> modality;
  modality.SetValue("CT");
  ds.Replace(modality.GetAsDataElement());
  gdcm::Attribute<0x0020, 0x000e> series;
  series.SetValue(seriesUid);
  ds.Replace(series.GetAsDataElement());
  gdcm::Attribute<0x0020, 0x000d> study;  // one study, as a scanner writes it (GDCM would make one a file)
  study.SetValue("1.2.826.0.1.3680043.8.498.7");
  ds.Replace(study.GetAsDataElement());
  if (!description.empty()) {
    gdcm::Attribute<0x0008, 0x103e> text;
    text.SetValue(description);
    ds.Replace(text.GetAsDataElement());
  }
  gdcm::Attribute<0x0018, 0x0050> thickness;
  thickness.SetValue(2.0);
  ds.Replace(thickness.GetAsDataElement());
  w.SetFileName(path.c_str());
  ASSERT_TRUE(w.Write()) << path;
}

// One CT slice of int16 pixels, Hounsfield units + 1024 (rescale intercept −1024).
void writeDicomSlice(const std::string& path, const std::vector<int16_t>& pixels, const glm::dvec3& position, const std::string& seriesUid,
                     const double (&cosines)[6] = {1, 0, 0, 0, 1, 0}, const std::string& description = "") {
  writeDicomImage(path, toBytes(pixels), DicomPixels{}, position, seriesUid, cosines, description);
}

// Slice k of the expected samples, stored as HU + 1024.
// "a3.dcm" (built by ostream: GCC 12's -Wrestrict misfires on "a" + std::to_string(k) when inlined).
std::string sliceName(const char* prefix, int k) {
  std::ostringstream name;
  name << prefix << k << ".dcm";
  return name.str();
}

std::vector<int16_t> storedSlice(int k) {
  const auto all = expectedSamples();
  const size_t slice = size_t(kDims.x) * kDims.y;
  std::vector<int16_t> px(all.begin() + ptrdiff_t(size_t(k) * slice), all.begin() + ptrdiff_t(size_t(k + 1) * slice));
  for (int16_t& p : px) p = int16_t(p + 1024);
  return px;
}

// A NIfTI-1 header with the given sform (RAS rows, code 1) and/or qform (code 1).
std::vector<uint8_t> orientedNifti(const std::vector<uint8_t>& data, const glm::dmat3* sformDirection, const glm::dvec3& sformOrigin,
                                   const glm::dmat3* qformDirection, const glm::dvec3& qformOrigin) {
  std::vector<uint8_t> b = niftiFile(0.0f, 0.0f, data);
  nifti_1_header h;
  std::memcpy(&h, b.data(), sizeof h);
  h.xyzt_units = NIFTI_UNITS_MM;
  if (sformDirection) {
    h.sform_code = NIFTI_XFORM_SCANNER_ANAT;
    float* rows[3] = {h.srow_x, h.srow_y, h.srow_z};
    const glm::dvec3 o = rasToLps(sformOrigin);
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) rows[r][c] = float(rasToLps((*sformDirection)[c])[r] * kSpacing[c]);
      rows[r][3] = float(o[r]);
    }
  }
  if (qformDirection) {
    // The quaternion of the RAS rotation; a left-handed one stores qfac = −1 and its third column negated.
    glm::dmat3 r;
    for (int c = 0; c < 3; ++c) r[c] = rasToLps((*qformDirection)[c]);
    h.pixdim[0] = glm::determinant(r) < 0 ? -1.0f : 1.0f;
    if (h.pixdim[0] < 0) r[2] = -r[2];
    // (a, b, c, d) from the largest of the four diagonal combinations (R[row][col] = r[col][row]).
    auto R = [&](int row, int col) { return r[col][row]; };
    const double t[4] = {1 + R(0, 0) + R(1, 1) + R(2, 2), 1 + R(0, 0) - R(1, 1) - R(2, 2), 1 - R(0, 0) + R(1, 1) - R(2, 2),
                         1 - R(0, 0) - R(1, 1) + R(2, 2)};
    const int k = int(std::max_element(t, t + 4) - t);
    const double s = 0.5 / std::sqrt(t[k]);
    double q[4] = {0, 0, 0, 0};  // a, b, c, d
    if (k == 0) q[0] = 0.25 / s, q[1] = (R(2, 1) - R(1, 2)) * s, q[2] = (R(0, 2) - R(2, 0)) * s, q[3] = (R(1, 0) - R(0, 1)) * s;
    if (k == 1) q[1] = 0.25 / s, q[0] = (R(2, 1) - R(1, 2)) * s, q[2] = (R(0, 1) + R(1, 0)) * s, q[3] = (R(0, 2) + R(2, 0)) * s;
    if (k == 2) q[2] = 0.25 / s, q[0] = (R(0, 2) - R(2, 0)) * s, q[1] = (R(0, 1) + R(1, 0)) * s, q[3] = (R(1, 2) + R(2, 1)) * s;
    if (k == 3) q[3] = 0.25 / s, q[0] = (R(1, 0) - R(0, 1)) * s, q[1] = (R(0, 2) + R(2, 0)) * s, q[2] = (R(1, 2) + R(2, 1)) * s;
    const double sign = q[0] < 0 ? -1.0 : 1.0;  // NIfTI keeps a >= 0
    h.qform_code = NIFTI_XFORM_SCANNER_ANAT;
    h.quatern_b = float(sign * q[1]);
    h.quatern_c = float(sign * q[2]);
    h.quatern_d = float(sign * q[3]);
    const glm::dvec3 o = rasToLps(qformOrigin);
    h.qoffset_x = float(o.x);
    h.qoffset_y = float(o.y);
    h.qoffset_z = float(o.z);
  }
  std::memcpy(b.data(), &h, sizeof h);
  return b;
}

TEST(NrrdReader, AttachedRawLittleEndian) {
  TempDir dir;
  const std::string path = dir.file("v.nrrd");
  writeBytes(path, concat(std::string(kNrrdHeader) + "endian: little\nencoding: raw\n\n", toBytes(expectedSamples())));
  expectExpectedVolume(readBoth(path), {0.5, 0.75, 2.5});
}

TEST(NrrdReader, DetachedRawBigEndianWithSpaceDirections) {
  TempDir dir;
  writeBytes(dir.file("v.raw"), toBytes(expectedSamples(), true));
  writeText(dir.file("v.nhdr"),
            "NRRD0005\ntype: int16\ndimension: 3\nspace: left-posterior-superior\nsizes: 4 3 5\n"
            "space directions: (0.5,0,0) (0,0.75,0) (0,0,2.5)\nendian: big\nencoding: raw\ndata file: v.raw\n");
  expectExpectedVolume(readBoth(dir.file("v.nhdr")), {0.5, 0.75, 2.5});
}

TEST(NrrdReader, GzipAttachedAndDetached) {
  TempDir dir;
  const auto gz = gzipBytes(toBytes(expectedSamples()), dir);
  writeBytes(dir.file("a.nrrd"), concat(std::string(kNrrdHeader) + "endian: little\nencoding: gzip\n\n", gz));
  expectExpectedVolume(readBoth(dir.file("a.nrrd")), {0.5, 0.75, 2.5});
  writeBytes(dir.file("d.raw.gz"), gz);
  writeText(dir.file("d.nhdr"), std::string(kNrrdHeader) + "endian: little\nencoding: gz\ndata file: d.raw.gz\n");
  expectExpectedVolume(readBoth(dir.file("d.nhdr")), {0.5, 0.75, 2.5});
}

TEST(NrrdReader, AsciiAndByteSkipAndUint8) {
  TempDir dir;
  std::string text;
  for (int16_t v : expectedSamples()) text += std::to_string(v) + " ";
  writeText(dir.file("t.nrrd"), std::string(kNrrdHeader) + "encoding: ascii\n\n" + text);
  expectExpectedVolume(readBoth(dir.file("t.nrrd"), false), {0.5, 0.75, 2.5});

  std::vector<uint8_t> raw = {9, 9, 9};  // three bytes to skip
  for (int i = 0; i < 8; ++i) raw.push_back(uint8_t(250 + i % 6));
  writeBytes(dir.file("u.raw"), raw);
  writeText(dir.file("u.nhdr"), "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\nbyte skip: 3\ndata file: u.raw\n");
  const Volume v = readBoth(dir.file("u.nhdr"));
  EXPECT_EQ(v.sourceType(), ScalarType::UInt8);
  EXPECT_EQ(v.at(0, 0, 0), 250.0f);
  EXPECT_EQ(v.at(1, 1, 1), 251.0f);  // index 7 -> 250 + 7 % 6
  EXPECT_EQ(v.spacing(), glm::dvec3(1.0));
}

TEST(NrrdReader, RejectsMalformedFiles) {
  TempDir dir;
  const auto data = toBytes(expectedSamples());
  auto nhdr = [&](const std::string& name, const std::string& fields, const std::vector<uint8_t>& raw) {
    writeBytes(dir.file(name + ".raw"), raw);
    writeText(dir.file(name + ".nhdr"), "NRRD0004\n" + fields + "data file: " + name + ".raw\n");
    return dir.file(name + ".nhdr");
  };
  const std::string good = "type: short\ndimension: 3\nsizes: 4 3 5\nendian: little\nencoding: raw\n";
  std::vector<uint8_t> shorter(data.begin(), data.end() - 7), longer = data;
  longer.resize(data.size() + 10);
  expectRejected(nhdr("trunc", good, shorter), "trunc.raw", "truncated data: expected 120 bytes");
  expectRejected(nhdr("long", good, longer), "long.raw", "header/data size mismatch");
  expectRejected(nhdr("zero", "type: short\ndimension: 3\nsizes: 4 0 5\nendian: little\nencoding: raw\n", data), "zero.nhdr", "sizes");
  expectRejected(nhdr("neg", "type: short\ndimension: 3\nsizes: 4 -3 5\nendian: little\nencoding: raw\n", data), "neg.nhdr", "sizes");
  expectRejected(nhdr("ovf", "type: short\ndimension: 3\nsizes: 30000 30000 30000\nendian: little\nencoding: raw\n", data),
                 "ovf.nhdr", "more than the limit");
  expectRejected(nhdr("big", "type: short\ndimension: 3\nsizes: 99999999999 2 2\nendian: little\nencoding: raw\n", data),
                 "big.nhdr", "sizes");
  expectRejected(nhdr("type", "type: quaternion\ndimension: 3\nsizes: 4 3 5\nendian: little\nencoding: raw\n", data),
                 "type.nhdr", "unknown or unsupported type");
  expectRejected(nhdr("dim", "type: short\ndimension: 2\nsizes: 4 3\nendian: little\nencoding: raw\n", data), "dim.nhdr",
                 "dimension");
  expectRejected(nhdr("end", "type: short\ndimension: 3\nsizes: 4 3 5\nencoding: raw\n", data), "end.nhdr", "endian");
  expectRejected(nhdr("enc", "type: short\ndimension: 3\nsizes: 4 3 5\nendian: little\nencoding: bzip2\n", data), "enc.nhdr",
                 "encoding 'bzip2' unsupported");
  std::vector<float> nan = {1.0f, std::nanf(""), 3.0f, 4.0f, 5.0f, 6.0f, 7.0f, 8.0f};
  expectRejected(nhdr("nan", "type: float\ndimension: 3\nsizes: 2 2 2\nendian: little\nencoding: raw\n", toBytes(nan)),
                 "nan.nhdr", "sample (1,0,0) is nan; expected finite values");
  std::vector<float> wide = {-3e38f, 3e38f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
  expectRejected(nhdr("wide", "type: float\ndimension: 3\nsizes: 2 2 2\nendian: little\nencoding: raw\n", toBytes(wide)),
                 "wide.nhdr", "expected a range (max - min) below");
  writeText(dir.file("missing.nhdr"), "NRRD0004\n" + good + "data file: nowhere.raw\n");
  expectRejected(dir.file("missing.nhdr"), "missing.nhdr", "data file '" + dir.file("nowhere.raw") + "' does not exist");
  writeText(dir.file("magic.nrrd"), "P6\n4 4\n255\n");
  expectRejected(dir.file("magic.nrrd"), "magic.nrrd", "not a NRRD file");
  const auto gz = gzipBytes(data, dir);
  writeBytes(dir.file("tgz.nrrd"), concat(std::string(kNrrdHeader) + "endian: little\nencoding: gzip\n\n",
                                          std::vector<uint8_t>(gz.begin(), gz.begin() + ptrdiff_t(gz.size() / 2))));
  expectRejected(dir.file("tgz.nrrd"), "tgz.nrrd", "truncated compressed data");
  expectRejected(dir.file("absent.nrrd"), "absent.nrrd", "does not exist");
  expectRejected(dir.file("x.vtk"), "x.vtk", "does not exist");
  writeText(dir.file("x.vtk"), "vtk");
  expectRejected(dir.file("x.vtk"), "x.vtk", "unknown volume format");
}

TEST(MetaImageReader, DetachedLocalAndCompressed) {
  TempDir dir;
  const auto data = toBytes(expectedSamples());
  const std::string header =
      "ObjectType = Image\nNDims = 3\nDimSize = 4 3 5\nElementSpacing = 0.5 0.75 2.5\nElementType = MET_SHORT\n";
  writeBytes(dir.file("v.raw"), data);
  writeText(dir.file("v.mhd"), header + "ElementByteOrderMSB = False\nElementDataFile = v.raw\n");
  expectExpectedVolume(readBoth(dir.file("v.mhd")), {0.5, 0.75, 2.5});

  writeBytes(dir.file("l.mha"), concat(header + "BinaryDataByteOrderMSB = True\nElementDataFile = LOCAL\n",
                                       toBytes(expectedSamples(), true)));
  expectExpectedVolume(readBoth(dir.file("l.mha")), {0.5, 0.75, 2.5});

  const auto z = zlibBytes(data);
  writeBytes(dir.file("c.mha"), concat(header + "CompressedData = True\nCompressedDataSize = " + std::to_string(z.size()) +
                                           "\nElementDataFile = LOCAL\n", z));
  expectExpectedVolume(readBoth(dir.file("c.mha")), {0.5, 0.75, 2.5});
}

TEST(MetaImageReader, RejectsMalformedFiles) {
  TempDir dir;
  const auto data = toBytes(expectedSamples());
  writeBytes(dir.file("v.raw"), std::vector<uint8_t>(data.begin(), data.begin() + 50));
  writeText(dir.file("t.mhd"), "NDims = 3\nDimSize = 4 3 5\nElementType = MET_SHORT\nElementDataFile = v.raw\n");
  expectRejected(dir.file("t.mhd"), "v.raw", "truncated data");
  writeText(dir.file("u.mhd"), "NDims = 3\nDimSize = 4 3 5\nElementType = MET_LONG_LONG\nElementDataFile = v.raw\n");
  expectRejected(dir.file("u.mhd"), "u.mhd", "ElementType 'MET_LONG_LONG' unsupported");
  writeText(dir.file("m.mhd"), "NDims = 3\nDimSize = 4 3 5\nElementDataFile = v.raw\n");
  expectRejected(dir.file("m.mhd"), "m.mhd", "missing required field 'ElementType'");
  writeText(dir.file("d.mhd"), "NDims = 3\nDimSize = 4 3\nElementType = MET_SHORT\nElementDataFile = v.raw\n");
  expectRejected(dir.file("d.mhd"), "d.mhd", "DimSize");
  writeText(dir.file("s.mhd"), "NDims = 3\nDimSize = 4 3 5\nElementSpacing = 1 0 1\nElementType = MET_SHORT\nElementDataFile = v.raw\n");
  expectRejected(dir.file("s.mhd"), "s.mhd", "spacing");
}

TEST(NiftiReader, PlainGzipAndScaling) {
  TempDir dir;
  const auto data = toBytes(expectedSamples());
  // Plain, gzip and big-endian files stream plane by plane, and give what nifti_clib reads whole.
  writeBytes(dir.file("v.nii"), niftiFile(0.0f, 0.0f, data));
  expectExpectedVolume(readBoth(dir.file("v.nii")), {0.5, 0.75, 2.5});
  writeBytes(dir.file("v.nii.gz"), gzipBytes(niftiFile(1.0f, 0.0f, data), dir));
  expectExpectedVolume(readBoth(dir.file("v.nii.gz")), {0.5, 0.75, 2.5});
  std::vector<uint8_t> big = niftiFile(0.0f, 0.0f, data);
  nifti_1_header h;
  std::memcpy(&h, big.data(), sizeof h);
  nifti_swap_as_nifti1(&h);
  std::memcpy(big.data(), &h, sizeof h);
  for (size_t i = 352; i + 1 < big.size(); i += 2) std::swap(big[i], big[i + 1]);
  writeBytes(dir.file("big.nii"), big);
  expectExpectedVolume(readBoth(dir.file("big.nii")), {0.5, 0.75, 2.5});
  // Rescaled samples may change their stored type: read whole.
  writeBytes(dir.file("s.nii"), niftiFile(2.0f, -1024.0f, data));
  const Volume s = readBoth(dir.file("s.nii"), false);
  EXPECT_EQ(s.at(1, 2, 3), 2.0f * expectedValue(1, 2, 3) - 1024.0f);
  EXPECT_EQ(s.storedType(), ScalarType::Int16);  // integer scaling of integers stays in 16 bits
  writeBytes(dir.file("f.nii"), niftiFile(0.5f, 0.25f, data));
  const Volume f = readVolume(dir.file("f.nii"));
  EXPECT_EQ(f.at(1, 2, 3), 0.5f * expectedValue(1, 2, 3) + 0.25f);
  EXPECT_EQ(f.storedType(), ScalarType::Float32);
}

// Every sample type is held in the narrowest of uint8, int8, uint16, int16 and float32 that keeps
// its values exact (32-bit integers by their range), and reads back exactly.
TEST(NiftiWriter, EveryStoredTypeAndFrameReadsBackAsWritten) {
  TempDir dir;
  const std::vector<std::pair<SampleArray, int>> cases = {
      {std::vector<uint8_t>{0, 7, 255, 128}, DT_UINT8},         {std::vector<int8_t>{-128, 0, 127, -5}, DT_INT8},
      {std::vector<uint16_t>{0, 65535, 4095, 1}, DT_UINT16},    {std::vector<int16_t>{-32768, 32767, -1024, 3071}, DT_INT16},
      {std::vector<float>{-0.5f, 1e-3f, 2.25f, 3e5f}, DT_FLOAT32}};
  for (const Geometry& g : geometries()) {
    for (const auto& [samples, datatype] : cases) {
      Volume v({2, 2, 1}, kSpacing, storedType(samples), samples, "v");
      v.setFrame(makePatientFrame(g.direction, g.origin, g.name));
      for (const char* name : {"v.nii", "v.nii.gz"}) {
        SCOPED_TRACE(std::string(g.name) + " " + scalarName(v.storedType()) + " " + name);
        writeVolume(v, dir.file(name));
        const Volume back = readVolume(dir.file(name));
        EXPECT_EQ(back.storedType(), v.storedType());
        for (size_t n = 0; n < 4; ++n) EXPECT_EQ(back.value(n), v.value(n)) << n;
        expectFrame(back, g, 1e-6);
        EXPECT_TRUE(back.warnings().empty());
        // Both transforms set, the same: the quaternion (qfac for a left-handed grid) gives the sform's matrix.
        std::unique_ptr<nifti_image, void (*)(nifti_image*)> nim(nifti_image_read(dir.file(name).c_str(), 0), nifti_image_free);
        ASSERT_TRUE(nim);
        EXPECT_EQ(nim->datatype, datatype);
        EXPECT_EQ(nim->sform_code, NIFTI_XFORM_SCANNER_ANAT);
        EXPECT_EQ(nim->qform_code, NIFTI_XFORM_SCANNER_ANAT);
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 4; ++c) EXPECT_NEAR(nim->qto_xyz.m[r][c], nim->sto_xyz.m[r][c], 1e-5) << r << "," << c;
      }
    }
  }
  // A frame the reader assumed is written as aligned (code 2), not the scanner's.
  Volume assumed({2, 2, 1}, kSpacing, ScalarType::UInt8, std::vector<uint8_t>(4, 1), "v");
  PatientFrame f;
  f.assumed = true;
  assumed.setFrame(f);
  writeVolume(assumed, dir.file("a.nii"));
  std::unique_ptr<nifti_image, void (*)(nifti_image*)> nim(nifti_image_read(dir.file("a.nii").c_str(), 0), nifti_image_free);
  ASSERT_TRUE(nim);
  EXPECT_EQ(nim->sform_code, NIFTI_XFORM_ALIGNED_ANAT);
  // An axis longer than NIfTI-1's dim[] holds, and an extension without a writer: refused naming the file, nothing left.
  const Volume wide({32768, 1, 1}, kSpacing, ScalarType::UInt8, std::vector<uint8_t>(32768, 0), "wide");
  try {
    writeVolume(wide, dir.file("w.nii"));
    ADD_FAILURE() << "32768 voxels along x written";
  } catch (const IoError& e) {
    EXPECT_THAT(e.what(), HasSubstr("w.nii: 32768x1x1 voxels do not fit NIfTI-1 (expected at most 32767 per axis)"));
  }
  EXPECT_THROW(writeVolume(assumed, dir.file("v.mha")), IoError);
  EXPECT_FALSE(std::filesystem::exists(dir.file("w.nii")));
  EXPECT_FALSE(std::filesystem::exists(dir.file("v.mha")));
}

TEST(VolumeReaders, SamplesAreHeldInTheirOwnTypeOrTheNarrowestExactOne) {
  TempDir dir;
  struct Case {
    const char* nrrdType;
    std::vector<double> values;
    ScalarType source, stored;
  };
  const std::vector<Case> cases = {
      {"uint8", {0, 7, 255, 128}, ScalarType::UInt8, ScalarType::UInt8},
      {"int8", {-128, 0, 127, -5}, ScalarType::Int8, ScalarType::Int8},
      {"uint16", {0, 65535, 4095, 1}, ScalarType::UInt16, ScalarType::UInt16},
      {"int16", {-32768, 32767, -1024, 3071}, ScalarType::Int16, ScalarType::Int16},
      {"int32", {-1024, 3071, 0, 12}, ScalarType::Int32, ScalarType::Int16},
      {"uint32", {0, 65535, 40000, 3}, ScalarType::UInt32, ScalarType::UInt16},
      {"int32", {-70000, 5, 0, 16777216}, ScalarType::Int32, ScalarType::Float32},
      {"float", {-0.5, 1e-3, 2.25, 3e5}, ScalarType::Float32, ScalarType::Float32},
      {"double", {-0.5, 0.125, 2.25, 1024}, ScalarType::Float64, ScalarType::Float32},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(std::string(c.nrrdType) + " -> " + scalarName(c.stored));
    std::vector<uint8_t> raw;
    for (double v : c.values) {
      uint8_t b[8];
      switch (c.source) {
        case ScalarType::UInt8: b[0] = uint8_t(v); break;
        case ScalarType::Int8: { const int8_t x = int8_t(v); std::memcpy(b, &x, 1); break; }
        case ScalarType::UInt16: { const uint16_t x = uint16_t(v); std::memcpy(b, &x, 2); break; }
        case ScalarType::Int16: { const int16_t x = int16_t(v); std::memcpy(b, &x, 2); break; }
        case ScalarType::UInt32: { const uint32_t x = uint32_t(v); std::memcpy(b, &x, 4); break; }
        case ScalarType::Int32: { const int32_t x = int32_t(v); std::memcpy(b, &x, 4); break; }
        case ScalarType::Float32: { const float x = float(v); std::memcpy(b, &x, 4); break; }
        case ScalarType::Float64: std::memcpy(b, &v, 8); break;
      }
      raw.insert(raw.end(), b, b + scalarSize(c.source));
    }
    const std::string header = std::string("NRRD0004\ntype: ") + c.nrrdType + "\ndimension: 3\nsizes: 2 2 1\nendian: little\n";
    writeBytes(dir.file("r.nrrd"), concat(header + "encoding: raw\n\n", raw));
    writeBytes(dir.file("g.nrrd"), concat(header + "encoding: gzip\n\n", gzipBytes(raw, dir)));
    std::string text;
    for (double v : c.values) text += std::to_string(v) + " ";
    writeText(dir.file("t.nrrd"), header + "encoding: ascii\n\n" + text);
    for (const char* file : {"r.nrrd", "g.nrrd", "t.nrrd"}) {
      // Planes stream but for text and 32-bit integers, whose stored type depends on their range.
      const bool streams = std::string(file) != "t.nrrd" && c.source != ScalarType::Int32 && c.source != ScalarType::UInt32;
      const Volume v = readBoth(dir.file(file), streams);
      EXPECT_EQ(v.sourceType(), c.source) << file;
      EXPECT_EQ(v.storedType(), c.stored) << file;
      for (size_t i = 0; i < c.values.size(); ++i) EXPECT_EQ(v.value(i), float(c.values[i])) << file << " sample " << i;
    }
  }
}

TEST(NiftiReader, RejectsTruncatedAndGarbage) {
  TempDir dir;
  const auto data = toBytes(expectedSamples());
  writeBytes(dir.file("t.nii"), niftiFile(0.0f, 0.0f, std::vector<uint8_t>(data.begin(), data.begin() + 40)));
  expectRejected(dir.file("t.nii"), "t.nii", "NIfTI");
  writeText(dir.file("g.nii"), std::string(400, 'x'));
  expectRejected(dir.file("g.nii"), "g.nii", "NIfTI");
}

TEST(RawReader, LayoutsAndSizeChecks) {
  TempDir dir;
  writeBytes(dir.file("v.bin"), toBytes(expectedSamples(), true));
  RawLayout l;
  l.dims = kDims;
  l.type = ScalarType::Int16;
  l.spacing = {0.5, 0.75, 2.5};
  l.bigEndian = true;
  expectExpectedVolume(readBoth(dir.file("v.bin"), true, &l), {0.5, 0.75, 2.5});
  l.dims = {4, 3, 6};
  expectRejected(dir.file("v.bin"), "v.bin", "truncated data: expected 144 bytes for 4x3x6 int16, found 120", &l);
  l.dims = {4, 3, 4};
  expectRejected(dir.file("v.bin"), "v.bin", "header/data size mismatch", &l);
  l.dims = {4, 0, 4};
  expectRejected(dir.file("v.bin"), "--raw-dims", "must all be positive", &l);
  l.dims = kDims;
  l.spacing = {1, -1, 1};
  expectRejected(dir.file("v.bin"), "--raw-spacing", "finite and positive", &l);
  expectRejected(dir.file("v.raw"), "v.raw", "does not exist");
  writeText(dir.file("v.raw"), "x");
  expectRejected(dir.file("v.raw"), "v.raw", "--raw-dims");
}

TEST(Inv3Reader, SyntheticProjectInCOrder) {
  TempDir dir;
  writeInv3(dir.file("p.inv3"), inv3Plist("<integer>5</integer><integer>3</integer><integer>4</integer>"),
            toBytes(expectedSamples()));
  expectExpectedVolume(readVolume(dir.file("p.inv3")), {0.5, 0.75, 2.5});
}

TEST(Inv3Reader, RejectsBrokenProjects) {
  TempDir dir;
  writeInv3(dir.file("s.inv3"), inv3Plist("<integer>6</integer><integer>3</integer><integer>4</integer>"),
            toBytes(expectedSamples()));
  expectRejected(dir.file("s.inv3"), "s.inv3", "truncated data");
  writeInv3(dir.file("m.inv3"), "<plist><dict></dict></plist>", toBytes(expectedSamples()));
  expectRejected(dir.file("m.inv3"), "m.inv3", "lacks matrix");
  writeInv3(dir.file("x.inv3"), "<plist><dict><key>matrix</key><array>", toBytes(expectedSamples()));
  expectRejected(dir.file("x.inv3"), "x.inv3", "malformed property list");
  const auto whole = test::readBytes(dir.file("s.inv3"));
  writeBytes(dir.file("cut.inv3"), std::vector<uint8_t>(whole.begin(), whole.begin() + ptrdiff_t(whole.size() / 2)));
  expectRejected(dir.file("cut.inv3"), "cut.inv3", "truncated");
  writeText(dir.file("txt.inv3"), "not an archive at all");
  expectRejected(dir.file("txt.inv3"), "txt.inv3", "InVesalius");
}

TEST(Inv3Reader, RealCraniumLoadsInHounsfieldUnits) {
  ASSERT_TRUE(std::filesystem::exists(kDefaultVolumePath))
      << kDefaultVolumePath << " missing: run scripts/setup.sh (Debian package invesalius-examples)";
  const Volume v = readVolume(kDefaultVolumePath);
  EXPECT_EQ(v.dims(), glm::ivec3(256, 256, 108));
  EXPECT_EQ(v.sourceType(), ScalarType::Int16);
  EXPECT_NEAR(v.spacing().x, 0.9570312, 1e-6);
  EXPECT_NEAR(v.spacing().y, 0.9570312, 1e-6);
  EXPECT_DOUBLE_EQ(v.spacing().z, 1.5);
  EXPECT_EQ(v.minValue(), -1024.0f);
  EXPECT_EQ(v.maxValue(), 2986.0f);
  EXPECT_EQ(v.sourceBytes(), size_t(256 * 256 * 108 * 2));
  EXPECT_EQ(v.storedType(), ScalarType::Int16);
  EXPECT_EQ(v.bytesUsed(), v.sourceBytes() + sizeof(Volume));
  // Exact percentiles (nearest rank), not histogram bin centres (those were -940 and -940).
  const Histogram h = computeHistogram(v, 24);
  EXPECT_EQ(h.p01, -1024.0);
  EXPECT_EQ(h.p50, -994.0);
  EXPECT_EQ(h.p99, 1210.0);
  EXPECT_EQ(orientationCode(v.frame().direction), "LAS");
}

TEST(DicomReader, SeriesSortedByPositionWithRescale) {
  TempDir dir;
  // Stored value = HU + 1024; slices written in a shuffled order under names that do not sort.
  const int order[5] = {3, 0, 4, 1, 2};
  for (int f = 0; f < 5; ++f) {
    const int k = order[f];
    writeDicomSlice(dir.file(sliceName("img", f)), storedSlice(k), glm::dvec3(10.0, -5.0, 100.0 + 2.5 * k),
                    "1.2.826.0.1.3680043.2.1125.1");
  }
  writeText(dir.file("notes.txt"), "not dicom");
  const Volume v = readVolume(dir.path().string());
  ASSERT_EQ(v.dims(), kDims);
  EXPECT_NEAR(v.spacing().x, 0.5, 1e-9);
  EXPECT_NEAR(v.spacing().y, 0.75, 1e-9);
  EXPECT_NEAR(v.spacing().z, 2.5, 1e-6);
  for (int k = 0; k < kDims.z; ++k)
    for (int j = 0; j < kDims.y; ++j)
      for (int i = 0; i < kDims.x; ++i) ASSERT_EQ(v.at(i, j, k), float(expectedValue(i, j, k)));
  EXPECT_EQ(v.frame().direction, glm::dmat3(1.0));
  EXPECT_EQ(v.frame().origin, glm::dvec3(10.0, -5.0, 100.0));
  EXPECT_EQ(v.infoValue("modality"), "CT");
  EXPECT_THAT(v.infoValue("thickness"), HasSubstr("2 mm"));
  EXPECT_THAT(v.infoValue("rescale"), HasSubstr("intercept -1024"));
  EXPECT_TRUE(v.warnings().empty());
  EXPECT_EQ(v.storedType(), ScalarType::Int16);  // Hounsfield units in two bytes, not widened to float
}

// Image Orientation gives i and j, the slices' order along their normal gives k, the first
// position the origin: exactly, for a flip, a permutation and an oblique rotation (DICOM frames
// are right-handed: k = i x j).
TEST(DicomReader, OrientationAndPositionGiveThePatientFrame) {
  for (Geometry g : geometries()) {
    TempDir dir;
    g.direction[2] = glm::cross(g.direction[0], g.direction[1]);
    const double cosines[6] = {g.direction[0].x, g.direction[0].y, g.direction[0].z, g.direction[1].x, g.direction[1].y, g.direction[1].z};
    for (int k = 0; k < kDims.z; ++k)
      writeDicomSlice(dir.file(std::to_string((k * 3) % 5).append(".dcm")), storedSlice(k), g.origin + g.direction[2] * (2.5 * k), "1.2.3", cosines);
    const Volume v = readVolume(dir.path().string());
    expectFrame(v, g, 1e-6);  // DICOM keeps decimal strings of 16 characters
    for (int j = 0; j < kDims.y; ++j) ASSERT_EQ(v.at(1, j, 3), float(expectedValue(1, j, 3))) << g.name;
  }
}

// Positions off the normal (a tilt) and uneven steps are resampled with a warning, read whole or
// streamed alike (the geometry against analytic objects: dicom_clinical_test.cpp).
TEST(DicomReader, GantryTiltAndUnevenSpacingAreResampled) {
  TempDir tilt, uneven;
  for (int k = 0; k < kDims.z; ++k) {
    // Each slice 0.75 mm (one row) further along y than the last: the positions leave the normal (z).
    writeDicomSlice(tilt.file(std::to_string(k).append(".dcm")), storedSlice(k), glm::dvec3(0.0, 0.75 * k, 2.5 * k), "1.2.3");
    writeDicomSlice(uneven.file(std::to_string(k).append(".dcm")), storedSlice(k), glm::dvec3(0.0, 0.0, k < 3 ? 2.5 * k : 3.0 * k), "1.2.3");
  }
  const Volume t = readBoth(tilt.path().string());
  EXPECT_EQ(t.dims(), glm::ivec3(kDims.x, kDims.y + 4, kDims.z));  // one more row a slice
  ASSERT_EQ(t.warnings().size(), 1u);
  EXPECT_THAT(t.warnings()[0], HasSubstr("gantry tilt of 16.7 degrees"));
  for (int k = 0; k < kDims.z; ++k)  // slice k moved down k rows, whole rows: exact
    for (int j = 0; j < kDims.y; ++j) ASSERT_EQ(t.at(1, j + k, k), float(expectedValue(1, j, k))) << j << "," << k;
  const Volume u = readBoth(uneven.path().string());
  EXPECT_EQ(u.spacing().z, 2.5);  // the smallest step that recurs
  EXPECT_EQ(u.dims().z, 6);       // 0 .. 12.5 mm, for slices from 0 to 12 mm
  ASSERT_EQ(u.warnings().size(), 1u);
  EXPECT_THAT(u.warnings()[0], HasSubstr("slices 2.5 to 4 mm apart along their normal: resampled onto a regular grid 2.5 mm apart"));
}

TEST(DicomReader, SeveralSeriesAreListedAndOneIsChosen) {
  TempDir dir;
  for (int k = 0; k < kDims.z; ++k)
    writeDicomSlice(dir.file(sliceName("a", k)), storedSlice(k), glm::dvec3(0.0, 0.0, 2.5 * k), "1.2.3.100", {1, 0, 0, 0, 1, 0}, "head soft");
  for (int k = 0; k < 3; ++k)
    writeDicomSlice(dir.file(sliceName("b", k)), storedSlice(k), glm::dvec3(0.0, 0.0, 1.0 * k), "1.2.3.200", {1, 0, 0, 0, 1, 0}, "scout");
  const std::vector<DicomSeriesInfo> all = listDicomSeries(dir.path().string()).series;
  ASSERT_EQ(all.size(), 2u);
  EXPECT_EQ(all[0].uid, "1.2.3.100");
  EXPECT_EQ(all[0].slices, 5u);
  EXPECT_EQ(all[0].description, "head soft");
  EXPECT_EQ(all[1].slices, 3u);
  EXPECT_EQ(all[1].columns, kDims.x);
  EXPECT_EQ(all[1].rows, kDims.y);
  // The largest, with a warning that names it and the others.
  const Volume largest = readVolume(dir.path().string());
  EXPECT_EQ(largest.dims().z, 5);
  ASSERT_EQ(largest.warnings().size(), 1u);
  EXPECT_THAT(largest.warnings()[0], HasSubstr("2 series; reading the largest axial one that is not a localizer, '1.2.3.100' (CT, head soft, 5 slices of 4x3)"));
  EXPECT_THAT(largest.warnings()[0], HasSubstr("--series"));
  EXPECT_THAT(largest.warnings()[0], HasSubstr("'1.2.3.200' (CT, scout, 3 slices of 4x3)"));
  // The one named, without a warning.
  const Volume scout = readVolume(dir.path().string(), nullptr, "1.2.3.200");
  EXPECT_EQ(scout.dims().z, 3);
  EXPECT_NEAR(scout.spacing().z, 1.0, 1e-9);
  EXPECT_TRUE(scout.warnings().empty());
  try {
    readVolume(dir.path().string(), nullptr, "9.9");
    ADD_FAILURE() << "an unknown series was accepted";
  } catch (const ValueError& e) {
    EXPECT_THAT(e.what(), HasSubstr("--series '9.9': no such series"));
    EXPECT_THAT(e.what(), HasSubstr("1.2.3.200"));
  }
}

// The command line: info lists every series; render reads the largest and says so in one
// warning line, or the one --series names.
TEST(DicomReader, InfoListsTheSeriesAndRenderNamesTheOneItReads) {
  TempDir dir;
  for (int k = 0; k < kDims.z; ++k)
    writeDicomSlice(dir.file(sliceName("a", k)), storedSlice(k), glm::dvec3(0.0, 0.0, 2.5 * k), "1.2.3.100", {1, 0, 0, 0, 1, 0}, "head");
  for (int k = 0; k < 2; ++k)
    writeDicomSlice(dir.file(sliceName("b", k)), storedSlice(k), glm::dvec3(0.0, 0.0, 1.0 * k), "1.2.3.200", {1, 0, 0, 0, 1, 0}, "scout");
  test::CliRun r = test::run({"info", dir.path().string()});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("series   2 in 1 study in "));
  EXPECT_THAT(r.out, HasSubstr("patient  (no name)\n  study  "));
  EXPECT_THAT(r.out, HasSubstr("    1.2.3.100  CT  5 slices of 4x3  4.3 KiB  head  (read by default)\n"));
  EXPECT_THAT(r.out, HasSubstr("    1.2.3.200  CT  2 slices of 4x3  1.7 KiB  scout\n"));
  EXPECT_THAT(r.out, HasSubstr("modality CT\n"));
  EXPECT_THAT(r.out, HasSubstr("series   '1.2.3.100' (CT, head, 5 slices of 4x3)\n"));
  EXPECT_THAT(r.out, HasSubstr("thickness 2 mm (Slice Thickness; slices 2.5 mm apart)\n"));
  EXPECT_THAT(r.out, HasSubstr("rescale  slope 1, intercept -1024 (applied)\n"));
  r = test::run({"render", dir.path().string(), "--size", "8x8", "-o", dir.file("r.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(test::lines(r.err), 1u) << r.err;
  EXPECT_THAT(r.err, HasSubstr("warning: " + dir.path().string() + ": 2 series; reading the largest axial one that is not a localizer, '1.2.3.100'"));
  r = test::run({"render", dir.path().string(), "--series", "1.2.3.200", "--size", "8x8", "-o", dir.file("s.png")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.err, "");
  test::expectBadInput({"render", dir.path().string(), "--series", "7.7", "--size", "8x8", "-o", dir.file("t.png")}, "--series '7.7'");
  // One image stands for its series; --series naming another is refused.
  test::expectBadInput({"info", dir.file("a0.dcm"), "--series", "1.2.3.200"}, "is an image of series '1.2.3.100'");
}

// A series of kDims.z slices in @p dir/@p name: slice k of format @p formatOf(k) holds the stored
// values @p raw(i, j, k), at z = 100 + 2.5 k, its file written in a shuffled order under a name
// that does not sort (slice k is in "img<f>.dcm" with kShuffled[f] = k). Returns the directory.
constexpr int kShuffled[5] = {3, 0, 4, 1, 2};
std::string dicomSeries(const TempDir& dir, const std::string& name, const std::function<DicomPixels(int k)>& formatOf,
                        const std::function<int(int i, int j, int k)>& raw) {
  const std::string d = dir.file(name);
  std::filesystem::create_directories(d);
  for (int f = 0; f < kDims.z; ++f) {
    const int k = kShuffled[f];
    const DicomPixels format = formatOf(k);
    const bool wide = format.type == gdcm::PixelFormat::UINT16 || format.type == gdcm::PixelFormat::INT16;
    std::vector<uint8_t> bytes;
    for (int j = 0; j < kDims.y; ++j)
      for (int i = 0; i < kDims.x; ++i) {
        const int v = raw(i, j, k);
        bytes.push_back(uint8_t(v & 0xff));
        if (wide) bytes.push_back(uint8_t((v >> 8) & 0xff));
      }
    writeDicomImage(d + "/" + sliceName("img", f), bytes, format, glm::dvec3(10.0, -5.0, 100.0 + 2.5 * k), "1.2.3.4");
  }
  return d;
}

DicomPixels pixels(gdcm::PixelFormat::ScalarType type, unsigned short bitsStored, double slope, double intercept, bool rle = false) {
  DicomPixels p;
  p.type = type;
  p.bitsStored = bitsStored;
  p.slope = slope;
  p.intercept = intercept;
  p.rle = rle;
  return p;
}

// The planes of a series streamed one by one, in order along the normal, with the shuffled files:
// equal bit for bit to readDicomSeries (samples in the same stored type, source type, frame,
// info, warnings; readBoth reads them twice, the second pass after rewind()), and each plane k
// the slice at position k rescaled by its own slope and intercept.
TEST(DicomPlanes, StreamedPlanesAreTheWholeReadBitForBit) {
  struct Case {
    const char* name;
    std::function<DicomPixels(int)> formatOf;
    std::function<int(int, int, int)> raw;
    ScalarType stored, source;
  };
  const auto hu = [](int i, int j, int k) { return expectedValue(i, j, k) + 1024; };
  const std::vector<Case> cases = {
      {"uint16", [](int) { return pixels(gdcm::PixelFormat::UINT16, 16, 1.0, 0.0); },
       [](int i, int j, int k) { return 65000 + expectedValue(i, j, k); }, ScalarType::UInt16, ScalarType::UInt16},
      {"int16, 12 bits, HU", [](int) { return pixels(gdcm::PixelFormat::INT16, 12, 1.0, -1024.0); },
       [](int i, int j, int k) { return 5 * expectedValue(i, j, k); }, ScalarType::Int16, ScalarType::Int16},
      {"uint16, 12 bits, HU", [](int) { return pixels(gdcm::PixelFormat::UINT16, 12, 1.0, -1024.0); }, hu, ScalarType::Int16,
       ScalarType::UInt16},
      {"slopes and intercepts per slice", [](int k) { return pixels(gdcm::PixelFormat::UINT16, 12, 1.0 + k % 2, -1024.0 + 10.0 * k); }, hu,
       ScalarType::Int16, ScalarType::UInt16},
      {"fractional slopes", [](int k) { return pixels(gdcm::PixelFormat::UINT16, 16, 0.25 * (k + 1), 0.5); }, hu, ScalarType::Float32,
       ScalarType::UInt16},
      {"uint8", [](int) { return pixels(gdcm::PixelFormat::UINT8, 8, 1.0, 0.0); },
       [](int i, int j, int k) { return expectedValue(i, j, k) / 2 + 150; }, ScalarType::UInt8, ScalarType::UInt8},
      {"RLE, uint16, 12 bits, HU", [](int) { return pixels(gdcm::PixelFormat::UINT16, 12, 1.0, -1024.0, true); }, hu, ScalarType::Int16,
       ScalarType::UInt16}};
  TempDir dir;
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string d = dicomSeries(dir, std::to_string(&c - cases.data()), c.formatOf, c.raw);
    if (c.formatOf(0).rle) {  // the files hold RLE Lossless
      const std::vector<uint8_t> b = test::readBytes(d + "/" + sliceName("img", 0));
      const std::string uid = "1.2.840.10008.1.2.5";
      EXPECT_NE(std::search(b.begin(), b.end(), uid.begin(), uid.end()), b.end());
    }
    const Volume whole = readBoth(d);
    EXPECT_EQ(whole.storedType(), c.stored);
    EXPECT_EQ(whole.sourceType(), c.source);
    const std::unique_ptr<PlaneSource> planes = detail::dicomPlanes(d, "");
    ASSERT_TRUE(planes);
    EXPECT_EQ(planes->storedType(), c.stored);
    EXPECT_EQ(planes->name(), d);
    SampleArray plane = detail::allocateSamples(planes->storedType(), planes->planeSize());
    for (int k = 0; k < kDims.z; ++k) {
      planes->read(1, &plane, 0);
      const DicomPixels f = c.formatOf(k);
      const Volume one(glm::ivec3(kDims.x, kDims.y, 1), glm::dvec3(1.0), c.source, plane);
      for (int j = 0; j < kDims.y; ++j)
        for (int i = 0; i < kDims.x; ++i) ASSERT_EQ(one.at(i, j, 0), float(c.raw(i, j, k) * f.slope + f.intercept)) << i << "," << j << "," << k;
    }
  }
}

TEST(DicomPlanes, RewindStartsAgainAtTheFirstPlane) {
  TempDir dir;
  const std::string d = dicomSeries(dir, "s", [](int) { return pixels(gdcm::PixelFormat::UINT16, 12, 1.0, -1024.0); },
                                     [](int i, int j, int k) { return expectedValue(i, j, k) + 1024; });
  const Volume whole = readDicomSeries(d);
  const std::unique_ptr<PlaneSource> planes = detail::dicomPlanes(d, "");
  ASSERT_TRUE(planes);
  SampleArray all = detail::allocateSamples(planes->storedType(), whole.voxelCount());
  planes->read(3, &all, 0);
  planes->rewind();
  SampleArray again = detail::allocateSamples(planes->storedType(), whole.voxelCount());
  planes->read(2, &again, 0);
  planes->read(3, &again, 2 * planes->planeSize());
  EXPECT_TRUE(again == whole.samples());
  planes->rewind();
  planes->read(5, &all, 0);
  EXPECT_TRUE(all == whole.samples());
}

// Where the whole reader's stored type depends on the values (it widens to float at the first
// rescaled value its type does not hold), the planes decide it from the values: the same volume,
// streamed.
TEST(DicomPlanes, SeriesWhoseStoredTypeDependsOnTheValuesStreamInTheTypeTheirValuesDecide) {
  TempDir dir;
  const auto hu = [](int i, int j, int k) { return expectedValue(i, j, k) + 1024; };
  // int16 with 16 bits stored and intercept −1024: values could reach −33792.
  const std::string full = dicomSeries(dir, "full", [](int) { return DicomPixels{}; }, hu);
  // The first slice not rescaled (uint16 kept), the others with an intercept.
  const std::string later = dicomSeries(dir, "later", [](int k) { return pixels(gdcm::PixelFormat::UINT16, 12, 1.0, k == 0 ? 0.0 : -1024.0); }, hu);
  // A fractional slope after integer ones.
  const std::string fraction = dicomSeries(dir, "fraction", [](int k) { return pixels(gdcm::PixelFormat::UINT16, 12, k == 3 ? 0.5 : 1.0, -1024.0); }, hu);
  // A fractional slope whose products are all integers: the whole reader keeps 16 bits (per value).
  const auto even = [](int i, int j, int k) { return 2 * ((expectedValue(i, j, k) + 1024) / 2); };
  const std::string halves = dicomSeries(dir, "halves", [](int k) { return pixels(gdcm::PixelFormat::UINT16, 12, k == 3 ? 0.5 : 1.0, -1024.0); }, even);
  for (const std::string& d : {full, later, fraction, halves}) {
    const std::unique_ptr<PlaneSource> planes = detail::dicomPlanes(d, "");
    ASSERT_TRUE(planes) << d;
    EXPECT_EQ(planes->storedType(), readDicomSeries(d).storedType()) << d;
    readBoth(d, true);
  }
  EXPECT_EQ(readDicomSeries(full).storedType(), ScalarType::Int16);  // its values fit
  EXPECT_EQ(readDicomSeries(fraction).storedType(), ScalarType::Float32);
  EXPECT_EQ(readDicomSeries(halves).storedType(), ScalarType::Int16);
}

// A slice that turns bad after the series was opened (truncated, rewritten with another rescale,
// removed) throws when its plane is read, naming its file; the planes before it read.
TEST(DicomPlanes, ASliceDamagedAfterTheScanThrowsNamingItsFile) {
  TempDir dir;
  const auto format = [](int) { return pixels(gdcm::PixelFormat::UINT16, 12, 1.0, -1024.0); };
  const auto hu = [](int i, int j, int k) { return expectedValue(i, j, k) + 1024; };
  const std::string d = dicomSeries(dir, "s", format, hu);
  const std::string third = d + "/" + sliceName("img", 4);  // kShuffled[4] == 2: plane 2
  const std::vector<uint8_t> bytes = test::readBytes(third);
  const auto opened = [&](const std::string& what, const std::function<void()>& damage) {
    const std::unique_ptr<PlaneSource> planes = detail::dicomPlanes(d, "");
    ASSERT_TRUE(planes);
    damage();
    SampleArray all = detail::allocateSamples(planes->storedType(), planes->planeSize() * size_t(kDims.z));
    planes->read(2, &all, 0);
    try {
      planes->read(1, &all, 2 * planes->planeSize());
      ADD_FAILURE() << "plane 2 read; expected an error containing '" << what << "'";
    } catch (const IoError& e) {
      EXPECT_THAT(e.what(), HasSubstr(third));
      EXPECT_THAT(e.what(), HasSubstr(what));
    }
    writeBytes(third, bytes);
  };
  opened("declaring 24 bytes where 17 are left", [&] { std::filesystem::resize_file(third, bytes.size() - 7); });
  opened("(slice 3 of 5): changed since the series was opened: uint16 pixels, rescale slope 1, intercept -1000 (expected uint16, slope 1, "
         "intercept -1024)",
         [&] {
           DicomPixels p = format(2);
           p.intercept = -1000.0;
           std::vector<uint8_t> px;
           for (int j = 0; j < kDims.y; ++j)
             for (int i = 0; i < kDims.x; ++i) {
               px.push_back(uint8_t(hu(i, j, 2) & 0xff));
               px.push_back(uint8_t(hu(i, j, 2) >> 8));
             }
           writeDicomImage(third, px, p, glm::dvec3(10.0, -5.0, 105.0), "1.2.3.4");
         });
  opened("does not exist", [&] { std::filesystem::remove(third); });
}

// The command line: build streams a DICOM series (reading it once per pass), info reads it whole.
TEST(DicomPlanes, BuildStreamsTheSeriesAndInfoReadsIt) {
  TempDir dir;
  const std::string d = dicomSeries(dir, "s", [](int) { return pixels(gdcm::PixelFormat::INT16, 12, 1.0, -1024.0); },
                                     [](int i, int j, int k) { return 5 * expectedValue(i, j, k); });
  test::CliRun r = test::run({"build", d, "-o", dir.file("s.hoct")});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("streamed plane by plane"));
  r = test::run({"info", d});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("rescale  slope 1, intercept -1024 (applied)\n"));
  r = test::run({"info", dir.file("s.hoct")});
  ASSERT_EQ(r.status, 0) << r.err;
}

// A rescale whose values leave the float range (held as float at widest) is refused naming the
// slice and the tag, read whole or streamed, and by the command line before it writes anything.
TEST(DicomReader, RescaleBeyondTheFloatRangeIsRefusedNamingTheSliceAndTag) {
  TempDir dir;
  const auto hu = [](int i, int j, int k) { return expectedValue(i, j, k) + 1024; };
  const std::string intercept =
      dicomSeries(dir, "intercept", [](int k) { return pixels(gdcm::PixelFormat::INT16, 12, 1.0, k == 2 ? -1e39 : -1024.0); }, hu);
  const std::string slope = dicomSeries(dir, "slope", [](int) { return pixels(gdcm::PixelFormat::INT16, 12, 1e308, 0.0); }, hu);
  expectRejected(intercept, "(slice 3 of 5)", "Rescale Intercept (0028,1052) -1e+39");
  expectRejected(slope, "(slice 1 of 5)", "Rescale Slope (0028,1053) 1e+308");
  for (const std::string& d : {intercept, slope}) {
    const test::CliRun r = test::run({"build", d, "-o", dir.file("s.hoct")});
    EXPECT_EQ(r.status, 2) << r.err;
    EXPECT_THAT(r.err, HasSubstr("beyond the float range"));
    EXPECT_FALSE(std::filesystem::exists(dir.file("s.hoct")));
  }
}

// A float sample that is not finite is refused naming the file and the voxel, read whole or
// streamed into a build (whose range, made from the planes, must be finite).
TEST(VolumeReaders, NonFiniteFloatSamplesAreRefusedReadWholeOrStreamed) {
  TempDir dir;
  for (const float bad : {std::numeric_limits<float>::infinity(), std::numeric_limits<float>::quiet_NaN()}) {
    std::vector<float> values(size_t(4 * 3 * 5), 1.5f);
    values[size_t(1 + 4 * (2 + 3 * 3))] = bad;  // voxel (1,2,3)
    writeBytes(dir.file("f.raw"), toBytes(values));
    writeText(dir.file("f.nhdr"), "NRRD0004\ntype: float\ndimension: 3\nsizes: 4 3 5\nendian: little\nencoding: raw\ndata file: f.raw\n");
    expectRejected(dir.file("f.nhdr"), "f.", std::isnan(bad) ? "sample (1,2,3) is nan" : "sample (1,2,3) is inf");
    const test::CliRun r = test::run({"build", dir.file("f.nhdr"), "-o", dir.file("f.hoct")});
    EXPECT_EQ(r.status, 2) << r.err;
    EXPECT_THAT(r.err, HasSubstr("sample (1,2,3) is "));
    EXPECT_FALSE(std::filesystem::exists(dir.file("f.hoct")));
  }
}

TEST(DicomReader, RejectsDirectoryWithoutDicom) {
  TempDir dir;
  writeText(dir.file("a.txt"), "hello");
  expectRejected(dir.path().string(), dir.path().string(), "no DICOM image series found (1 file: 1 not DICOM");
}

TEST(NrrdReader, SpaceDirectionsAndOriginInRasLasAndLps) {
  TempDir dir;
  const auto data = toBytes(expectedSamples());
  for (const Geometry& g : geometries())
    for (const auto& [space, sign] : {std::pair{"right-anterior-superior", glm::dvec3(-1, -1, 1)}, {"LAS", glm::dvec3(1, -1, 1)},
                                      {"left-posterior-superior", glm::dvec3(1, 1, 1)}}) {
      std::string header = std::string("NRRD0005\ntype: short\ndimension: 3\nsizes: 4 3 5\nspace: ") + space + "\nspace directions:";
      for (int a = 0; a < 3; ++a) header.append(" ").append(vec(g.direction[a] * kSpacing[a] * sign));
      header.append("\nspace origin: ").append(vec(g.origin * sign)).append("\nendian: little\nencoding: raw\n\n");
      writeBytes(dir.file("v.nrrd"), concat(header, data));
      const Volume v = readVolume(dir.file("v.nrrd"));
      expectFrame(v, g, 1e-12);
      EXPECT_TRUE(v.warnings().empty()) << v.warnings().front();
      expectExpectedVolume(v, kSpacing);
    }
  // Space units: centimetres scale directions and origin.
  writeBytes(dir.file("cm.nrrd"), concat("NRRD0005\ntype: short\ndimension: 3\nsizes: 4 3 5\nspace: LPS\nspace units: \"cm\" \"cm\" \"cm\"\n"
                                         "space directions: (0.05,0,0) (0,0.075,0) (0,0,0.25)\nspace origin: (1,2,3)\nendian: little\nencoding: raw\n\n",
                                         data));
  const Volume cm = readVolume(dir.file("cm.nrrd"));
  EXPECT_EQ(cm.frame().origin, glm::dvec3(10, 20, 30));
  EXPECT_NEAR(cm.spacing().z, 2.5, 1e-12);
  // No space directions: identity, with a warning that says so.
  writeBytes(dir.file("plain.nrrd"), concat(std::string(kNrrdHeader) + "endian: little\nencoding: raw\n\n", data));
  const Volume plain = readVolume(dir.file("plain.nrrd"));
  EXPECT_EQ(plain.frame().direction, glm::dmat3(1.0));
  ASSERT_EQ(plain.warnings().size(), 1u);
  EXPECT_THAT(plain.warnings()[0], HasSubstr("orientation unknown"));
  // A sheared grid and an unknown space are refused.
  writeBytes(dir.file("shear.nrrd"), concat("NRRD0005\ntype: short\ndimension: 3\nsizes: 4 3 5\nspace: LPS\n"
                                            "space directions: (0.5,0,0) (0,0.75,0) (0,0.5,2.5)\nendian: little\nencoding: raw\n\n", data));
  expectRejected(dir.file("shear.nrrd"), "shear.nrrd", "not orthogonal");
  writeBytes(dir.file("sp.nrrd"), concat("NRRD0005\ntype: short\ndimension: 3\nsizes: 4 3 5\nspace: right-anterior-superior-time\n"
                                         "space directions: (0.5,0,0) (0,0.75,0) (0,0,2.5)\nendian: little\nencoding: raw\n\n", data));
  expectRejected(dir.file("sp.nrrd"), "sp.nrrd", "space 'right-anterior-superior-time' unsupported");
}

TEST(MetaImageReader, OffsetTransformMatrixAndAnatomicalOrientation) {
  TempDir dir;
  const auto data = toBytes(expectedSamples());
  writeBytes(dir.file("v.raw"), data);
  const std::string head = "ObjectType = Image\nNDims = 3\nDimSize = 4 3 5\nElementSpacing = 0.5 0.75 2.5\nElementType = MET_SHORT\n";
  for (const Geometry& g : geometries()) {
    std::string m = "TransformMatrix =";
    for (int a = 0; a < 3; ++a) m += vec(g.direction[a], " ", " ", "");  // row a: axis a's direction (ITK)
    writeText(dir.file("v.mhd"), head + m + "\nOffset =" + vec(g.origin, " ", " ", "") + "\nElementDataFile = v.raw\n");
    const Volume v = readVolume(dir.file("v.mhd"));
    expectFrame(v, g, 1e-12);
    EXPECT_TRUE(v.warnings().empty());
  }
  // AnatomicalOrientation alone: "RPI" names where the axes come from (R, P, I), so they point
  // to L, A, S.
  writeText(dir.file("a.mhd"), head + "AnatomicalOrientation = RPI\nPosition = 1 2 3\nElementDataFile = v.raw\n");
  const Volume a = readVolume(dir.file("a.mhd"));
  expectFrame(a, {"RPI", glm::dmat3(glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1)), {1, 2, 3}}, 0.0);
  // A matrix that disagrees with the letters wins, with a warning naming both.
  writeText(dir.file("d.mhd"), head + "TransformMatrix = 1 0 0 0 1 0 0 0 1\nAnatomicalOrientation = RPI\nElementDataFile = v.raw\n");
  const Volume d = readVolume(dir.file("d.mhd"));
  EXPECT_EQ(d.frame().direction, glm::dmat3(1.0));
  ASSERT_EQ(d.warnings().size(), 1u);
  EXPECT_THAT(d.warnings()[0], HasSubstr("disagrees with TransformMatrix (LPS)"));
  writeText(dir.file("b.mhd"), head + "TransformMatrix = 1 0 0 0 1\nElementDataFile = v.raw\n");
  expectRejected(dir.file("b.mhd"), "b.mhd", "TransformMatrix '1 0 0 0 1' malformed");
}

TEST(NiftiReader, SformThenQformThenMethodOne) {
  TempDir dir;
  const auto data = toBytes(expectedSamples());
  const glm::dmat3 sheared(glm::dvec3(1, 0, 0), glm::dvec3(0, 1, 0), glm::dvec3(0, 0.3, 1));
  for (const Geometry& g : geometries()) {
    // The sform alone, then the sform over a different qform: the sform wins.
    const glm::dmat3 other(1.0);
    writeBytes(dir.file("s.nii"), orientedNifti(data, &g.direction, g.origin, nullptr, {}));
    expectFrame(readVolume(dir.file("s.nii")), g, 1e-6);
    writeBytes(dir.file("sq.nii"), orientedNifti(data, &g.direction, g.origin, &other, {0, 0, 0}));
    expectFrame(readVolume(dir.file("sq.nii")), g, 1e-6);
    // The qform alone (quaternion and qfac).
    writeBytes(dir.file("q.nii"), orientedNifti(data, nullptr, {}, &g.direction, g.origin));
    const Volume q = readVolume(dir.file("q.nii"));
    expectFrame(q, g, 1e-6);
    EXPECT_TRUE(q.warnings().empty());
  }
  // A sform sheared along its third axis (a tilted acquisition) wins over the qform too: its planes
  // are resampled where it puts them (dicom_clinical_test.cpp compares it with the DICOM series).
  writeBytes(dir.file("shq.nii"), orientedNifti(data, &sheared, {0, 0, 0}, &geometries().front().direction, {}));
  const Volume shq = readBoth(dir.file("shq.nii"));
  ASSERT_EQ(shq.warnings().size(), 1u);
  EXPECT_THAT(shq.warnings()[0], HasSubstr("gantry tilt of 16.7 degrees (a sheared sform)"));
  // Sheared within its plane: no stack of planes, refused.
  const glm::dmat3 inPlane(glm::dvec3(1, 0, 0), glm::dvec3(0.3, 1, 0), glm::dvec3(0, 0, 1));
  writeBytes(dir.file("sh.nii"), orientedNifti(data, &inPlane, {0, 0, 0}, nullptr, {}));
  expectRejected(dir.file("sh.nii"), "sh.nii (sform)", "not orthogonal");
  // A column or the origin not finite: refused by the frame's check, not taken for a sheared stack.
  const double nan = std::nan("");
  const glm::dmat3 nanColumn(glm::dvec3(1, 0, 0), glm::dvec3(0, 1, 0), glm::dvec3(0, nan, 1));
  writeBytes(dir.file("nan.nii"), orientedNifti(data, &nanColumn, {0, 0, 0}, nullptr, {}));
  expectRejected(dir.file("nan.nii"), "nan.nii (sform)", "not finite");
  const glm::dmat3 identity(1.0);
  writeBytes(dir.file("nanorigin.nii"), orientedNifti(data, &identity, {nan, 0, 0}, nullptr, {}));
  expectRejected(dir.file("nanorigin.nii"), "nanorigin.nii (sform)", "is not finite");
  // Neither: method 1, RAS axes, and a warning.
  writeBytes(dir.file("none.nii"), niftiFile(0.0f, 0.0f, data));
  const Volume none = readVolume(dir.file("none.nii"));
  EXPECT_EQ(orientationCode(none.frame().direction), "RAS");
  ASSERT_EQ(none.warnings().size(), 1u);
  EXPECT_THAT(none.warnings()[0], HasSubstr("method 1"));
}

TEST(Inv3Reader, MatrixIsLasAndAStoredAffineIsUndone) {
  TempDir dir;
  const std::string shape = "<integer>5</integer><integer>3</integer><integer>4</integer>";
  writeInv3(dir.file("p.inv3"), inv3Plist(shape), toBytes(expectedSamples()));
  const Volume p = readVolume(dir.file("p.inv3"));
  EXPECT_EQ(orientationCode(p.frame().direction), "LAS");
  EXPECT_EQ(p.frame().origin, glm::dvec3(0.0));
  // A project imported from NIfTI stores the inverse of the canonical (RAS) image's rigid
  // transform, its rows flipped into the matrix: voxel (i, j, k) is canonical voxel (i, ny−1−j, k).
  const glm::dmat3 r = rotation(10, -25);
  const glm::dvec3 t(12.5, -40, 7);
  glm::dmat4 rigid(r);
  rigid[3] = glm::dvec4(t, 1.0);
  const glm::dmat4 stored = glm::inverse(rigid);
  std::ostringstream affine;
  affine << std::setprecision(17) << "<key>affine</key><array>";
  for (int row = 0; row < 4; ++row) {
    affine << "<array>";
    for (int c = 0; c < 4; ++c) affine << "<real>" << stored[c][row] << "</real>";
    affine << "</array>";
  }
  affine << "</array>\n";
  std::string plist = inv3Plist(shape);
  plist.insert(plist.find("<key>modality</key>"), affine.str());
  writeInv3(dir.file("n.inv3"), plist, toBytes(expectedSamples()));
  const Volume n = readVolume(dir.file("n.inv3"));
  for (const glm::ivec3 ijk : {glm::ivec3(0, 0, 0), glm::ivec3(3, 1, 4), glm::ivec3(1, 2, 0)}) {
    const glm::dvec3 canonical(ijk.x * 0.5, (kDims.y - 1 - ijk.y) * 0.75, ijk.z * 2.5);
    const glm::dvec3 expected = rasToLps(r * canonical + t);
    const glm::dvec3 got = n.frame().toPatient(glm::dvec3(ijk) * n.spacing());
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(got[a], expected[a], 1e-9) << ijk.x << "," << ijk.y << "," << ijk.z;
  }
}

// A spacing whose reciprocal is not finite (1e-320 mm) or that float cannot hold is refused by
// every reader, naming the file or flag: it used to pass and make gradients read out of bounds.
TEST(VolumeReaders, ASpacingWithoutAFiniteReciprocalIsRefusedByEveryReader) {
  TempDir dir;
  const auto data = toBytes(expectedSamples());
  writeBytes(dir.file("v.raw"), data);
  for (const char* s : {"1e-320", "1e-7", "1e300"}) {
    writeBytes(dir.file("n.nhdr"), concat(std::string("NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 5\nspacings: 0.5 ") + s +
                                              " 2.5\nencoding: raw\nendian: little\ndata file: v.raw\n",
                                          {}));
    expectRejected(dir.file("n.nhdr"), "n.nhdr", "spacing");
    writeText(dir.file("m.mhd"), std::string("NDims = 3\nDimSize = 4 3 5\nElementSpacing = 0.5 0.75 ") + s +
                                     "\nElementType = MET_SHORT\nElementDataFile = v.raw\n");
    expectRejected(dir.file("m.mhd"), "m.mhd", "spacing");
    writeInv3(dir.file("p.inv3"),
              "<plist><dict><key>matrix</key><dict><key>dtype</key><string>int16</string><key>filename</key><string>matrix.dat</string>"
              "<key>shape</key><array><integer>5</integer><integer>3</integer><integer>4</integer></array></dict>"
              "<key>spacing</key><array><real>" + std::string(s) + "</real><real>0.75</real><real>2.5</real></array></dict></plist>",
              data);
    expectRejected(dir.file("p.inv3"), "p.inv3", "spacing");
    RawLayout l;
    l.dims = kDims;
    l.type = ScalarType::Int16;
    l.spacing = {0.5, std::strtod(s, nullptr), 2.5};  // (std::stod refuses a denormal)
    expectRejected(dir.file("v.raw"), "--raw-spacing", "spacing", &l);
  }
  std::vector<uint8_t> nifti = niftiFile(0.0f, 0.0f, data);
  const float tiny = 1e-40f;  // a float denormal: its reciprocal overflows float
  std::memcpy(nifti.data() + offsetof(nifti_1_header, pixdim) + 2 * sizeof(float), &tiny, sizeof tiny);
  writeBytes(dir.file("t.nii"), nifti);
  expectRejected(dir.file("t.nii"), "t.nii", "spacing");
  TempDir series;
  for (int k = 0; k < kDims.z; ++k)
    writeDicomSlice(series.file(sliceName("s", k)), storedSlice(k), glm::dvec3(0.0, 0.0, 1e7 * k), "1.2.3");  // (positions hold 16 characters: none nearer)
  expectRejected(series.path().string(), series.path().string(), "spacing");
  EXPECT_THROW(Volume(kDims, {1.0, 1e-320, 1.0}, ScalarType::Float32, std::vector<float>(60, 0.0f), "scene.hoct"), ValueError);
}

}  // namespace
}  // namespace hyb
