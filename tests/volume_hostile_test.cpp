// Hostile inputs: FIFOs, memory bombs, declared sizes the data does not hold, shapes that make
// GDCM assert, deep nesting, endless lines. Each must end in one typed, one-line error naming the
// file and what was expected, quickly, within bounded memory and without third-party output.
#include <archive.h>
#include <archive_entry.h>
#include <gdcmAttribute.h>
#include <gdcmFileMetaInformation.h>
#include <gdcmMediaStorage.h>
#include <gdcmTrace.h>
#include <gdcmWriter.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nifti1.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <functional>
#include <sstream>
#include <stdexcept>

#include "hybrid_octree/hybrid_io.h"
#include "render/transfer_function.h"
#include "test_util.h"
#include "volume/core/file_util.h"
#include "volume/core/memory_limit.h"
#include "volume/plane_source.h"
#include "volume/volume_io.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;
using test::TempDir;
using test::writeBytes;
using test::writeText;

// Runs @p read, which must throw an E whose message is one printable line naming @p named and
// saying @p what, within a few seconds and with nothing written to stderr.
template <class E = IoError>
void expectRefused(const std::function<void()>& read, const std::string& named, const std::string& what) {
  testing::internal::CaptureStderr();
  std::string msg;
  try {
    read();
    ADD_FAILURE() << named << " was accepted; expected an error containing '" << what << "'";
  } catch (const E& e) {
    msg = e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << named << ": wrong exception type: " << e.what();
  }
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_EQ(err, "") << "third-party output for " << named;
  if (msg.empty()) return;
  EXPECT_THAT(msg, HasSubstr(named));
  EXPECT_THAT(msg, HasSubstr(what));
  EXPECT_THAT(msg, HasSubstr("expected")) << msg;
  EXPECT_LT(msg.size(), 600u) << msg;
  for (char c : msg) ASSERT_TRUE(static_cast<unsigned char>(c) >= 0x20 && c != 0x7f) << "control byte in message: " << msg;
}

void expectVolumeRefused(const std::string& path, const std::string& named, const std::string& what, const RawLayout* raw = nullptr) {
  expectRefused([&] { readVolume(path, raw); }, named, what);
}

// Read whole and opened plane by plane (the streamed build's path).
void expectBothRefused(const std::string& path, const std::string& named, const std::string& what, const RawLayout* raw = nullptr) {
  expectVolumeRefused(path, named, what, raw);
  expectRefused([&] { openPlanes(path, raw); }, named, what);
}

std::vector<uint8_t> concat(const std::string& header, const std::vector<uint8_t>& data) {
  std::vector<uint8_t> b(header.begin(), header.end());
  b.insert(b.end(), data.begin(), data.end());
  return b;
}

std::vector<uint8_t> deflateBytes(const std::vector<uint8_t>& raw, bool gzip) {
  z_stream z{};
  deflateInit2(&z, 9, Z_DEFLATED, gzip ? 15 + 16 : 15, 9, Z_DEFAULT_STRATEGY);
  std::vector<uint8_t> out(deflateBound(&z, uLong(raw.size())));
  z.next_in = const_cast<uint8_t*>(raw.data());
  z.avail_in = uInt(raw.size());
  z.next_out = out.data();
  z.avail_out = uInt(out.size());
  deflate(&z, Z_FINISH);
  out.resize(z.total_out);
  deflateEnd(&z);
  return out;
}

// A gzip stream of @p bytes zeros, compressed in chunks (it never holds them all).
std::vector<uint8_t> gzipZeros(uint64_t bytes) {
  z_stream z{};
  deflateInit2(&z, 9, Z_DEFLATED, 15 + 16, 9, Z_DEFAULT_STRATEGY);
  const std::vector<uint8_t> zeros(1 << 20, 0);
  std::vector<uint8_t> out;
  uint8_t buf[1 << 16];
  for (uint64_t left = bytes;;) {
    const uint64_t n = std::min<uint64_t>(left, zeros.size());
    left -= n;
    z.next_in = const_cast<uint8_t*>(zeros.data());
    z.avail_in = uInt(n);
    const int flush = left ? Z_NO_FLUSH : Z_FINISH;
    int rc;
    do {
      z.next_out = buf;
      z.avail_out = sizeof buf;
      rc = deflate(&z, flush);
      out.insert(out.end(), buf, buf + (sizeof buf - z.avail_out));
    } while (z.avail_out == 0);
    if (flush == Z_FINISH && rc == Z_STREAM_END) break;
  }
  deflateEnd(&z);
  return out;
}

const std::string kNrrd16 = "NRRD0004\ntype: short\ndimension: 3\nsizes: 4 3 5\nendian: little\n";

TEST(HostileInputs, FifosAreRefusedWithoutBlocking) {
  TempDir dir;
  const char* kVolumes[] = {"v.nrrd", "v.nhdr", "v.mha", "v.mhd", "v.nii", "v.nii.gz", "v.hdr", "v.inv3"};
  for (const char* name : kVolumes) ASSERT_EQ(::mkfifo(dir.file(name).c_str(), 0600), 0) << name;
  for (const char* name : {"v.raw", "v.hoct", "data.raw", "f.tf", "i.img"}) ASSERT_EQ(::mkfifo(dir.file(name).c_str(), 0600), 0) << name;
  alarm(60);  // a reader that blocks on a FIFO must fail the run, not hang it
  for (const char* name : kVolumes) expectBothRefused(dir.file(name), name, "FIFO");
  RawLayout raw;
  raw.dims = {2, 2, 2};
  expectBothRefused(dir.file("v.raw"), "v.raw", "FIFO", &raw);
  expectBothRefused(dir.file("v.hoct"), "v.hoct", "FIFO", &raw);  // a scene's name with raw flags: still not opened
  expectRefused([&] { loadScene(dir.file("v.hoct")); }, "v.hoct", "FIFO");
  EXPECT_FALSE(isSceneFile(dir.file("v.hoct")));
  writeText(dir.file("d.nhdr"), "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: data.raw\n");
  expectBothRefused(dir.file("d.nhdr"), "data.raw", "expected a regular file, found a FIFO");
  writeText(dir.file("d.mhd"), "NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = data.raw\n");
  expectBothRefused(dir.file("d.mhd"), "data.raw", "FIFO");
  expectRefused([&] { TransferFunction::fromFile(dir.file("f.tf")); }, "f.tf", "expected a regular file, found a FIFO");
  expectRefused([&] { readFileBytes(dir.file("f.tf")); }, "f.tf", "FIFO");
  expectRefused([&] { readFileBytes(dir.path().string()); }, dir.path().string(), "found a directory");
  alarm(0);
}

TEST(HostileInputs, GzipBombsStopAtTheDeclaredSize) {
  TempDir dir;
  // 64 MiB of zeros behind a header that declares 120 bytes: refused once the 121st byte appears.
  writeBytes(dir.file("bomb.nrrd"), concat(kNrrd16 + "encoding: gzip\n\n", gzipZeros(uint64_t(64) << 20)));
  expectVolumeRefused(dir.file("bomb.nrrd"), "bomb.nrrd", "inflates past the 120 bytes the header declares");
  writeBytes(dir.file("bomb.mha"), concat("NDims = 3\nDimSize = 4 3 5\nElementType = MET_SHORT\nCompressedData = True\nElementDataFile = LOCAL\n",
                                          deflateBytes(std::vector<uint8_t>(1 << 20, 0), false)));
  expectVolumeRefused(dir.file("bomb.mha"), "bomb.mha", "inflates past the 120 bytes");
  // A 1 KB stream cannot inflate to 32768x32768x4 shorts: refused before any allocation.
  std::vector<uint8_t> kilobyte = gzipZeros(1 << 20);
  kilobyte.resize(1024);
  writeBytes(dir.file("claim.nrrd"),
             concat("NRRD0004\ntype: short\ndimension: 3\nsizes: 32768 32768 4\nendian: little\nencoding: gzip\n\n", kilobyte));
  expectVolumeRefused(dir.file("claim.nrrd"), "claim.nrrd", "cannot hold the 8589934592 bytes");
  writeBytes(dir.file("claim.mha"), concat("NDims = 3\nDimSize = 32768 32768 4\nElementType = MET_SHORT\nCompressedData = True\n"
                                           "ElementDataFile = LOCAL\n", kilobyte));
  expectVolumeRefused(dir.file("claim.mha"), "claim.mha", "cannot hold");
  // A stream that could hold the claim but stops short.
  writeBytes(dir.file("short.nrrd"), concat(kNrrd16 + "encoding: gzip\n\n", gzipZeros(100)));
  expectVolumeRefused(dir.file("short.nrrd"), "short.nrrd", "120 bytes the header declares");
}

// Peak memory of reading a bomb in a child process: what the stream holds must not be allocated.
TEST(HostileInputs, GzipBombPeakMemoryStaysBounded) {
  TempDir dir;
  const std::string path = dir.file("bomb.nrrd");
  // Declares 4 MiB of uint8 samples; the stream holds 512 MiB of zeros (about 500 KB compressed).
  writeBytes(path, concat("NRRD0004\ntype: uchar\ndimension: 3\nsizes: 256 256 64\nencoding: gzip\n\n", gzipZeros(uint64_t(512) << 20)));
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    rusage before{}, after{};
    getrusage(RUSAGE_SELF, &before);
    bool refused = false;
    try {
      readVolume(path);
    } catch (const IoError& e) {
      refused = std::string(e.what()).find("inflates past") != std::string::npos;
    }
    getrusage(RUSAGE_SELF, &after);
    const long grewKb = after.ru_maxrss - before.ru_maxrss;
    _exit(!refused ? 2 : grewKb > 64 * 1024 ? 3 : 0);  // 64 MiB: far below the 512 MiB the stream holds
  }
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << "2: not refused as inflating past the claim; 3: peak memory grew by more than 64 MiB";
}

TEST(HostileInputs, MemoryLimitRefusesBeforeAllocating) {
  EXPECT_GT(defaultMemoryLimit(), uint64_t(0));
  EXPECT_EQ(memoryLimit(), defaultMemoryLimit());
  TempDir dir;
  // A valid 64x64x64 float volume: 1 MiB of data, 2 MiB with its samples.
  writeBytes(dir.file("v.nrrd"), concat("NRRD0004\ntype: float\ndimension: 3\nsizes: 64 64 64\nendian: little\nencoding: raw\n\n",
                                        std::vector<uint8_t>(64 * 64 * 64 * 4, 0)));
  setMemoryLimit(uint64_t(1) << 20);
  EXPECT_EQ(memoryLimit(), uint64_t(1) << 20);
  expectVolumeRefused(dir.file("v.nrrd"), "v.nrrd", "64x64x64 float32 samples need 2097152 bytes (2.0 MiB), more than the memory limit of 1.0 MiB");
  setMemoryLimit(0);
  EXPECT_EQ(memoryLimit(), defaultMemoryLimit());
  EXPECT_EQ(readVolume(dir.file("v.nrrd")).dims(), glm::ivec3(64));
}

std::vector<uint8_t> niftiHeader(short nx, short ny, short nz) {
  nifti_1_header h{};
  h.sizeof_hdr = 348;
  h.dim[0] = 3;
  h.dim[1] = nx;
  h.dim[2] = ny;
  h.dim[3] = nz;
  for (int d = 4; d < 8; ++d) h.dim[d] = 1;
  h.datatype = DT_INT16;
  h.bitpix = 16;
  for (int d = 0; d < 4; ++d) h.pixdim[d] = 1.0f;
  h.vox_offset = 352.0f;
  std::memcpy(h.magic, "n+1\0", 4);
  std::vector<uint8_t> b(352, 0);
  std::memcpy(b.data(), &h, sizeof h);
  return b;
}

void writeInv3(const std::string& path, const std::vector<std::pair<std::string, std::vector<uint8_t>>>& entries) {
  archive* a = archive_write_new();
  archive_write_add_filter_gzip(a);
  archive_write_set_format_pax_restricted(a);
  archive_write_open_filename(a, path.c_str());
  for (const auto& [name, data] : entries) {
    archive_entry* e = archive_entry_new();
    archive_entry_set_pathname(e, name.c_str());
    archive_entry_set_size(e, la_int64_t(data.size()));
    archive_entry_set_filetype(e, AE_IFREG);
    archive_entry_set_perm(e, 0644);
    archive_write_header(a, e);
    archive_write_data(a, data.data(), data.size());
    archive_entry_free(e);
  }
  archive_write_close(a);
  archive_write_free(a);
}

std::vector<uint8_t> bytesOf(const std::string& s) { return std::vector<uint8_t>(s.begin(), s.end()); }

std::string inv3Plist(const std::string& shape) {
  return "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<plist version=\"1.0\">\n<dict>\n"
         "<key>matrix</key><dict><key>dtype</key><string>int16</string><key>filename</key><string>matrix.dat</string>"
         "<key>shape</key><array>" + shape + "</array></dict>\n"
         "<key>spacing</key><array><real>0.5</real><real>0.75</real><real>2.5</real></array>\n</dict>\n</plist>\n";
}

const std::string kShape = "<integer>5</integer><integer>3</integer><integer>4</integer>";

TEST(HostileInputs, DeclaredSizeLargerThanTheDataIsRefusedInEveryFormat) {
  TempDir dir;
  const std::vector<uint8_t> data(100, 1);  // 120 bytes are declared below
  writeBytes(dir.file("a.nrrd"), concat(kNrrd16 + "encoding: raw\n\n", data));
  expectVolumeRefused(dir.file("a.nrrd"), "a.nrrd", "truncated data: expected 120 bytes for 4x3x5 int16, found 100");
  writeBytes(dir.file("huge.nrrd"), concat("NRRD0004\ntype: short\ndimension: 3\nsizes: 32768 32768 4\nendian: little\nencoding: raw\n\n", data));
  expectVolumeRefused(dir.file("huge.nrrd"), "huge.nrrd", "truncated data: expected 8589934592 bytes");
  writeBytes(dir.file("t.nrrd"), concat(kNrrd16 + "encoding: ascii\n\n", bytesOf("1 2 3")));
  expectVolumeRefused(dir.file("t.nrrd"), "t.nrrd", "truncated ASCII data");
  writeBytes(dir.file("a.mha"), concat("NDims = 3\nDimSize = 4 3 5\nElementType = MET_SHORT\nElementDataFile = LOCAL\n", data));
  expectVolumeRefused(dir.file("a.mha"), "a.mha", "truncated data: expected 120 bytes");
  writeBytes(dir.file("z.mha"), concat("NDims = 3\nDimSize = 4 3 5\nElementType = MET_SHORT\nCompressedData = True\nElementDataFile = LOCAL\n",
                                       deflateBytes(data, false)));
  expectVolumeRefused(dir.file("z.mha"), "z.mha", "stops short after 100 bytes (expected the 120 bytes the header declares)");
  std::vector<uint8_t> nii = niftiHeader(4, 3, 5);
  nii.insert(nii.end(), data.begin(), data.end());
  writeBytes(dir.file("a.nii"), nii);
  expectVolumeRefused(dir.file("a.nii"), "a.nii", "truncated NIfTI data: expected 120 bytes of samples from byte 352, found 100");
  std::vector<uint8_t> hugeNii = niftiHeader(32767, 32767, 4);
  hugeNii.resize(1400);
  writeBytes(dir.file("huge.nii.gz"), deflateBytes(hugeNii, true));
  expectVolumeRefused(dir.file("huge.nii.gz"), "huge.nii.gz", "cannot hold");
  writeInv3(dir.file("a.inv3"), {{"p/main.plist", bytesOf(inv3Plist(kShape))}, {"p/matrix.dat", data}});
  expectVolumeRefused(dir.file("a.inv3"), "a.inv3:matrix.dat", "truncated data: expected 120 bytes");
  RawLayout raw;
  raw.dims = {4, 3, 5};
  raw.type = ScalarType::Int16;
  writeBytes(dir.file("a.bin"), data);
  expectVolumeRefused(dir.file("a.bin"), "a.bin", "truncated data: expected 120 bytes", &raw);
  raw.dims = {32768, 32768, 4};
  expectVolumeRefused(dir.file("a.bin"), "a.bin", "truncated data: expected 8589934592 bytes", &raw);
}

TEST(HostileInputs, Inv3KeepsOnlyWhatItNeeds) {
  TempDir dir;
  std::vector<uint8_t> matrix;
  for (int i = 0; i < 60; ++i) matrix.push_back(uint8_t(i)), matrix.push_back(0);
  // The matrix before main.plist, with masks and other entries around it: all skipped but the matrix.
  writeInv3(dir.file("p.inv3"), {{"p/mask_1.dat", std::vector<uint8_t>(1 << 20, 7)},
                                 {"p/matrix.dat", matrix},
                                 {"p/other.dat", std::vector<uint8_t>(1 << 20, 9)},
                                 {"p/main.plist", bytesOf(inv3Plist(kShape))}});
  const Volume v = readVolume(dir.file("p.inv3"));
  EXPECT_EQ(v.dims(), glm::ivec3(4, 3, 5));
  EXPECT_EQ(v.at(3, 2, 4), 59.0f);
  // A matrix entry larger than the plist's shape.
  matrix.resize(1000);
  writeInv3(dir.file("big.inv3"), {{"p/main.plist", bytesOf(inv3Plist(kShape))}, {"p/matrix.dat", matrix}});
  expectVolumeRefused(dir.file("big.inv3"), "big.inv3:matrix.dat", "header/data size mismatch: expected 120 bytes");
}

TEST(HostileInputs, DeeplyNestedPlistIsRefusedWithoutOverflowingTheStack) {
  TempDir dir;
  std::string nested;
  for (int i = 0; i < 200000; ++i) nested += "<array>";
  const std::string plist = "<?xml version=\"1.0\"?>\n<plist version=\"1.0\"><dict><key>matrix</key>" + nested;
  writeInv3(dir.file("deep.inv3"), {{"p/main.plist", bytesOf(plist)}, {"p/matrix.dat", std::vector<uint8_t>(120, 0)}});
  expectVolumeRefused(dir.file("deep.inv3"), "deep.inv3:main.plist", "nested deeper than 64 levels (expected a shallow document)");
}

TEST(HostileInputs, LongLinesAndBinaryHeadersAreNotEchoed) {
  TempDir dir;
  writeText(dir.file("long.tf"), std::string(10 << 20, '1'));
  expectRefused([&] { TransferFunction::fromFile(dir.file("long.tf")); }, "long.tf", "longer than the limit of 1.0 MiB");
  writeText(dir.file("line.tf"), "0 0 0 0 0\n" + std::string(8000, ' ') + "\n");
  expectRefused([&] { TransferFunction::fromFile(dir.file("line.tf")); }, "line.tf", "line 2 of the transfer function is longer than 4096 bytes");
  // A NRRD whose header runs into 27 KB of binary (no blank line before the data).
  std::vector<uint8_t> binary(27 << 10);
  for (size_t i = 0; i < binary.size(); ++i) binary[i] = uint8_t(i * 7 + 1) == '\n' ? 0 : uint8_t(i * 7 + 1);
  writeBytes(dir.file("bin.nrrd"), concat("NRRD0004\ntype: short\n", binary));
  expectVolumeRefused(dir.file("bin.nrrd"), "bin.nrrd", "malformed header line 3 '\\x01\\x08\\x0f");
  // A header without any line end, longer than any header is.
  writeBytes(dir.file("endless.nrrd"), concat("NRRD0004 ", std::vector<uint8_t>(3 << 20, 'x')));
  expectVolumeRefused(dir.file("endless.nrrd"), "endless.nrrd", "header is longer than 1048576 bytes");
  writeBytes(dir.file("endless.mha"), std::vector<uint8_t>(3 << 20, 'x'));
  expectVolumeRefused(dir.file("endless.mha"), "endless.mha", "header is longer than 1048576 bytes");
}

TEST(HostileInputs, NiftiFailuresPrintNothing) {
  TempDir dir;
  writeText(dir.file("g.nii"), std::string(400, 'x'));
  expectVolumeRefused(dir.file("g.nii"), "g.nii", "not a readable NIfTI-1/2 image");
  std::vector<uint8_t> bad = niftiHeader(4, 3, 5);
  bad[70] = 99;  // datatype 99: unknown to nifti_clib
  bad.resize(352 + 120);
  writeBytes(dir.file("t.nii"), bad);
  expectVolumeRefused(dir.file("t.nii"), "t.nii", "not a readable NIfTI-1/2 image (nifti_clib: '** ERROR: nifti_convert_n1hdr2nim: bad datatype')");
  writeBytes(dir.file("cut.nii.gz"), std::vector<uint8_t>{0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3, 1, 2, 3});
  expectVolumeRefused(dir.file("cut.nii.gz"), "cut.nii.gz", "NIfTI");
}

// A DICOM slice with the given pixel module, written tag by tag (gdcm::Writer checks nothing).
struct PixelShape {
  unsigned short samples = 1, allocated = 16, stored = 16, high = 15, rows = 3, columns = 4;
  std::string photometric = "MONOCHROME2";
  size_t pixelBytes = 24;
};

void writeSlice(const std::string& path, const PixelShape& s, double z) {
  gdcm::Trace::WarningOff();
  gdcm::Writer w;
  gdcm::DataSet& ds = w.GetFile().GetDataSet();
  auto put = [&](auto attribute) { ds.Replace(attribute.GetAsDataElement()); };
  gdcm::Attribute<0x0008, 0x0016> sopClass;
  sopClass.SetValue(gdcm::MediaStorage::GetMSString(gdcm::MediaStorage::CTImageStorage));
  put(sopClass);
  gdcm::Attribute<0x0008, 0x0018> sop;
  sop.SetValue("1.2.3.4." + std::to_string(int(z)));
  put(sop);
  gdcm::Attribute<0x0020, 0x000e> series;
  series.SetValue("1.2.3");
  put(series);
  gdcm::Attribute<0x0020, 0x0032> position;
  const double p[3] = {0, 0, z};
  position.SetValues(p, 3);
  put(position);
  gdcm::Attribute<0x0020, 0x0037> orientation;
  const double c[6] = {1, 0, 0, 0, 1, 0};
  orientation.SetValues(c, 6);
  put(orientation);
  gdcm::Attribute<0x0028, 0x0002> samples;
  samples.SetValue(s.samples);
  put(samples);
  gdcm::Attribute<0x0028, 0x0004> photometric;
  photometric.SetValue(s.photometric);
  put(photometric);
  gdcm::Attribute<0x0028, 0x0010> rows;
  rows.SetValue(s.rows);
  put(rows);
  gdcm::Attribute<0x0028, 0x0011> columns;
  columns.SetValue(s.columns);
  put(columns);
  gdcm::Attribute<0x0028, 0x0100> allocated;
  allocated.SetValue(s.allocated);
  put(allocated);
  gdcm::Attribute<0x0028, 0x0101> stored;
  stored.SetValue(s.stored);
  put(stored);
  gdcm::Attribute<0x0028, 0x0102> high;
  high.SetValue(s.high);
  put(high);
  gdcm::Attribute<0x0028, 0x0103> representation;
  representation.SetValue(1);
  put(representation);
  const std::vector<char> pixels(s.pixelBytes, 1);
  gdcm::DataElement pixelData(gdcm::Tag(0x7fe0, 0x0010));
  pixelData.SetVR(gdcm::VR::OW);
  pixelData.SetByteValue(pixels.data(), uint32_t(pixels.size()));
  ds.Replace(pixelData);
  w.GetFile().GetHeader().SetDataSetTransferSyntax(gdcm::TransferSyntax::ExplicitVRLittleEndian);
  w.SetFileName(path.c_str());
  ASSERT_TRUE(w.Write()) << path;
}

// A two-slice series of @p shape in a fresh directory under @p dir; returns it.
std::string series(const TempDir& dir, const std::string& name, const PixelShape& shape) {
  const std::string d = dir.file(name);
  std::filesystem::create_directories(d);
  writeSlice(d + "/s0.dcm", shape, 0.0);
  writeSlice(d + "/s1.dcm", shape, 1.0);
  return d;
}

// A two-slice series whose slice @p file is changed in place by @p patch.
std::string patchedSeries(const TempDir& dir, const std::string& name, const std::string& file,
                          const std::function<void(std::vector<uint8_t>&)>& patch) {
  const std::string d = series(dir, name, PixelShape{});
  std::vector<uint8_t> b = test::readBytes(d + "/" + file);
  patch(b);
  test::writeBytes(d + "/" + file, b);
  return d;
}

// Where the value of Photometric Interpretation ("MONOCHROME2") starts in @p b: its VR is 4 bytes
// before, its 16-bit length 2 bytes before.
size_t photometricAt(const std::vector<uint8_t>& b) {
  const std::string mono = "MONOCHROME2";
  const auto at = std::search(b.begin(), b.end(), mono.begin(), mono.end());
  if (at == b.end()) throw std::runtime_error("the test slice holds no MONOCHROME2");
  return size_t(at - b.begin());
}

TEST(HostileInputs, DicomShapesThatMadeGdcmAssertAreRefused) {
  TempDir dir;
  EXPECT_EQ(readVolume(series(dir, "good", PixelShape{})).dims(), glm::ivec3(4, 3, 2));
  PixelShape palette;
  palette.photometric = "PALETTE COLOR";
  expectVolumeRefused(series(dir, "palette", palette), "s0.dcm (slice 1 of 2)",
                      "Photometric Interpretation 'PALETTE COLOR' unsupported (expected MONOCHROME1 or MONOCHROME2");
  PixelShape oneBit;
  oneBit.allocated = oneBit.stored = 1;
  oneBit.high = 0;
  oneBit.pixelBytes = 2;
  expectVolumeRefused(series(dir, "onebit", oneBit), "s0.dcm (slice 1 of 2)", "Bits Allocated 1 unsupported (expected 8, 16 or 32)");
  PixelShape wide;
  wide.allocated = 32;
  expectVolumeRefused(series(dir, "alloc32", wide), "s0.dcm (slice 1 of 2)", "Bits Stored 16 unsupported (expected equal to Bits Allocated");
  PixelShape noSamples;
  noSamples.samples = 0;
  expectVolumeRefused(series(dir, "spp0", noSamples), "s0.dcm (slice 1 of 2)", "Samples per Pixel 0 unsupported (expected 1");
  PixelShape huge;
  huge.rows = huge.columns = 32768;
  expectVolumeRefused(series(dir, "huge", huge), "s0.dcm (slice 1 of 2)", "Pixel Data holds 24 bytes (expected 2147483648 for 32768x32768");
  // One bad slice in a good series: refused, naming the slice.
  const std::string mixed = series(dir, "mixed", PixelShape{});
  writeSlice(mixed + "/s2.dcm", wide, 2.0);
  expectVolumeRefused(mixed, "s2.dcm (slice 3 of 3)", "Bits Stored 16");
}

TEST(HostileInputs, DamagedDicomMetaAndAppendedBytesAreRefused) {
  TempDir dir;
  // Offsets 136 and 150 fall on the length fields of the first two meta elements.
  for (const int offset : {136, 150}) {
    const std::string d = series(dir, "meta" + std::to_string(offset), PixelShape{});
    std::fstream f(d + "/s1.dcm", std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(offset);
    f.write("\xff\xff\xff\xff", 4);
    f.close();
    expectVolumeRefused(d, "s1.dcm", "damaged DICOM file meta information");
  }
  const std::string d = series(dir, "appended", PixelShape{});
  {
    std::ofstream f(d + "/s0.dcm", std::ios::app | std::ios::binary);
    f << std::string(37, '\x7f') << "garbage\x01\x02";
  }
  expectVolumeRefused(d, "s0.dcm", "damaged DICOM data set: an unknown value representation");
  // An element declaring more bytes than the file holds (GDCM would allocate them first: 2 GB for a
  // 545-byte slice the fuzzer made) is refused before GDCM reads the file.
  const std::string big = patchedSeries(dir, "long", "s1.dcm", [](std::vector<uint8_t>& b) {
    const size_t at = photometricAt(b);
    b[at - 2] = b[at - 1] = 0xff;  // the element's 16-bit length: 65,535 bytes
  });
  expectVolumeRefused(big, "s1.dcm", "damaged DICOM data set: element (0028,0004) declaring 65535 bytes where");
  // A value representation that is not one (GDCM would read its value bytes as a 32-bit length).
  const std::string unknown = patchedSeries(dir, "vr", "s1.dcm", [](std::vector<uint8_t>& b) { b[photometricAt(b) - 4] = 'F'; });  // CS -> FS
  expectVolumeRefused(unknown, "s1.dcm", "damaged DICOM data set: an unknown value representation 'FS'");
  // An image-module tag of another value representation (GDCM's typed attributes assert on it).
  const std::string otherVr = patchedSeries(dir, "othervr", "s0.dcm", [](std::vector<uint8_t>& b) {
    const size_t at = photometricAt(b);
    b[at - 4] = 'A';  // CS -> AS, a valid VR but not this tag's
    b[at - 3] = 'S';
  });
  expectVolumeRefused(otherVr, "s0.dcm", "element (0028,0004) of value representation 'AS' where the standard says CS");
  // Meta information without value representations (GDCM's implicit reading of it asserts).
  const std::string implicitMeta = patchedSeries(dir, "implicit", "s0.dcm", [](std::vector<uint8_t>& b) {
    ASSERT_EQ(b[136], 'U');  // (0002,0000) UL
    b[136] = 0x4c;
    b[137] = 0x00;
  });
  expectVolumeRefused(implicitMeta, "s0.dcm", "damaged DICOM file meta information: an element without a known value representation");
  // The DICM prefix followed by something other than meta information.
  const std::string noMeta = patchedSeries(dir, "nometa", "s0.dcm", [](std::vector<uint8_t>& b) { b[132] = 0x06; });  // group 0006
  expectVolumeRefused(noMeta, "s0.dcm", "damaged DICOM file meta information: no group 0002 after the DICM prefix");
  // Five bytes after the last element: a partial element header (GDCM asserts reading it).
  const std::string partial = series(dir, "partial", PixelShape{});
  {
    std::ofstream f(partial + "/s1.dcm", std::ios::app | std::ios::binary);
    f.write("\x28\x00\x30\x00\x44", 5);
  }
  expectVolumeRefused(partial, "s1.dcm", "damaged DICOM data set: an element cut short");
  // Meta information and nothing after it (GDCM asserts reading the next tag).
  const std::string bare = series(dir, "bare", PixelShape{});
  {
    const std::vector<uint8_t> b = test::readBytes(bare + "/s0.dcm");
    size_t end = 132;
    while (end + 8 <= b.size() && b[end] == 0x02 && b[end + 1] == 0x00) {
      const bool longForm = (b[end + 4] == 'O' && b[end + 5] == 'B') || (b[end + 4] == 'U' && b[end + 5] == 'N');
      end += longForm ? 12 + (b[end + 8] | b[end + 9] << 8) : 8 + (b[end + 6] | b[end + 7] << 8);
    }
    test::writeBytes(bare + "/s0.dcm", std::vector<uint8_t>(b.begin(), b.begin() + ptrdiff_t(end)));
  }
  expectVolumeRefused(bare, "s0.dcm", "no data set after the file meta information");
  // A FIFO among the slices is not opened.
  const std::string withFifo = series(dir, "fifo", PixelShape{});
  ASSERT_EQ(::mkfifo((withFifo + "/pipe.dcm").c_str(), 0600), 0);
  alarm(60);
  EXPECT_EQ(readVolume(withFifo).dims(), glm::ivec3(4, 3, 2));
  alarm(0);
}

}  // namespace
}  // namespace hyb
