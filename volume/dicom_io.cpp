// DICOM series through GDCM, behind a firewall: GDCM asserts (aborting the process) on some
// malformed files and prints to the terminal, so every file is checked here first (its file meta
// information byte by byte, then the pixel module's tags and the pixel data's length) and GDCM's
// output is captured; what GDCM still refuses becomes one line naming the file and the slice.
// A series is read whole (readDicomSeries) or slice by slice (detail::dicomPlanes), by the same
// per-slice steps and checks.
#include <gdcmDirectory.h>
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmScanner.h>
#include <gdcmStringFilter.h>
#include <gdcmTrace.h>
#include <sys/stat.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <sstream>
#include <type_traits>
#include <variant>

#include "volume/file_util.h"
#include "volume/memory_limit.h"
#include "volume/plane_source.h"
#include "volume/reader_util.h"
#include "volume/volume_io.h"

namespace hyb {

using detail::decodeSamples;
using detail::placed;
using detail::trim;

namespace {

const gdcm::Tag kSeriesUid(0x0020, 0x000e), kSeriesNumber(0x0020, 0x0011), kSeriesDescription(0x0008, 0x103e), kModality(0x0008, 0x0060),
    kRows(0x0028, 0x0010), kColumns(0x0028, 0x0011), kPosition(0x0020, 0x0032), kOrientation(0x0020, 0x0037), kThickness(0x0018, 0x0050),
    kSlope(0x0028, 0x1053), kIntercept(0x0028, 0x1052), kPatientPosition(0x0018, 0x5100);

// Backslash-separated decimal strings (DICOM's multi-valued DS).
std::vector<double> decimals(const char* text) {
  std::vector<double> out;
  if (!text) return out;
  std::string t(text);
  for (char& c : t)
    if (c == '\\') c = ' ';
  std::istringstream in(t);
  double v;
  while (in >> v) out.push_back(v);
  return out;
}

// The DICOM files of @p dir scanned for the tags the series need.
struct DicomScan {
  gdcm::Scanner scanner;
  std::map<std::string, std::vector<std::string>> series;  // series UID -> files
  std::string value(const std::string& file, const gdcm::Tag& t) const {
    const char* v = scanner.GetValue(file.c_str(), t);
    return v ? trim(v) : std::string();
  }
};

// GDCM prints its warnings (a missing Photometric Interpretation, say) and errors on stderr; the
// reader reports what matters in its own one-line errors instead, so GDCM writes to a stream
// without a buffer, which drops everything (and cannot race between threads).
void silenceGdcm() {
  static std::ostream sink(nullptr);
  gdcm::Trace::SetStream(sink);
  gdcm::Trace::WarningOff();
  gdcm::Trace::ErrorOff();
  gdcm::Trace::DebugOff();
}

// ---------------------------------------------------------------------------------------------
// File meta information (PS3.10 7.1), checked before GDCM parses it: GDCM asserts on an undefined
// length, a sequence or a value running past the file in group 0002.

enum class DicomKind { NotDicom, Dicom };

uint16_t le16(const uint8_t* p) { return uint16_t(p[0] | p[1] << 8); }
uint32_t le32(const uint8_t* p) { return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24; }

bool isVr(const uint8_t* p) { return p[0] >= 'A' && p[0] <= 'Z' && p[1] >= 'A' && p[1] <= 'Z'; }

// The value representations of PS3.5 6.2: GDCM reads an element of any other as implicit, taking
// its value bytes for a 32-bit length (a 545-byte slice made it allocate 825 MB that way).
bool knownVr(const uint8_t* p) {
  static const char* kVrs[] = {"AE", "AS", "AT", "CS", "DA", "DS", "DT", "FL", "FD", "IS", "LO", "LT", "OB", "OD", "OF", "OL", "OV",
                               "OW", "PN", "SH", "SL", "SQ", "SS", "ST", "SV", "TM", "UC", "UI", "UL", "UN", "UR", "US", "UT", "UV"};
  return std::any_of(std::begin(kVrs), std::end(kVrs), [&](const char* v) { return p[0] == v[0] && p[1] == v[1]; });
}

// Explicit VRs whose length takes 4 bytes after 2 reserved ones (PS3.5 7.1.2).
bool longVr(const uint8_t* p) {
  static const char* kLong[] = {"OB", "OW", "OF", "OD", "OL", "OV", "SQ", "UT", "UN", "UC", "UR", "SV", "UV"};
  return std::any_of(std::begin(kLong), std::end(kLong), [&](const char* v) { return p[0] == v[0] && p[1] == v[1]; });
}

// Longest file meta information accepted (real ones are a few hundred bytes).
constexpr size_t kMaxMetaBytes = 64 << 10;

// The value representation GDCM's typed reading of the image module expects of a tag (its
// attributes assert on another), or null for tags it reads as they come.
const char* imageModuleVr(uint16_t group, uint16_t element) {
  static const struct { uint16_t g, e; const char* vr; } kTags[] = {
      {0x0008, 0x0060, "CS"}, {0x0018, 0x0050, "DS"}, {0x0018, 0x0088, "DS"}, {0x0020, 0x0032, "DS"}, {0x0020, 0x0037, "DS"},
      {0x0028, 0x0002, "US"}, {0x0028, 0x0004, "CS"}, {0x0028, 0x0006, "US"}, {0x0028, 0x0008, "IS"}, {0x0028, 0x0010, "US"},
      {0x0028, 0x0011, "US"}, {0x0028, 0x0030, "DS"}, {0x0028, 0x0100, "US"}, {0x0028, 0x0101, "US"}, {0x0028, 0x0102, "US"},
      {0x0028, 0x0103, "US"}, {0x0028, 0x1050, "DS"}, {0x0028, 0x1051, "DS"}, {0x0028, 0x1052, "DS"}, {0x0028, 0x1053, "DS"}};
  for (const auto& t : kTags)
    if (t.g == group && t.e == element) return t.vr;
  return nullptr;
}

// The data set after the file meta information, walked element by element before GDCM reads it:
// GDCM allocates what an element declares before it finds the file shorter (a 545-byte slice
// made it allocate 2 GB), so every declared length must fit in the bytes left. Sequences and
// encapsulated pixel data of undefined length are walked item by item, 16 levels deep at most.
class DataSetWalk {
 public:
  DataSetWalk(const std::vector<uint8_t>& bytes, bool explicitVr, bool bigEndian, const std::string& file)
      : mB(bytes), mExplicit(explicitVr), mBig(bigEndian), mFile(file) {}
  // Walks elements from @p pos to @p end (or to an item delimiter when @p inItem); returns where it stopped.
  size_t elements(size_t pos, size_t end, int depth, bool inItem) {
    if (depth > 16) fail(pos, "sequences nested more than 16 deep");
    while (pos + 8 <= end) {
      const uint16_t group = u16(pos), element = u16(pos + 2);
      if (group == 0xfffe) {
        if (element == 0xe00d && inItem) return pos + 8;  // item delimiter
        fail(pos, "an item tag outside a sequence");
      }
      const bool explicitHere = mExplicit && group != 0xfffe;
      size_t header = 8;
      uint64_t length;
      bool sequence = false, maySequence = !explicitHere;
      if (explicitHere) {
        const uint8_t* vr = mB.data() + pos + 4;
        if (!knownVr(vr)) fail(pos, detail::concat("an unknown value representation ", quotedExcerpt(std::string_view(reinterpret_cast<const char*>(vr), 2))));
        if (const char* want = imageModuleVr(group, element); want && (vr[0] != want[0] || vr[1] != want[1]))
          fail(pos, detail::concat("element (", hex(group), ",", hex(element), ") of value representation ",
                                   quotedExcerpt(std::string_view(reinterpret_cast<const char*>(vr), 2)), " where the standard says ", want));
        sequence = vr[0] == 'S' && vr[1] == 'Q';
        maySequence = sequence || (vr[0] == 'U' && vr[1] == 'N') || (vr[0] == 'O' && vr[1] == 'B') || (vr[0] == 'O' && vr[1] == 'W');
        if (longVr(vr)) {
          if (pos + 12 > end) fail(pos, "an element cut short");
          length = u32(pos + 8);
          header = 12;
        } else {
          length = u16(pos + 6);
        }
      } else {
        length = u32(pos + 4);
      }
      pos += header;
      if (length == 0xffffffffu) {
        if (!maySequence) fail(pos - header, "an undefined length on a value that cannot hold items");
        pos = items(pos, end, depth + 1, group == 0x7fe0 && element == 0x0010);
        continue;
      }
      if (length > end - pos) fail(pos - header, detail::concat("element (", hex(group), ",", hex(element), ") declaring ", length,
                                                               " bytes where ", end - pos, " are left"));
      if (sequence) elementsOfItems(pos, pos + size_t(length), depth + 1);
      pos += size_t(length);
    }
    if (inItem) fail(pos, "an item without its delimiter");
    if (pos < end) fail(pos, "an element cut short");  // GDCM asserts on a partial element header
    return pos;
  }

 private:
  // Items of a sequence (data sets, walked) or @p fragments of encapsulated pixel data, up to the
  // sequence delimiter.
  size_t items(size_t pos, size_t end, int depth, bool fragments) {
    for (;;) {
      if (pos + 8 > end) fail(pos, "a sequence without its delimiter");
      const uint16_t group = u16(pos), element = u16(pos + 2);
      const uint32_t length = u32(pos + 4);
      pos += 8;
      if (group != 0xfffe) fail(pos - 8, "a sequence holding something other than items");
      if (element == 0xe0dd) return pos;  // sequence delimiter
      if (element != 0xe000) fail(pos - 8, "an unknown item tag");
      if (length == 0xffffffffu) {
        pos = elements(pos, end, depth, true);
        continue;
      }
      if (length > end - pos) fail(pos - 8, detail::concat("an item declaring ", length, " bytes where ", end - pos, " are left"));
      if (!fragments) elements(pos, pos + length, depth, false);
      pos += length;
    }
  }
  // A sequence of defined length: its items, each checked.
  void elementsOfItems(size_t pos, size_t end, int depth) {
    while (pos + 8 <= end) {
      if (u16(pos) != 0xfffe || u16(pos + 2) != 0xe000) fail(pos, "a sequence holding something other than items");
      const uint32_t length = u32(pos + 4);
      pos += 8;
      if (length == 0xffffffffu) {
        pos = elements(pos, end, depth, true);
        continue;
      }
      if (length > end - pos) fail(pos - 8, detail::concat("an item declaring ", length, " bytes where ", end - pos, " are left"));
      elements(pos, pos + length, depth, false);
      pos += length;
    }
  }
  uint16_t u16(size_t at) const { return mBig ? uint16_t(mB[at] << 8 | mB[at + 1]) : le16(mB.data() + at); }
  uint32_t u32(size_t at) const {
    return mBig ? uint32_t(mB[at]) << 24 | uint32_t(mB[at + 1]) << 16 | uint32_t(mB[at + 2]) << 8 | mB[at + 3] : le32(mB.data() + at);
  }
  static std::string hex(uint16_t v) {
    char s[5];
    std::snprintf(s, sizeof s, "%04x", v);
    return s;
  }
  [[noreturn]] void fail(size_t at, const std::string& what) const {
    HYB_THROW(IoError, mFile, ": damaged DICOM data set: ", what, " at byte ", at, " (expected elements whose lengths fit in the file)");
  }
  const std::vector<uint8_t>& mB;
  bool mExplicit, mBig;
  std::string mFile;
};

// Whether @p file looks like DICOM (the "DICM" prefix, or a data set starting at group 0002 or
// 0008 as old files do); throws when it is DICOM whose file meta information would make GDCM
// assert.
DicomKind checkFileMeta(const InputFile& file) {
  std::vector<uint8_t> head(size_t(std::min<uint64_t>(file.size(), 132 + kMaxMetaBytes)));
  file.read(0, head.size(), head.data());
  size_t pos = 0;
  if (head.size() >= 132 && std::memcmp(head.data() + 128, "DICM", 4) == 0) pos = 132;
  else if (head.size() < 8 || (le16(head.data()) != 0x0002 && le16(head.data()) != 0x0008)) return DicomKind::NotDicom;
  auto damaged = [&](const std::string& what) {
    HYB_THROW(IoError, file.path(), ": damaged DICOM file meta information: ", what, " at byte ", pos,
              " (expected group 0002 elements of defined length within the file)");
  };
  // After the prefix GDCM expects meta information; without it its guesses allocated 1.6 GB for a 394-byte file.
  if (pos == 132 && (head.size() < 140 || le16(head.data() + pos) != 0x0002)) damaged("no group 0002 after the DICM prefix");
  std::string syntax;  // the Transfer Syntax UID (0002,0010)
  while (pos + 8 <= head.size() && le16(head.data() + pos) == 0x0002) {
    const uint8_t* e = head.data() + pos;
    size_t headerBytes = 8;
    uint64_t length;
    // PS3.10 7.1: the meta information is explicit VR (GDCM's reading of implicit meta asserts).
    if (!knownVr(e + 4)) damaged("an element without a known value representation");
    if (longVr(e + 4)) {
      if (e[4] == 'S' && e[5] == 'Q') damaged("a sequence");
      if (pos + 12 > head.size()) damaged("an element cut short");
      length = le32(e + 8);
      headerBytes = 12;
    } else {
      length = le16(e + 6);
    }
    if (length == 0xffffffffu) damaged("an undefined length");
    if (pos + headerBytes + length > file.size()) damaged(detail::concat("a length of ", length, " past the end of the file"));
    if (pos + headerBytes + length > head.size()) damaged(detail::concat("more than ", kMaxMetaBytes, " bytes of meta information"));
    if (le16(e + 2) == 0x0010) syntax.assign(reinterpret_cast<const char*>(e + headerBytes), size_t(length));
    pos += headerBytes + size_t(length);
  }
  // GDCM asserts when it finds the end of the file where the element after the meta information should be.
  if (pos + 8 > file.size()) damaged("no data set after the file meta information");
  while (!syntax.empty() && (syntax.back() == '\0' || syntax.back() == ' ')) syntax.pop_back();
  if (syntax == "1.2.840.10008.1.2.1.99") return DicomKind::Dicom;  // deflated: lengths are inside the compressed stream
  const std::vector<uint8_t> bytes = file.bytes(0, file.size());
  const bool explicitVr = syntax.empty() ? pos + 6 <= bytes.size() && isVr(bytes.data() + pos + 4) : syntax != "1.2.840.10008.1.2";
  DataSetWalk(bytes, explicitVr, syntax == "1.2.840.10008.1.2.2", file.path()).elements(pos, bytes.size(), 0, false);
  return DicomKind::Dicom;
}

// ---------------------------------------------------------------------------------------------
// Pixel module, checked before GDCM decodes it: GDCM asserts on palette colour without its
// tables, 1-bit pixels, unused bits in 8- or 32-bit pixels, zero samples per pixel; a length that
// is not the image's lets a small file claim a huge slice.

const gdcm::Tag kPixelData(0x7fe0, 0x0010), kSamplesPerPixel(0x0028, 0x0002), kPhotometric(0x0028, 0x0004), kFrames(0x0028, 0x0008),
    kBitsAllocated(0x0028, 0x0100), kBitsStored(0x0028, 0x0101), kHighBit(0x0028, 0x0102), kPixelRepresentation(0x0028, 0x0103);

// What one slice's pixel module declares.
struct PixelModule {
  int rows = 0, columns = 0, bitsAllocated = 0;
};

// An unsigned integer tag of @p ds as text (GDCM's StringFilter swaps and formats it); -1 when absent.
long tagNumber(const gdcm::StringFilter& sf, const gdcm::DataSet& ds, const gdcm::Tag& t) {
  if (!ds.FindDataElement(t) || ds.GetDataElement(t).IsEmpty()) return -1;
  const std::string text = trim(sf.ToString(t));
  char* end = nullptr;
  const long v = std::strtol(text.c_str(), &end, 10);
  return end == text.c_str() ? -1 : v;
}

// The length of the Pixel Data element whose value starts at @p valueStart, read from the file;
// -1 when it is not there, 0xffffffff for encapsulated (compressed) data.
int64_t pixelDataLength(const InputFile& file, uint64_t valueStart, const gdcm::TransferSyntax& ts) {
  const uint64_t headerBytes = ts.IsImplicit() ? 8 : 12;
  if (valueStart < headerBytes || valueStart > file.size()) return -1;
  uint8_t h[12];
  file.read(valueStart - headerBytes, headerBytes, h);
  const bool big = ts.GetSwapCode() == gdcm::SwapCode::BigEndian;
  auto u16 = [&](const uint8_t* q) { return big ? uint16_t(q[0] << 8 | q[1]) : le16(q); };
  if (u16(h) != 0x7fe0 || u16(h + 2) != 0x0010) return -1;
  const uint8_t* l = h + headerBytes - 4;
  return big ? int64_t(uint32_t(l[0]) << 24 | uint32_t(l[1]) << 16 | uint32_t(l[2]) << 8 | l[3]) : int64_t(le32(l));
}

// Checks what GDCM needs to decode @p file without asserting; @p where names it and its slice.
PixelModule checkPixelModule(const InputFile& file, const std::string& where) {
  gdcm::Reader reader;
  reader.SetFileName(file.path().c_str());
  if (!reader.ReadUpToTag(kPixelData, {kPixelData})) HYB_THROW(IoError, where, ": not a readable DICOM file (expected a DICOM image)");
  const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  gdcm::StringFilter sf;
  sf.SetFile(reader.GetFile());
  auto number = [&](const gdcm::Tag& t) { return tagNumber(sf, ds, t); };
  auto refuse = [&](const char* name, long v, const char* expected) {
    HYB_THROW(IoError, where, ": ", name, " ", v < 0 ? std::string("missing") : std::to_string(v), " unsupported (expected ", expected, ")");
  };
  const long spp = number(kSamplesPerPixel);
  if (spp != 1) refuse("Samples per Pixel", spp, "1, greyscale");
  const std::string photometric = trim(sf.ToString(kPhotometric));
  if (photometric != "MONOCHROME1" && photometric != "MONOCHROME2")
    HYB_THROW(IoError, where, ": Photometric Interpretation ", quotedExcerpt(photometric), " unsupported (expected MONOCHROME1 or MONOCHROME2, greyscale)");
  const long allocated = number(kBitsAllocated), stored = number(kBitsStored), high = number(kHighBit);
  if (allocated != 8 && allocated != 16 && allocated != 32) refuse("Bits Allocated", allocated, "8, 16 or 32");
  // GDCM masks unused bits only in 16-bit pixels; 8- and 32-bit ones must use every bit.
  if (stored < 1 || stored > allocated || (allocated != 16 && stored != allocated))
    refuse("Bits Stored", stored, allocated == 16 ? "1 to 16 with 16 bits allocated" : "equal to Bits Allocated for 8- or 32-bit pixels");
  if (high < stored - 1 || high >= allocated) refuse("High Bit", high, "from Bits Stored - 1 to Bits Allocated - 1");
  const long representation = number(kPixelRepresentation);
  if (representation != 0 && representation != 1) refuse("Pixel Representation", representation, "0 or 1");
  const long frames = number(kFrames);
  if (frames > 1) HYB_THROW(IoError, where, ": multi-frame images are not supported (expected one slice per file)");
  PixelModule m;
  const long rows = number(kRows), columns = number(kColumns);
  if (rows < 1 || rows > kMaxDim) refuse("Rows", rows, "1 to 32768");
  if (columns < 1 || columns > kMaxDim) refuse("Columns", columns, "1 to 32768");
  m.rows = int(rows);
  m.columns = int(columns);
  m.bitsAllocated = int(allocated);
  // The pixel data's length must be the image's (odd lengths padded by one byte, PS3.5 7.1.1).
  const gdcm::TransferSyntax& ts = reader.GetFile().GetHeader().GetDataSetTransferSyntax();
  if (ts == gdcm::TransferSyntax::DeflatedExplicitVRLittleEndian) return m;  // positions are in the inflated stream
  const uint64_t expected = uint64_t(rows) * uint64_t(columns) * uint64_t(allocated / 8);
  const int64_t length = pixelDataLength(file, reader.GetStreamCurrentPosition(), ts);
  if (length < 0) HYB_THROW(IoError, where, ": no Pixel Data (expected a DICOM image)");
  if (length == 0xffffffff) {
    if (!ts.IsEncapsulated()) HYB_THROW(IoError, where, ": Pixel Data of undefined length in an uncompressed transfer syntax");
    return m;
  }
  if (uint64_t(length) != expected && uint64_t(length) != expected + (expected & 1))
    HYB_THROW(IoError, where, ": Pixel Data holds ", length, " bytes (expected ", expected, " for ", columns, "x", rows, " pixels of ", allocated,
              " bits)");
  if (reader.GetStreamCurrentPosition() + uint64_t(length) > file.size())
    HYB_THROW(IoError, where, ": Pixel Data of ", length, " bytes runs past the end of the file (expected ", expected, " bytes in the file)");
  return m;
}

void scanDicom(const std::string& dir, DicomScan* scan) {
  silenceGdcm();
  gdcm::Directory directory;
  if (directory.Load(dir, false) == 0) HYB_THROW(IoError, dir, ": directory holds no files (expected a DICOM series)");
  // Only regular files that pass the meta check reach GDCM (a FIFO would block its open).
  std::vector<std::string> candidates;
  for (const std::string& f : directory.GetFilenames()) {
    struct stat st {};
    if (::stat(f.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) continue;
    if (checkFileMeta(InputFile(f)) == DicomKind::Dicom) candidates.push_back(f);
  }
  for (const gdcm::Tag& t : {kSeriesUid, kSeriesNumber, kSeriesDescription, kModality, kRows, kColumns, kPosition, kOrientation, kThickness,
                             kSlope, kIntercept, kPatientPosition})
    scan->scanner.AddTag(t);
  if (!scan->scanner.Scan(candidates)) HYB_THROW(IoError, dir, ": cannot scan the directory for DICOM files");
  for (const std::string& f : candidates)
    if (scan->scanner.IsKey(f.c_str())) scan->series[scan->value(f, kSeriesUid)].push_back(f);
  if (scan->series.empty()) HYB_THROW(IoError, dir, ": no DICOM files found (expected a directory holding one series)");
}

DicomSeriesInfo seriesInfo(const DicomScan& scan, const std::string& uid, const std::vector<std::string>& files) {
  DicomSeriesInfo s;
  s.uid = uid;
  s.slices = files.size();
  const std::string& f = files.front();
  s.number = scan.value(f, kSeriesNumber);
  s.description = scan.value(f, kSeriesDescription);
  s.modality = scan.value(f, kModality);
  s.columns = std::atoi(scan.value(f, kColumns).c_str());
  s.rows = std::atoi(scan.value(f, kRows).c_str());
  return s;
}

// One line naming series @p s.
std::string describe(const DicomSeriesInfo& s) {
  return detail::concat("", quotedExcerpt(s.uid), " (", s.modality.empty() ? "?" : s.modality, s.description.empty() ? "" : ", " + s.description, ", ",
                        s.slices, " slices of ", s.columns, "x", s.rows, ")");
}

// A slice of the chosen series and where it lies.
struct DicomSlice {
  std::string file;
  glm::dvec3 position;
  double depth;  // along the slices' normal, mm
};

// A series chosen in a directory, its geometry checked and its slices ordered: what the whole
// reader and the streamed planes share.
struct SeriesLayout {
  std::string dir;
  DicomSeriesInfo chosen;
  std::vector<std::string> warnings;
  PatientFrame axes;               // the slices' rows, columns and normal
  std::vector<DicomSlice> slices;  // ordered along the normal
  double zSpacing = 1.0;
  std::string patientPosition, thickness;  // the first slice's, for the info
};

SeriesLayout seriesLayout(const std::string& dir, const std::string& seriesUid) {
  DicomScan scan;
  scanDicom(dir, &scan);
  SeriesLayout l;
  l.dir = dir;
  // The series: the one named, or the largest (with a line naming it when there are several).
  std::vector<DicomSeriesInfo> all;
  for (const auto& [uid, files] : scan.series) all.push_back(seriesInfo(scan, uid, files));
  std::stable_sort(all.begin(), all.end(), [](const DicomSeriesInfo& a, const DicomSeriesInfo& b) { return a.slices > b.slices; });
  std::string listing;
  for (const DicomSeriesInfo& s : all) listing += (listing.empty() ? "" : "; ") + describe(s);
  const DicomSeriesInfo* chosen = &all.front();
  if (!seriesUid.empty()) {
    const auto it = std::find_if(all.begin(), all.end(), [&](const DicomSeriesInfo& s) { return s.uid == seriesUid; });
    if (it == all.end()) HYB_THROW(ValueError, "--series ", quotedExcerpt(seriesUid), ": no such series in ", dir, " (it holds ", listing, ")");
    chosen = &*it;
  } else if (all.size() > 1) {
    l.warnings.push_back(detail::concat(dir, ": ", all.size(), " series; reading the largest, ", describe(*chosen),
                                        " (choose another with --series UID: ", listing, ")"));
  }
  l.chosen = *chosen;
  const std::vector<std::string>& files = scan.series.at(chosen->uid);

  // Geometry (DICOM PS3.3 C.7.6.2): the rows' and columns' directions from Image Orientation
  // (Patient), the slices ordered by Image Position (Patient) along their normal, which must hold
  // every position (no gantry tilt) at one spacing.
  const std::vector<double> iop = decimals(scan.scanner.GetValue(files.front().c_str(), kOrientation));
  glm::dmat3 direction(1.0);
  const bool oriented = iop.size() == 6;
  if (oriented) {
    direction[0] = glm::dvec3(iop[0], iop[1], iop[2]);
    direction[1] = glm::dvec3(iop[3], iop[4], iop[5]);
    direction[2] = glm::cross(direction[0], direction[1]);
  } else if (files.size() > 1) {
    HYB_THROW(IoError, files.front(), ": Image Orientation (Patient) missing or malformed (expected six cosines to order the slices)");
  } else {
    l.warnings.push_back(files.front() + ": no Image Orientation (Patient): the slice's axes are taken as LPS");
  }
  l.axes = makePatientFrame(direction, glm::dvec3(0.0), files.front() + " (Image Orientation (Patient))");
  std::vector<DicomSlice>& slices = l.slices;
  for (const std::string& f : files) {
    const std::vector<double> ipp = decimals(scan.scanner.GetValue(f.c_str(), kPosition));
    if (ipp.size() != 3 && files.size() > 1)
      HYB_THROW(IoError, f, ": Image Position (Patient) missing or malformed (expected three numbers to order the slices)");
    const glm::dvec3 p = ipp.size() == 3 ? glm::dvec3(ipp[0], ipp[1], ipp[2]) : glm::dvec3(0.0);
    if (oriented && f != files.front()) {
      const std::vector<double> other = decimals(scan.scanner.GetValue(f.c_str(), kOrientation));
      bool same = other.size() == 6;
      for (size_t c = 0; same && c < 6; ++c) same = std::abs(other[c] - iop[c]) <= 1e-4;
      if (!same) HYB_THROW(IoError, f, ": Image Orientation (Patient) differs from ", files.front(), "'s (expected one orientation for the series)");
    }
    slices.push_back({f, p, glm::dot(p, l.axes.direction[2])});
  }
  std::sort(slices.begin(), slices.end(), [](const DicomSlice& a, const DicomSlice& b) { return a.depth < b.depth; });
  if (slices.size() > 1) {
    l.zSpacing = (slices.back().depth - slices.front().depth) / double(slices.size() - 1);
    const double zSpacing = l.zSpacing;
    for (size_t k = 1; k < slices.size(); ++k) {
      const double step = slices[k].depth - slices[k - 1].depth;
      if (step <= 1e-3 * std::max(zSpacing, 1e-3))
        HYB_THROW(IoError, slices[k].file, ": at the same position as ", slices[k - 1].file, " along the slice normal (expected one slice per position)");
      if (std::abs(step - zSpacing) > std::max(1e-3, 1e-2 * zSpacing))
        HYB_THROW(IoError, dir, ": slices are not evenly spaced along the normal (", slices[k - 1].file, " to ", slices[k].file, ": ", step,
                  " mm, the series' mean ", zSpacing, " mm; expected a regular grid)");
      // Positions must run along the normal: a gantry tilt moves them across the image plane.
      const glm::dvec3 offset = slices[k].position - slices.front().position;
      const double across = glm::length(offset - glm::dot(offset, l.axes.direction[2]) * l.axes.direction[2]);
      if (across > std::max(1e-2, 1e-3 * glm::length(offset)))
        HYB_THROW(IoError, dir, ": slice positions move ", across, " mm across the image plane by ", slices[k].file,
                  " (gantry tilt or a sheared series: the grid is not orthogonal); resample it to an orthogonal grid first "
                  "(e.g. Slicer or ITK), it is refused rather than drawn sheared");
    }
  } else if (const std::vector<double> t = decimals(scan.scanner.GetValue(slices.front().file.c_str(), kThickness)); t.size() == 1 && t[0] > 0) {
    l.zSpacing = t[0];
  }
  l.patientPosition = scan.value(slices.front().file, kPatientPosition);
  l.thickness = scan.value(slices.front().file, kThickness);
  return l;
}

// Slice @p s of @p l named for messages: its file and its place in the series.
std::string sliceWhere(const SeriesLayout& l, size_t s) {
  return detail::concat(l.slices[s].file, " (slice ", s + 1, " of ", l.slices.size(), ")");
}

// Refuses a slice whose Columns and Rows (@p module) are not the first slice's (@p dims).
void checkSliceSize(const std::string& where, const PixelModule& module, const glm::ivec3& dims) {
  if (module.columns != dims.x || module.rows != dims.y)
    HYB_THROW(IoError, where, ": slice is ", module.columns, "x", module.rows, ", expected ", dims.x, "x", dims.y, " like the first slice");
}

// One slice's image as GDCM reads it, its pixels not decoded yet.
struct SliceImage {
  gdcm::ImageReader reader;
  ScalarType type = ScalarType::Int16;  // of the decoded pixels
  glm::ivec2 size{0};
  glm::dvec2 spacing{1.0};  // between columns, between rows (Pixel Spacing's second and first)
  double slope = 1.0, intercept = 0.0;
  // The values GDCM can decode: the type's range, or Bits Stored's where GDCM clears the unused bits
  // of 16-bit pixels (ImageCodec::DoOverlayCleanup, run by its raw and RLE decoders with the
  // header's pixel format; the JPEG family's decoders may take another from the stream).
  double lo = 0.0, hi = 0.0;
};

// The series' rows, columns and their spacings from its first slice's @p image.
void takeGrid(const SliceImage& image, const std::string& dir, glm::ivec3* dims, glm::dvec3* spacing) {
  dims->x = image.size.x;
  dims->y = image.size.y;
  validateDims(*dims, dir);
  spacing->x = image.spacing.x;
  spacing->y = image.spacing.y;
}

// Reads slice @p file (its pixel module @p module checked) with GDCM, checking what it decodes to.
void readSliceImage(const std::string& file, const std::string& where, const PixelModule& module, SliceImage* out) {
  gdcm::ImageReader& reader = out->reader;
  reader.SetFileName(file.c_str());
  if (!reader.Read()) HYB_THROW(IoError, where, ": not a readable DICOM image (GDCM refused its data set; expected a well-formed DICOM file)");
  const gdcm::Image& image = reader.GetImage();
  const gdcm::PixelFormat& pf = image.GetPixelFormat();
  if (pf.GetSamplesPerPixel() != 1)
    HYB_THROW(IoError, where, ": ", pf.GetSamplesPerPixel(), " samples per pixel (expected 1, greyscale)");
  if (image.GetNumberOfDimensions() == 3 && image.GetDimension(2) > 1)
    HYB_THROW(IoError, where, ": multi-frame images are not supported (expected one slice per file)");
  out->size = glm::ivec2(int(image.GetDimension(0)), int(image.GetDimension(1)));
  if (out->size.x != module.columns || out->size.y != module.rows)
    HYB_THROW(IoError, where, ": GDCM decodes ", out->size.x, "x", out->size.y, " pixels (expected the ", module.columns, "x", module.rows,
              " of Columns and Rows)");
  switch (pf.GetScalarType()) {
    case gdcm::PixelFormat::UINT8: out->type = ScalarType::UInt8; break;
    case gdcm::PixelFormat::INT8: out->type = ScalarType::Int8; break;
    case gdcm::PixelFormat::UINT16: out->type = ScalarType::UInt16; break;
    case gdcm::PixelFormat::INT16: out->type = ScalarType::Int16; break;
    case gdcm::PixelFormat::UINT32: out->type = ScalarType::UInt32; break;
    case gdcm::PixelFormat::INT32: out->type = ScalarType::Int32; break;
    case gdcm::PixelFormat::FLOAT32: out->type = ScalarType::Float32; break;
    case gdcm::PixelFormat::FLOAT64: out->type = ScalarType::Float64; break;
    default: HYB_THROW(IoError, where, ": unsupported pixel format ", pf.GetScalarTypeAsString());
  }
  const double* sp = image.GetSpacing();
  out->spacing = glm::dvec2(sp[0], sp[1]);
  out->slope = image.GetSlope();
  out->intercept = image.GetIntercept();
  const bool isFloat = out->type == ScalarType::Float32 || out->type == ScalarType::Float64;
  const bool isSigned = out->type == ScalarType::Int8 || out->type == ScalarType::Int16 || out->type == ScalarType::Int32;
  int bits = int(scalarSize(out->type)) * 8;
  const gdcm::TransferSyntax& ts = image.GetTransferSyntax();
  if (pf.GetBitsAllocated() == 16 && bits == 16 && (!ts.IsEncapsulated() || ts == gdcm::TransferSyntax::RLELossless)) bits = pf.GetBitsStored();
  out->lo = isFloat ? -std::numeric_limits<double>::infinity() : isSigned ? -std::ldexp(1.0, bits - 1) : 0.0;
  out->hi = isFloat ? std::numeric_limits<double>::infinity() : std::ldexp(1.0, isSigned ? bits - 1 : bits) - 1.0;
  // Samples are held as float at widest: a rescale whose values leave its range would make infinities.
  const double a = isFloat ? 0.0 : out->lo * out->slope + out->intercept, b = isFloat ? 0.0 : out->hi * out->slope + out->intercept;
  if (!std::isfinite(out->slope) || !std::isfinite(out->intercept) || !std::isfinite(a) || !std::isfinite(b) ||
      std::max(std::abs(a), std::abs(b)) > double(std::numeric_limits<float>::max()))
    HYB_THROW(IoError, where, ": Rescale Slope (0028,1053) ", out->slope, " and Rescale Intercept (0028,1052) ", out->intercept,
              " take the pixel values ", out->lo, "..", out->hi, " beyond the float range (expected rescaled values within +-3.4e38)");
}

// The @p image's decoded pixels in the type a volume holds them in (decodeSamples).
SampleArray sliceSamples(const SliceImage& image, const std::string& where) {
  const size_t count = size_t(image.size.x) * size_t(image.size.y);
  const gdcm::Image& im = image.reader.GetImage();
  if (im.GetBufferLength() != count * scalarSize(image.type))
    HYB_THROW(IoError, where, ": decoded pixel data holds ", im.GetBufferLength(), " bytes (expected ", count * scalarSize(image.type), ")");
  std::vector<char> buffer(im.GetBufferLength());
  if (!im.GetBuffer(buffer.data())) HYB_THROW(IoError, where, ": pixel data missing or truncated");
  return decodeSamples(reinterpret_cast<const uint8_t*>(buffer.data()), count, image.type, std::endian::native == std::endian::big);
}

// The series' frame, info and warnings on @p v (the whole volume or its description).
Volume placedSeries(Volume v, const SeriesLayout& l, double slopeFirst, double interceptFirst, bool rescaled) {
  v = placed(std::move(v), makePatientFrame(l.axes.direction, l.slices.front().position, l.dir), l.warnings);
  v.addInfo("modality", l.chosen.modality.empty() ? "(none)" : l.chosen.modality);
  v.addInfo("series", describe(l.chosen) + (l.chosen.number.empty() ? "" : ", number " + l.chosen.number));
  if (!l.patientPosition.empty()) v.addInfo("position", l.patientPosition + " (Patient Position)");
  if (!l.thickness.empty())
    v.addInfo("thickness", l.thickness + " mm (Slice Thickness; slices " + detail::concat(l.zSpacing) + " mm apart)");
  v.addInfo("rescale", detail::concat("slope ", slopeFirst, ", intercept ", interceptFirst, rescaled ? " (applied)" : ""));
  return v;
}

// Whether slope * v + intercept is a value of @p stored (the samples' type) for every integer v in
// [lo, hi]: then rescaleSamples keeps samples of that type (float holds any value).
bool holdsAll(ScalarType stored, double lo, double hi, double slope, double intercept) {
  if (stored == ScalarType::Float32) return true;
  if (slope != std::floor(slope) || intercept != std::floor(intercept)) return false;  // (NaN too)
  const double a = lo * slope + intercept, b = hi * slope + intercept;  // the extremes (linear in v)
  return detail::withFileType(stored, [&](auto zero) {
    using T = decltype(zero);
    return holdsExactly<T>(std::min(a, b)) && holdsExactly<T>(std::max(a, b));
  });
}

// What one slice's header decided when the series was opened.
struct SliceHeader {
  ScalarType type;
  double slope, intercept;
};

// The planes of a DICOM series, each decoded from its slice file when it is read: the file is
// checked as the whole reader checks it (it may have changed since the series was opened) and its
// samples rescaled as readDicomSeries rescales them, into the stored type its headers decided.
class DicomPlanes final : public PlaneSource {
 public:
  DicomPlanes(Volume description, SeriesLayout layout, std::vector<SliceHeader> headers)
      : PlaneSource(std::move(description), layout.dir), mLayout(std::move(layout)), mHeaders(std::move(headers)) {}
  void rewind() override { mNext = 0; }
  void read(int count, SampleArray* out, size_t first) override {
    HYB_CHECK(count >= 0 && mNext + count <= dims().z && first + size_t(count) * planeSize() <= sampleCount(*out) &&
              hyb::storedType(*out) == storedType());
    for (int k = 0; k < count; ++k, ++mNext) {
      decodePlane(size_t(mNext));
      std::visit(
          [&](const auto& plane) {
            using T = typename std::remove_reference_t<decltype(plane)>::value_type;
            std::copy(plane.begin(), plane.end(), std::get<std::vector<T>>(*out).begin() + ptrdiff_t(first + size_t(k) * planeSize()));
          },
          mPlane);
    }
  }

 private:
  // Decodes plane @p z into mPlane.
  void decodePlane(size_t z) {
    const std::string& file = mLayout.slices[z].file;
    const std::string where = sliceWhere(mLayout, z);
    const SliceHeader& h = mHeaders[z];
    PixelModule module;
    {
      // The checks that keep GDCM from asserting, made again: the file may have changed since it was scanned.
      const InputFile f(file);
      if (checkFileMeta(f) != DicomKind::Dicom)
        HYB_THROW(IoError, where, ": no longer a DICOM file (expected the slice the series was opened with)");
      module = checkPixelModule(f, where);
      checkSliceSize(where, module, dims());
    }
    SliceImage image;
    readSliceImage(file, where, module, &image);
    if (image.type != h.type || image.slope != h.slope || image.intercept != h.intercept)
      HYB_THROW(IoError, where, ": changed since the series was opened: ", scalarName(image.type), " pixels, rescale slope ", image.slope,
                ", intercept ", image.intercept, " (expected ", scalarName(h.type), ", slope ", h.slope, ", intercept ", h.intercept, ")");
    const SampleArray slice = sliceSamples(image, where);
    if (sampleCount(mPlane) != planeSize() || hyb::storedType(mPlane) != storedType()) mPlane = detail::allocateSamples(storedType(), planeSize());
    detail::rescaleSamples(&mPlane, 0, slice, h.slope, h.intercept);
    if (hyb::storedType(mPlane) != storedType())  // (GDCM decoded values outside the range its header gives)
      HYB_THROW(IoError, where, ": decoded values that ", scalarName(storedType()), " samples do not hold (expected values within the range of "
                "its Bits Stored and Pixel Representation, rescaled)");
  }

  SeriesLayout mLayout;
  std::vector<SliceHeader> mHeaders;  // per plane
  int mNext = 0;
  SampleArray mPlane;  // the plane last decoded, rescaled
};

}  // namespace

std::vector<DicomSeriesInfo> listDicomSeries(const std::string& dir) {
  DicomScan scan;
  scanDicom(dir, &scan);
  std::vector<DicomSeriesInfo> out;
  for (const auto& [uid, files] : scan.series) out.push_back(seriesInfo(scan, uid, files));
  std::stable_sort(out.begin(), out.end(), [](const DicomSeriesInfo& a, const DicomSeriesInfo& b) { return a.slices > b.slices; });
  return out;
}

Volume readDicomSeries(const std::string& dir, const std::string& seriesUid, const Progress* progress) {
  const SeriesLayout layout = seriesLayout(dir, seriesUid);
  const std::vector<DicomSlice>& slices = layout.slices;
  glm::ivec3 dims(0, 0, int(slices.size()));
  glm::dvec3 spacing(1.0, 1.0, layout.zSpacing);
  ScalarType type = ScalarType::Int16;
  SampleArray samples;
  bool rescaled = false;
  double slopeFirst = 1.0, interceptFirst = 0.0;
  ProgressTask task(progress, "DICOM slices", slices.size());
  for (size_t s = 0; s < slices.size(); ++s, task.advance()) {
    const std::string& file = slices[s].file;
    const std::string where = sliceWhere(layout, s);
    const PixelModule module = checkPixelModule(InputFile(file), where);
    if (s == 0)  // the whole series is allocated up front (float at worst): what its first slice claims must fit
      checkMemory(where, uint64_t(module.columns) * uint64_t(module.rows) * (slices.size() * sizeof(float) + 2 * sizeof(double)),
                  detail::concat(slices.size(), " slices of ", module.columns, "x", module.rows, " samples"));
    else
      checkSliceSize(where, module, dims);
    SliceImage image;
    readSliceImage(file, where, module, &image);
    if (s == 0) {
      takeGrid(image, dir, &dims, &spacing);
      type = image.type;
      slopeFirst = image.slope;
      interceptFirst = image.intercept;
      samples = detail::rescaleTarget(type, slopeFirst, interceptFirst, size_t(dims.x) * dims.y * dims.z);
    } else if (image.size.x != dims.x || image.size.y != dims.y) {
      HYB_THROW(IoError, where, ": slice is ", image.size.x, "x", image.size.y, ", expected ", dims.x, "x", dims.y, " like the first slice");
    }
    const SampleArray slice = sliceSamples(image, where);
    if (image.slope != 1.0 || image.intercept != 0.0) rescaled = true;
    detail::rescaleSamples(&samples, s * size_t(dims.x) * dims.y, slice, image.slope, image.intercept);
  }
  validateSpacing(spacing, dir);
  return placedSeries(Volume(dims, spacing, type, std::move(samples), dir), layout, slopeFirst, interceptFirst, rescaled);
}

namespace detail {

std::unique_ptr<PlaneSource> dicomPlanes(const std::string& dir, const std::string& seriesUid) {
  SeriesLayout layout = seriesLayout(dir, seriesUid);
  const size_t n = layout.slices.size();
  // Every slice's header, checked as the whole reader checks it; the stored type is decided by the
  // whole reader's rule (rescaleTarget of the first slice, widened to float when a rescaled value
  // does not fit) applied to the range each header allows, or where that range does not fit, to
  // the values, read once a slice at a time.
  glm::ivec3 dims(0, 0, int(n));
  glm::dvec3 spacing(1.0, 1.0, layout.zSpacing);
  ScalarType stored = ScalarType::Int16;
  bool rescaled = false, byValues = false;
  std::vector<SliceHeader> headers;
  headers.reserve(n);
  for (size_t s = 0; s < n; ++s) {
    const std::string& file = layout.slices[s].file;
    const std::string where = sliceWhere(layout, s);
    const PixelModule module = checkPixelModule(InputFile(file), where);
    if (s > 0) checkSliceSize(where, module, dims);
    SliceImage image;
    readSliceImage(file, where, module, &image);
    if (s == 0) {
      takeGrid(image, dir, &dims, &spacing);
      stored = storedType(detail::rescaleTarget(image.type, image.slope, image.intercept, 0));
    }
    // Whether the whole reader widens to float depends on the values (below).
    byValues = byValues || !holdsAll(stored, image.lo, image.hi, image.slope, image.intercept);
    if (image.slope != 1.0 || image.intercept != 0.0) rescaled = true;
    headers.push_back({image.type, image.slope, image.intercept});
  }
  validateSpacing(spacing, dir);
  // The values decide (an int16 CT with 16 bits stored and an intercept, GE's): rescaled as the whole
  // reader rescales them, a slice at a time, float as soon as one is not of the stored type.
  for (size_t s = 0; byValues && s < n; ++s) {
    const std::string where = sliceWhere(layout, s);
    SliceImage image;
    readSliceImage(layout.slices[s].file, where, checkPixelModule(InputFile(layout.slices[s].file), where), &image);
    SampleArray plane = detail::allocateSamples(stored, size_t(dims.x) * size_t(dims.y));
    detail::rescaleSamples(&plane, 0, sliceSamples(image, where), image.slope, image.intercept);
    if (storedType(plane) != stored) {
      stored = ScalarType::Float32;
      break;
    }
  }
  Volume description = placedSeries(Volume::withoutSamples(dims, spacing, headers.front().type, stored, 0.0f, 0.0f, dir), layout, headers.front().slope,
                                    headers.front().intercept, rescaled);
  return std::make_unique<DicomPlanes>(std::move(description), std::move(layout), std::move(headers));
}

}  // namespace detail

}  // namespace hyb
