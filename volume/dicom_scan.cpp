#include "volume/dicom_scan.h"

#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <set>
#include <sstream>

#include "volume/core/error.h"
#include "volume/core/file_util.h"
#include "volume/reader_util.h"

namespace hyb::detail {

namespace fs = std::filesystem;

namespace {

// The tags whose values a header keeps, and the sequences it descends into; everything else is
// walked over (its length checked) without being kept.
const std::set<uint32_t>& keptTags() {
  static const std::set<uint32_t> kTags = {
      dicomTag(0x0002, 0x0002), dicomTag(0x0002, 0x0010),                            // meta: SOP class, transfer syntax
      dicomTag(0x0004, 0x1430), dicomTag(0x0004, 0x1500), dicomTag(0x0004, 0x1510),  // DICOMDIR records
      dicomTag(0x0008, 0x0008), dicomTag(0x0008, 0x0016), dicomTag(0x0008, 0x0018), dicomTag(0x0008, 0x0020), dicomTag(0x0008, 0x0021), dicomTag(0x0008, 0x0060),
      dicomTag(0x0008, 0x1030), dicomTag(0x0008, 0x103e),                            // image type, SOP class and instance, dates, modality, descriptions
      dicomTag(0x0010, 0x0010), dicomTag(0x0010, 0x0020),                            // patient
      dicomTag(0x0018, 0x0050), dicomTag(0x0018, 0x1120), dicomTag(0x0018, 0x5100),  // thickness, gantry tilt, patient position
      dicomTag(0x0020, 0x000d), dicomTag(0x0020, 0x000e), dicomTag(0x0020, 0x0011), dicomTag(0x0020, 0x0013),
      dicomTag(0x0020, 0x0032), dicomTag(0x0020, 0x0037),                            // UIDs, numbers, position, orientation
      dicomTag(0x0028, 0x0002), dicomTag(0x0028, 0x0004), dicomTag(0x0028, 0x0008), dicomTag(0x0028, 0x0010), dicomTag(0x0028, 0x0011),
      dicomTag(0x0028, 0x0030), dicomTag(0x0028, 0x1052), dicomTag(0x0028, 0x1053)};  // pixel module, spacing, rescale
  return kTags;
}

bool descends(uint32_t tag) {
  switch (tag) {
    case dicomTag(0x0004, 0x1220):  // Directory Record Sequence
    case dicomTag(0x5200, 0x9229):  // Shared Functional Groups
    case dicomTag(0x5200, 0x9230):  // Per-frame Functional Groups
    case dicomTag(0x0020, 0x9113):  // Plane Position
    case dicomTag(0x0020, 0x9116):  // Plane Orientation
    case dicomTag(0x0028, 0x9110):  // Pixel Measures
    case dicomTag(0x0028, 0x9145):  // Pixel Value Transformation
      return true;
    default:
      return false;
  }
}

// Tags of value representation US: binary in any transfer syntax, kept as decimal text.
bool isUs(uint32_t tag) {
  return tag == dicomTag(0x0028, 0x0002) || tag == dicomTag(0x0028, 0x0010) || tag == dicomTag(0x0028, 0x0011);
}

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

// The value representation GDCM's typed reading of the image module expects of a tag (its
// attributes assert on another), or null for tags it reads as they come.
const char* imageModuleVr(uint32_t tag) {
  static const struct { uint32_t tag; const char* vr; } kTags[] = {
      {dicomTag(0x0008, 0x0060), "CS"}, {dicomTag(0x0018, 0x0050), "DS"}, {dicomTag(0x0018, 0x0088), "DS"}, {dicomTag(0x0020, 0x0032), "DS"},
      {dicomTag(0x0020, 0x0037), "DS"}, {dicomTag(0x0028, 0x0002), "US"}, {dicomTag(0x0028, 0x0004), "CS"}, {dicomTag(0x0028, 0x0006), "US"},
      {dicomTag(0x0028, 0x0008), "IS"}, {dicomTag(0x0028, 0x0010), "US"}, {dicomTag(0x0028, 0x0011), "US"}, {dicomTag(0x0028, 0x0030), "DS"},
      {dicomTag(0x0028, 0x0100), "US"}, {dicomTag(0x0028, 0x0101), "US"}, {dicomTag(0x0028, 0x0102), "US"}, {dicomTag(0x0028, 0x0103), "US"},
      {dicomTag(0x0028, 0x1050), "DS"}, {dicomTag(0x0028, 0x1051), "DS"}, {dicomTag(0x0028, 0x1052), "DS"}, {dicomTag(0x0028, 0x1053), "DS"}};
  for (const auto& t : kTags)
    if (t.tag == tag) return t.vr;
  return nullptr;
}

// Thrown inside a parse when an element lies within the file but past the bytes read so far.
struct NeedMoreBytes {};

std::string hex(uint16_t v) {
  char s[5];
  std::snprintf(s, sizeof s, "%04x", v);
  return s;
}

}  // namespace

// One run of DicomHeaderParser::elements: the bytes [pos, end) it walks, and what it keeps.
struct ElementWalk {
  uint64_t end;
  int depth = 0;                // of sequences nested around it
  bool inItem = false;          // it ends at an item delimiter (an item of undefined length)
  bool implicitVr = false;      // implicit VR though the file's is explicit (an unknown sequence's items)
  DicomDataSet* out = nullptr;  // where the values kept go, or nowhere
  bool* pixelData = nullptr;    // set when a header's walk stops at the pixel data
};

// One run of DicomHeaderParser::sequenceItems: the sequence's bytes up to end, and its items' kind.
struct SequenceWalk {
  uint64_t end;
  int depth;
  bool implicitVr;                     // its items' elements have implicit VR
  bool undefinedLength;                // it ends at its delimiter rather than at end
  bool fragments;                      // encapsulated pixel data: its items are bytes, not data sets
  std::vector<DicomDataSet>* items;    // where its items go, or nowhere
};

// Walks a data set held in a byte buffer, every length checked against the file: GDCM allocates
// what an element declares before it finds the file shorter (a 545-byte slice made it allocate 2
// GB), and asserts on malformed structure. Sequences and encapsulated pixel data of undefined
// length are walked item by item, 16 levels deep at most. Reading a header, the walk stops at the
// pixel data and keeps the values asked for; checking a whole file for GDCM, it walks to the end
// and checks the image module's value representations.
class DicomHeaderParser {
 public:
  enum class Mode { Header, WholeFile };
  DicomHeaderParser(const std::vector<uint8_t>& b, uint64_t available, bool explicitVr, bool bigEndian, const std::string& path, Mode mode)
      : mB(b), mAvailable(available), mExplicit(explicitVr), mBig(bigEndian), mPath(path), mMode(mode) {}

  // Elements from @p pos to the walk's end, or to an item delimiter when it is in an item; returns
  // where it stopped. Reading a header, the pixel data at the top level ends the walk.
  size_t elements(size_t pos, const ElementWalk& walk) {
    const uint64_t end = walk.end;
    const int depth = walk.depth;
    const bool inItem = walk.inItem, implicitHere = walk.implicitVr;
    DicomDataSet* const out = walk.out;
    bool* const pixelData = walk.pixelData;
    if (depth > 16) fail(pos, "sequences nested more than 16 deep");
    const bool explicitVr = mExplicit && !implicitHere;
    while (pos + 8 <= end) {
      need(pos, 8);
      const uint16_t group = u16(pos), element = u16(pos + 2);
      const uint32_t tag = dicomTag(group, element);
      if (group == 0xfffe) {
        if (element == 0xe00d && inItem) return pos + 8;
        fail(pos, "an item tag outside a sequence");
      }
      const bool pixels = tag == dicomTag(0x7fe0, 0x0010);
      if (pixels && depth == 0 && mMode == Mode::Header) {
        if (pixelData) *pixelData = true;
        return pos;
      }
      size_t header = 8;
      uint64_t length;
      bool sequence = false, maySequence = !explicitVr, implicitItems = implicitHere;
      std::string vr;
      if (explicitVr) {
        const uint8_t* v = mB.data() + pos + 4;
        vr.assign(reinterpret_cast<const char*>(v), 2);
        if (!knownVr(v)) fail(pos, concat("an unknown value representation ", quotedExcerpt(vr)));
        if (const char* want = imageModuleVr(tag); mMode == Mode::WholeFile && want && vr != want)
          fail(pos, concat("element (", hex(group), ",", hex(element), ") of value representation ", quotedExcerpt(vr), " where the standard says ", want));
        sequence = vr == "SQ";
        maySequence = sequence || vr == "UN" || vr == "OB" || vr == "OW";
        implicitItems = implicitHere || vr == "UN";  // an unknown sequence keeps its items implicit (PS3.5 6.2.2)
        if (longVr(v)) {
          need(pos, 12);
          if (pos + 12 > end) fail(pos, "an element cut short");
          length = u32(pos + 8);
          header = 12;
        } else {
          length = u16(pos + 6);
        }
      } else {
        length = u32(pos + 4);
        sequence = descends(tag);
      }
      pos += header;
      if (length == 0xffffffffu) {
        if (!maySequence) fail(pos - header, "an undefined length on a value that cannot hold items");
        std::vector<DicomDataSet>* items = out && descends(tag) ? &out->mItems[tag] : nullptr;
        pos = sequenceItems(pos, {end, depth + 1, implicitItems, true, pixels, items});
        continue;
      }
      if (length > end - pos || pos + length > mAvailable)
        fail(pos - header, concat("element (", hex(group), ",", hex(element), ") declaring ", length, " bytes where ",
                                  std::min<uint64_t>(end, mAvailable) - pos, " are left"));
      if (sequence && (mMode == Mode::WholeFile || descends(tag))) {
        need(pos, length);
        sequenceItems(pos, {pos + length, depth + 1, implicitItems, false, false, out && descends(tag) ? &out->mItems[tag] : nullptr});
      } else if (out && keptTags().count(tag) && length <= 4096) {
        need(pos, length);
        out->mValues[tag] = value(tag, vr, pos, size_t(length));
      }
      pos += size_t(length);
    }
    if (inItem) {
      need(pos, 8);
      fail(pos, "an item without its delimiter");
    }
    if (pos < end) {
      need(pos, end - pos);
      fail(pos, "an element cut short");  // GDCM asserts on a partial element header
    }
    return size_t(end);
  }

 private:
  // Items of a sequence from @p pos, to its delimiter or to its end; each kept when asked for.
  size_t sequenceItems(size_t pos, const SequenceWalk& seq) {
    const uint64_t end = seq.end;
    for (;;) {
      if (pos + 8 > end) {
        if (!seq.undefinedLength && pos == end) return pos;
        need(pos, 8);
        fail(pos, "a sequence without its delimiter");
      }
      need(pos, 8);
      const uint16_t group = u16(pos), element = u16(pos + 2);
      const uint32_t length = u32(pos + 4);
      pos += 8;
      if (group != 0xfffe) fail(pos - 8, "a sequence holding something other than items");
      if (element == 0xe0dd) {
        if (!seq.undefinedLength) fail(pos - 8, "a sequence delimiter in a sequence of defined length");
        return pos;
      }
      if (element != 0xe000) fail(pos - 8, "an unknown item tag");
      DicomDataSet* item = seq.items ? &seq.items->emplace_back() : nullptr;
      if (length == 0xffffffffu && !seq.fragments) {
        pos = elements(pos, {.end = end, .depth = seq.depth, .inItem = true, .implicitVr = seq.implicitVr, .out = item});
        continue;
      }
      if (length > end - pos || pos + length > mAvailable) fail(pos - 8, concat("an item declaring ", length, " bytes where ", end - pos, " are left"));
      if (!seq.fragments) {
        need(pos, length);
        elements(pos, {.end = pos + length, .depth = seq.depth, .implicitVr = seq.implicitVr, .out = item});
      }
      pos += length;
    }
  }

  std::string value(uint32_t tag, const std::string& vr, size_t pos, size_t length) const {
    if ((vr == "US" || (vr.empty() && isUs(tag))) && length >= 2) return std::to_string(u16(pos));
    return std::string(reinterpret_cast<const char*>(mB.data() + pos), length);
  }
  // The bytes [pos, pos + n) must have been read; a value past them but within the file asks for more.
  void need(size_t pos, uint64_t n) const {
    if (pos + n > mB.size()) {
      if (pos + n <= mAvailable) throw NeedMoreBytes{};
      fail(pos, "an element cut short");
    }
  }
  uint16_t u16(size_t at) const { return mBig ? uint16_t(mB[at] << 8 | mB[at + 1]) : le16(mB.data() + at); }
  uint32_t u32(size_t at) const {
    return mBig ? uint32_t(mB[at]) << 24 | uint32_t(mB[at + 1]) << 16 | uint32_t(mB[at + 2]) << 8 | mB[at + 3] : le32(mB.data() + at);
  }
  [[noreturn]] void fail(size_t at, const std::string& what) const {
    HYB_THROW(IoError, mPath, ": damaged DICOM data set: ", what, " at byte ", at, " (expected elements whose lengths fit in the file)");
  }

  const std::vector<uint8_t>& mB;
  uint64_t mAvailable;  // bytes of the data set in the file
  bool mExplicit, mBig;
  std::string mPath;
  Mode mMode;
};

std::string DicomDataSet::text(uint32_t tag) const {
  const auto it = mValues.find(tag);
  if (it == mValues.end()) return "";
  std::string s = it->second;
  while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
  size_t start = 0;
  while (start < s.size() && s[start] == ' ') ++start;
  return s.substr(start);
}

std::vector<double> DicomDataSet::numbers(uint32_t tag) const {
  std::vector<double> out;
  std::string t = text(tag);
  for (char& c : t)
    if (c == '\\') c = ' ';
  std::istringstream in(t);
  in.imbue(std::locale::classic());
  std::string word;
  while (in >> word) {
    char* end = nullptr;
    const double v = std::strtod(word.c_str(), &end);
    if (end != word.c_str() + word.size()) return {};
    out.push_back(v);
  }
  return out;
}

std::optional<long> DicomDataSet::integer(uint32_t tag) const {
  const std::string t = text(tag);
  if (t.empty()) return std::nullopt;
  char* end = nullptr;
  const long v = std::strtol(t.c_str(), &end, 10);
  if (end == t.c_str()) return std::nullopt;
  return v;
}

const std::vector<DicomDataSet>* DicomDataSet::items(uint32_t tag) const {
  const auto it = mItems.find(tag);
  return it == mItems.end() ? nullptr : &it->second;
}

namespace {

constexpr uint64_t kFirstRead = 16 << 10;                  // most headers end within this
constexpr uint64_t kMaxMetaBytes = 64 << 10;                // real file meta information is a few hundred bytes
constexpr uint64_t kMaxHeaderBytes = uint64_t(256) << 20;  // a DICOMDIR of a large CD, per-frame groups of thousands of frames

// The data set after the meta information inflated (Deflated Explicit VR Little Endian), bounded.
std::vector<uint8_t> inflatedDataSet(const InputFile& file, uint64_t start) {
  const std::vector<uint8_t> packed = file.bytes(start, file.size() - start);
  std::vector<uint8_t> out;
  z_stream z{};
  if (inflateInit2(&z, -15) != Z_OK) HYB_THROW(RuntimeError, file.path(), ": zlib initialisation failed");
  z.next_in = const_cast<uint8_t*>(packed.data());
  z.avail_in = uInt(packed.size());
  uint8_t buf[1 << 15];
  int rc = Z_OK;
  while (rc == Z_OK && out.size() < kMaxHeaderBytes) {
    z.next_out = buf;
    z.avail_out = sizeof buf;
    rc = inflate(&z, Z_NO_FLUSH);
    out.insert(out.end(), buf, buf + (sizeof buf - z.avail_out));
  }
  inflateEnd(&z);
  if (rc != Z_STREAM_END && out.size() < kMaxHeaderBytes) HYB_THROW(IoError, file.path(), ": damaged deflated DICOM data set (zlib ", rc, ")");
  return out;
}

// A file's meta information and where its data set starts.
struct Meta {
  size_t dataSet = 0;
  std::string transferSyntax, mediaStorage;
  bool explicitVr(const std::vector<uint8_t>& b) const {
    return transferSyntax.empty() ? dataSet + 6 <= b.size() && isVr(b.data() + dataSet + 4) : transferSyntax != "1.2.840.10008.1.2";
  }
  bool bigEndian() const { return transferSyntax == "1.2.840.10008.1.2.2"; }
};

// The file meta information (PS3.10 7.1) of @p file, whose first bytes are @p head (all of them, or
// at least 132 and the meta information's most), checked element by element before anything reads
// it (GDCM asserts on an undefined length, a sequence or a value running past the file in group
// 0002); none when the file is not DICOM (no "DICM" prefix, no data set starting at group 0002 or
// 0008 as old files do).
std::optional<Meta> readMeta(const InputFile& file, const std::vector<uint8_t>& head) {
  size_t pos = 0;
  if (head.size() >= 132 && std::memcmp(head.data() + 128, "DICM", 4) == 0) pos = 132;
  else if (head.size() < 8 || (le16(head.data()) != 0x0002 && le16(head.data()) != 0x0008)) return std::nullopt;
  auto damaged = [&](const std::string& what) {
    HYB_THROW(IoError, file.path(), ": damaged DICOM file meta information: ", what, " at byte ", pos,
              " (expected group 0002 elements of defined length within the file)");
  };
  // After the prefix GDCM expects meta information; without it its guesses allocated 1.6 GB for a 394-byte file.
  if (pos == 132 && (head.size() < 140 || le16(head.data() + pos) != 0x0002)) damaged("no group 0002 after the DICM prefix");
  Meta m;
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
    if (pos + headerBytes + length > file.size()) damaged(concat("a length of ", length, " past the end of the file"));
    if (pos + headerBytes + length > head.size()) damaged(concat("more than ", kMaxMetaBytes, " bytes of meta information"));
    std::string v(reinterpret_cast<const char*>(e + headerBytes), size_t(length));
    while (!v.empty() && (v.back() == '\0' || v.back() == ' ')) v.pop_back();
    if (le16(e + 2) == 0x0010) m.transferSyntax = v;
    if (le16(e + 2) == 0x0002) m.mediaStorage = v;
    pos += headerBytes + size_t(length);
  }
  // GDCM asserts when it finds the end of the file where the element after the meta information should be.
  if (pos + 8 > file.size()) damaged("no data set after the file meta information");
  m.dataSet = pos;
  return m;
}

// The transfer syntaxes GDCM decodes here (Debian's GDCM 3.0, greyscale), and the names of those
// it does not that CT archives may hold, for the message.
constexpr struct {
  const char* uid;
  const char* name;
  bool decoded;
} kTransferSyntaxes[] = {
    {"1.2.840.10008.1.2", "implicit VR little endian", true},
    {"1.2.840.10008.1.2.1", "explicit VR little endian", true},
    {"1.2.840.10008.1.2.1.99", "deflated explicit VR little endian", true},
    {"1.2.840.10008.1.2.2", "explicit VR big endian", true},
    {"1.2.840.10008.1.2.4.50", "JPEG baseline", true},
    {"1.2.840.10008.1.2.4.51", "JPEG extended", true},
    {"1.2.840.10008.1.2.4.57", "JPEG lossless", true},
    {"1.2.840.10008.1.2.4.70", "JPEG lossless, first-order prediction", true},
    {"1.2.840.10008.1.2.4.80", "JPEG-LS lossless", true},
    {"1.2.840.10008.1.2.4.81", "JPEG-LS near-lossless", true},
    {"1.2.840.10008.1.2.4.90", "JPEG 2000 lossless", true},
    {"1.2.840.10008.1.2.4.91", "JPEG 2000", true},
    {"1.2.840.10008.1.2.5", "RLE lossless", true},
    {"1.2.840.10008.1.2.4.92", "JPEG 2000 part 2 multi-component lossless", false},
    {"1.2.840.10008.1.2.4.93", "JPEG 2000 part 2 multi-component", false},
    {"1.2.840.10008.1.2.4.94", "JPIP referenced", false},
    {"1.2.840.10008.1.2.4.95", "JPIP referenced deflate", false},
    {"1.2.840.10008.1.2.4.110", "JPEG XL lossless", false},
    {"1.2.840.10008.1.2.4.111", "JPEG XL JPEG recompression", false},
    {"1.2.840.10008.1.2.4.112", "JPEG XL", false},
    {"1.2.840.10008.1.2.4.201", "HTJ2K lossless", false},
    {"1.2.840.10008.1.2.4.202", "HTJ2K lossless RPCL", false},
    {"1.2.840.10008.1.2.4.203", "HTJ2K", false},
};

}  // namespace

std::optional<std::string> checkDicomFile(const InputFile& file) {
  std::vector<uint8_t> head(size_t(std::min<uint64_t>(file.size(), 132 + kMaxMetaBytes)));
  file.read(0, head.size(), head.data());
  const std::optional<Meta> meta = readMeta(file, head);
  if (!meta) return std::nullopt;
  if (meta->transferSyntax == kDeflatedTransferSyntax) return meta->transferSyntax;  // lengths are inside the compressed stream: GDCM inflates it
  const std::vector<uint8_t> bytes = file.bytes(0, file.size());
  DicomHeaderParser(bytes, bytes.size(), meta->explicitVr(bytes), meta->bigEndian(), file.path(), DicomHeaderParser::Mode::WholeFile)
      .elements(meta->dataSet, {.end = bytes.size()});
  return meta->transferSyntax;
}

void checkTransferSyntax(const std::string& uid, const std::string& where) {
  if (uid.empty()) return;
  const char* const expected = " unsupported (expected uncompressed, deflated, JPEG, JPEG-LS, JPEG 2000 or RLE; convert the series, e.g. with gdcmconv --raw)";
  for (const auto& t : kTransferSyntaxes)
    if (uid == t.uid) {
      if (t.decoded) return;
      HYB_THROW(IoError, where, ": transfer syntax ", uid, " (", t.name, ")", expected);
    }
  HYB_THROW(IoError, where, ": transfer syntax ", quotedExcerpt(uid, kUidChars), uid.rfind("1.2.840.10008.", 0) == 0 ? "" : " (not a standard one)", expected);
}

std::optional<DicomHeader> readDicomHeader(const std::string& path, std::string* why) {
  const InputFile file(path);
  std::vector<uint8_t> b = file.bytes(0, std::min(file.size(), std::max(kFirstRead, 132 + kMaxMetaBytes)));
  const std::optional<Meta> meta = readMeta(file, b);
  if (!meta) {
    if (why) *why = "not DICOM";
    return std::nullopt;
  }
  DicomHeader h;
  h.transferSyntax = meta->transferSyntax;
  h.mediaStorage = meta->mediaStorage;
  if (meta->transferSyntax == kDeflatedTransferSyntax) {  // the data set is one raw deflate stream
    const std::vector<uint8_t> inflated = inflatedDataSet(file, meta->dataSet);
    try {
      DicomHeaderParser(inflated, inflated.size(), true, false, path, DicomHeaderParser::Mode::Header)
          .elements(0, {.end = inflated.size(), .out = &h.data, .pixelData = &h.pixelData});
    } catch (const NeedMoreBytes&) {
      HYB_THROW(IoError, path, ": deflated DICOM data set longer than ", kMaxHeaderBytes, " bytes");
    }
    return h;
  }
  for (;;) {
    DicomHeader attempt = h;
    try {
      DicomHeaderParser(b, file.size(), meta->explicitVr(b), meta->bigEndian(), path, DicomHeaderParser::Mode::Header)
          .elements(meta->dataSet, {.end = file.size(), .out = &attempt.data, .pixelData = &attempt.pixelData});
      return attempt;
    } catch (const NeedMoreBytes&) {
      if (b.size() >= kMaxHeaderBytes) HYB_THROW(IoError, path, ": DICOM header longer than ", kMaxHeaderBytes, " bytes (expected the pixel data sooner)");
      b = file.bytes(0, std::min({file.size(), uint64_t(b.size()) * 8, kMaxHeaderBytes}));
    }
  }
}

std::string nonImageReason(const std::string& sopClass) {
  static const struct { const char* prefix; const char* reason; } kKinds[] = {
      {"1.2.840.10008.1.3.10", "DICOMDIR"},
      {"1.2.840.10008.5.1.4.1.1.88.59", "key object selection"},
      {"1.2.840.10008.5.1.4.1.1.88.", "structured report"},
      {"1.2.840.10008.5.1.4.1.1.11.", "presentation state"},
      {"1.2.840.10008.5.1.4.1.1.481.", "RT object"},
      {"1.2.840.10008.5.1.4.1.1.104.", "encapsulated document"},
      {"1.2.840.10008.5.1.4.1.1.66", "raw data, registration or segmentation"},
      {"1.2.840.10008.5.1.4.1.1.9.", "waveform"},
      {"1.2.840.10008.5.1.4.1.1.67", "real world value mapping"},
      {"1.2.840.10008.5.1.4.38.", "hanging protocol"},
      {"1.2.840.10008.5.1.4.39.", "colour palette"}};
  for (const auto& k : kKinds)
    if (sopClass.rfind(k.prefix, 0) == 0) return k.reason;
  return "";
}

namespace {

// The file @p id names under @p root (components separated by backslashes, as a DICOMDIR's
// Referenced File ID), each component matched without regard to case when not found as written
// (CDs are written in capitals; copies may not be); none when it is not there.
// @throw IoError naming @p dicomdir when the ID leaves @p root.
std::optional<std::string> referencedFile(const fs::path& root, const std::string& id, const fs::path& dicomdir) {
  fs::path at = root;
  std::string part;
  std::istringstream in(id);
  while (std::getline(in, part, '\\')) {
    while (!part.empty() && (part.back() == ' ' || part.back() == '\0')) part.pop_back();
    // PS3.10 8.5: components separated by backslashes, below the DICOMDIR's folder; another separator,
    // a parent or an absolute part would reach files outside it (a viewer's data folder, say).
    if (part == ".." || part.find_first_of("/:") != std::string::npos)
      HYB_THROW(IoError, dicomdir.string(), ": Referenced File ID ", quotedExcerpt(id), " leaves its folder (expected backslash-separated names within ",
                root.string(), ")");
    if (part.empty() || part == ".") return std::nullopt;
    std::error_code ec;
    if (fs::exists(at / part, ec)) {
      at /= part;
      continue;
    }
    bool found = false;
    for (auto it = fs::directory_iterator(at, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
      const std::string name = it->path().filename().string();
      if (name.size() == part.size() && std::equal(name.begin(), name.end(), part.begin(), [](char a, char b) { return std::tolower(a) == std::tolower(b); })) {
        at = it->path();
        found = true;
        break;
      }
    }
    if (!found) return std::nullopt;
  }
  return at.string();
}

// The DICOMDIR in @p root, if any (its name in any case).
std::optional<fs::path> dicomdirIn(const fs::path& root) {
  std::error_code ec;
  for (auto it = fs::directory_iterator(root, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
    std::string name = it->path().filename().string();
    std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return char(std::toupper(c)); });
    if (name == "DICOMDIR" && it->is_regular_file(ec)) return it->path();
  }
  return std::nullopt;
}

// What a directory record of type @p type that is not an image stands for, or "" for records
// that only give the hierarchy.
std::string recordSkipReason(const std::string& type) {
  if (type == "PATIENT" || type == "STUDY" || type == "SERIES" || type == "IMAGE" || type.empty()) return "";
  if (type == "SR DOCUMENT") return "structured report";
  if (type == "KEY OBJECT DOC") return "key object selection";
  if (type == "PRESENTATION") return "presentation state";
  if (type.rfind("RT ", 0) == 0) return "RT object";
  if (type == "ENCAP DOC") return "encapsulated document";
  std::string lower = type;
  std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return lower + " record";
}

// Adds one to @p reason's count.
void countSkipped(std::vector<std::pair<std::string, size_t>>* skipped, const std::string& reason) {
  for (auto& [r, n] : *skipped)
    if (r == reason) {
      ++n;
      return;
    }
  skipped->push_back({reason, 1});
}

// The image files a DICOMDIR's records name, and the records skipped.
std::vector<std::string> dicomdirFiles(const fs::path& root, const fs::path& dicomdir, DicomCatalog* catalog) {
  std::string why;
  const std::optional<DicomHeader> h = readDicomHeader(dicomdir.string(), &why);
  const std::vector<DicomDataSet>* records = h ? h->data.items(dicomTag(0x0004, 0x1220)) : nullptr;
  if (!records)
    HYB_THROW(IoError, dicomdir.string(), ": not a DICOMDIR (expected its Directory Record Sequence (0004,1220))");
  std::vector<std::string> files, missing;
  for (const DicomDataSet& r : *records) {
    const std::string type = r.text(dicomTag(0x0004, 0x1430));
    const std::string id = r.text(dicomTag(0x0004, 0x1500));
    if (const std::string reason = recordSkipReason(type); !reason.empty()) {
      if (!id.empty()) countSkipped(&catalog->skipped, reason);
      continue;
    }
    if (type != "IMAGE" || id.empty()) continue;
    if (const std::optional<std::string> f = referencedFile(root, id, dicomdir)) files.push_back(*f);
    else missing.push_back(id);
  }
  if (!missing.empty())
    HYB_THROW(IoError, dicomdir.string(), ": names ", missing.size(), " of its ", files.size() + missing.size(), " image files that are not there, ",
              quotedExcerpt(missing.front()), " first (expected every file its records name, relative to ", root.string(), ")");
  return files;
}

// The files of @p root (its tree when @p recursive), sorted; links to files are followed, links to
// directories are not (a tree must not loop).
std::vector<std::string> treeFiles(const fs::path& root, bool recursive) {
  std::vector<std::string> files;
  std::error_code ec;
  auto take = [&](const fs::directory_entry& e) {
    std::error_code e2;
    if (e.is_regular_file(e2)) files.push_back(e.path().string());
  };
  if (recursive) {
    for (auto it = fs::recursive_directory_iterator(root, fs::directory_options::skip_permission_denied, ec);
         !ec && it != fs::recursive_directory_iterator(); it.increment(ec))
      take(*it);
  } else {
    for (auto it = fs::directory_iterator(root, fs::directory_options::skip_permission_denied, ec); !ec && it != fs::directory_iterator();
         it.increment(ec))
      take(*it);
  }
  if (ec) HYB_THROW(IoError, root.string(), ": cannot list the directory (", ec.message(), ")");
  std::sort(files.begin(), files.end());
  return files;
}

// The planes of one image: a single frame, or the frames of an enhanced multi-frame image from its
// functional groups (per frame where given, else shared).
std::vector<DicomFrame> imagePlanes(const std::string& file, const DicomDataSet& d, int frames, bool localizer) {
  DicomFrame top;
  top.file = file;
  top.localizer = localizer;
  top.sopInstance = d.text(dicomTag(0x0008, 0x0018));
  if (const std::vector<double> p = d.numbers(dicomTag(0x0020, 0x0032)); p.size() == 3) {
    top.position = {p[0], p[1], p[2]};
    top.hasPosition = true;
  }
  top.orientation = d.numbers(dicomTag(0x0020, 0x0037));
  if (const std::vector<double> s = d.numbers(dicomTag(0x0028, 0x1053)); s.size() == 1) top.slope = s[0];
  if (const std::vector<double> i = d.numbers(dicomTag(0x0028, 0x1052)); i.size() == 1) top.intercept = i[0];
  if (frames <= 1) return {top};
  const std::vector<DicomDataSet>* sharedItems = d.items(dicomTag(0x5200, 0x9229));
  const std::vector<DicomDataSet>* perFrame = d.items(dicomTag(0x5200, 0x9230));
  const DicomDataSet* shared = sharedItems && !sharedItems->empty() ? &sharedItems->front() : nullptr;
  // The first item of macro @p macro in @p group, then in the shared groups.
  auto macro = [&](const DicomDataSet* group, uint32_t macroTag) -> const DicomDataSet* {
    for (const DicomDataSet* g : {group, shared}) {
      if (!g) continue;
      if (const std::vector<DicomDataSet>* m = g->items(macroTag); m && !m->empty()) return &m->front();
    }
    return nullptr;
  };
  std::vector<DicomFrame> out;
  for (int f = 0; f < frames; ++f) {
    DicomFrame p = top;
    p.frame = f;
    p.hasPosition = false;
    const DicomDataSet* group = perFrame && size_t(f) < perFrame->size() ? &(*perFrame)[size_t(f)] : nullptr;
    if (const DicomDataSet* m = macro(group, dicomTag(0x0020, 0x9113)))
      if (const std::vector<double> v = m->numbers(dicomTag(0x0020, 0x0032)); v.size() == 3) {
        p.position = {v[0], v[1], v[2]};
        p.hasPosition = true;
      }
    if (const DicomDataSet* m = macro(group, dicomTag(0x0020, 0x9116))) p.orientation = m->numbers(dicomTag(0x0020, 0x0037));
    if (const DicomDataSet* m = macro(group, dicomTag(0x0028, 0x9145))) {
      if (const std::vector<double> s = m->numbers(dicomTag(0x0028, 0x1053)); s.size() == 1) p.slope = s[0];
      if (const std::vector<double> i = m->numbers(dicomTag(0x0028, 0x1052)); i.size() == 1) p.intercept = i[0];
    }
    out.push_back(std::move(p));
  }
  return out;
}

// Pixel Spacing (and Slice Thickness) of an image: its own, or a multi-frame image's Pixel Measures.
void pixelMeasures(const DicomDataSet& d, DicomInstance* in) {
  std::vector<double> spacing = d.numbers(dicomTag(0x0028, 0x0030));
  in->thickness = d.text(dicomTag(0x0018, 0x0050));
  for (const uint32_t group : {dicomTag(0x5200, 0x9229), dicomTag(0x5200, 0x9230)}) {
    const std::vector<DicomDataSet>* g = d.items(group);
    if (!g || g->empty()) continue;
    const std::vector<DicomDataSet>* m = g->front().items(dicomTag(0x0028, 0x9110));
    if (!m || m->empty()) continue;
    if (spacing.size() != 2) spacing = m->front().numbers(dicomTag(0x0028, 0x0030));
    if (in->thickness.empty()) in->thickness = m->front().text(dicomTag(0x0018, 0x0050));
  }
  if (spacing.size() == 2) in->pixelSpacing = {spacing[1], spacing[0]};
}

// The normal of six direction cosines (rows' direction x columns'), or zero.
glm::dvec3 normalOf(const std::vector<double>& iop) {
  if (iop.size() != 6) return glm::dvec3(0.0);
  const glm::dvec3 n = glm::cross(glm::dvec3(iop[0], iop[1], iop[2]), glm::dvec3(iop[3], iop[4], iop[5]));
  const double l = glm::length(n);
  return l > 1e-6 ? n / l : glm::dvec3(0.0);
}

}  // namespace

std::string describeSeries(const DicomSeriesInfo& s) {
  return concat("", quotedExcerpt(s.uid, kUidChars), " (", s.modality.empty() ? "?" : s.modality, s.description.empty() ? "" : ", " + s.description, ", ",
                s.slices, s.slices == 1 ? " slice" : " slices", " of ", s.columns, "x", s.rows, s.localizer ? ", localizer" : "", ")");
}

DicomCatalog catalogDicom(const std::string& dir, bool recursive, const Progress* progress) {
  DicomCatalog c;
  c.root = dir;
  const fs::path root(dir);
  std::vector<std::string> files;
  if (const std::optional<fs::path> dicomdir = dicomdirIn(root)) {
    c.dicomdir = true;
    files = dicomdirFiles(root, *dicomdir, &c);
  } else {
    files = treeFiles(root, recursive);
  }
  c.files = files.size();
  for (const auto& [reason, n] : c.skipped) c.files += n;  // records of a DICOMDIR naming files that are not images
  ProgressTask task(progress, "DICOM headers", files.size());
  for (const std::string& f : files) {
    task.advance();
    std::string why;
    std::optional<DicomHeader> h;
    try {
      h = readDicomHeader(f, &why);
    } catch (const IoError& e) {
      c.damaged.push_back({f, e.what()});
      countSkipped(&c.skipped, "damaged header");
      continue;
    }
    if (!h) {
      countSkipped(&c.skipped, why);
      c.skippedFiles.push_back({f, why});
      continue;
    }
    const DicomDataSet& d = h->data;
    const std::string sop = d.text(dicomTag(0x0008, 0x0016)).empty() ? h->mediaStorage : d.text(dicomTag(0x0008, 0x0016));
    std::string reason = nonImageReason(sop);
    if (reason.empty() && nonImageReason(h->mediaStorage) == "DICOMDIR") reason = "DICOMDIR";
    if (reason.empty() && !h->pixelData) reason = "no pixel data";
    if (reason.empty() && d.integer(dicomTag(0x0028, 0x0002)).value_or(1) == 3) reason = "colour image";
    if (reason.empty() && d.text(dicomTag(0x0020, 0x000e)).empty()) reason = "no Series Instance UID";
    if (!reason.empty()) {
      countSkipped(&c.skipped, reason);
      c.skippedFiles.push_back({f, reason});
      continue;
    }
    DicomInstance in;
    in.file = f;
    in.bytes = fs::file_size(f);
    in.sopClass = sop;
    in.studyUid = d.text(dicomTag(0x0020, 0x000d));
    in.seriesUid = d.text(dicomTag(0x0020, 0x000e));
    in.transferSyntax = h->transferSyntax;
    in.rows = int(d.integer(dicomTag(0x0028, 0x0010)).value_or(0));
    in.columns = int(d.integer(dicomTag(0x0028, 0x0011)).value_or(0));
    in.frames = int(std::clamp<long>(d.integer(dicomTag(0x0028, 0x0008)).value_or(1), 1, 1 << 20));
    in.patientPosition = d.text(dicomTag(0x0018, 0x5100));
    in.tilt = d.text(dicomTag(0x0018, 0x1120));
    pixelMeasures(d, &in);
    const std::string imageType = d.text(dicomTag(0x0008, 0x0008));
    in.planes = imagePlanes(f, d, in.frames, imageType.find("LOCALIZER") != std::string::npos);
    if (const std::vector<DicomDataSet>* perFrame = d.items(dicomTag(0x5200, 0x9230)); in.frames > 1 && perFrame && perFrame->size() != size_t(in.frames))
      in.defect = concat("Per-frame Functional Groups Sequence (5200,9230) holds ", perFrame->size(), " items (expected one per frame: Number of Frames (0028,0008) is ",
                         in.frames, ")");
    std::vector<DicomInstance>& series = c.instances[in.seriesUid];
    if (series.empty()) {
      DicomSeriesInfo s;
      s.uid = in.seriesUid;
      s.number = d.text(dicomTag(0x0020, 0x0011));
      s.description = d.text(dicomTag(0x0008, 0x103e));
      s.modality = d.text(dicomTag(0x0008, 0x0060));
      s.studyUid = in.studyUid;
      s.studyDate = d.text(dicomTag(0x0008, 0x0020));
      s.studyDescription = d.text(dicomTag(0x0008, 0x1030));
      s.date = d.text(dicomTag(0x0008, 0x0021));
      s.patientName = d.text(dicomTag(0x0010, 0x0010));
      s.patientId = d.text(dicomTag(0x0010, 0x0020));
      s.columns = in.columns;
      s.rows = in.rows;
      c.series.push_back(s);
    }
    series.push_back(std::move(in));
  }
  // Counts, localizers and the default choice.
  std::map<std::string, glm::dvec3> studyNormal;  // the normal of each study's largest series
  std::map<std::string, size_t> studyLargest;
  for (DicomSeriesInfo& s : c.series) {
    const std::vector<DicomInstance>& ins = c.instances.at(s.uid);
    bool allLocalizers = true;
    for (const DicomInstance& in : ins) {
      s.slices += in.planes.size();
      s.bytes += in.bytes;
      for (const DicomFrame& p : in.planes) allLocalizers = allLocalizers && p.localizer;
    }
    s.files = ins.size();
    s.localizer = allLocalizers;
    const glm::dvec3 n = normalOf(ins.front().planes.front().orientation);
    s.axial = std::abs(n.z) >= std::max(std::abs(n.x), std::abs(n.y)) && glm::length(n) > 0.0;
    if (!s.localizer && s.slices > studyLargest[s.studyUid]) {
      studyLargest[s.studyUid] = s.slices;
      studyNormal[s.studyUid] = n;
    }
  }
  for (DicomSeriesInfo& s : c.series) {  // one slice across the study's main series: a scout
    const glm::dvec3 n = normalOf(c.instances.at(s.uid).front().planes.front().orientation);
    if (s.slices == 1 && studyLargest[s.studyUid] > 1 && std::abs(glm::dot(n, studyNormal[s.studyUid])) < 0.5) s.localizer = true;
  }
  if (c.series.empty()) {
    std::string found;
    for (const auto& [reason, n] : c.skipped) found += (found.empty() ? "" : ", ") + concat(n, " ", reason);
    HYB_THROW(IoError, dir, ": no DICOM image series found (", c.files, c.files == 1 ? " file" : " files", found.empty() ? "" : ": " + found,
              "; expected a folder, a folder tree or a CD holding DICOM images)");
  }
  // The default first: not a localizer, axial, the most slices; then the rest by size.
  std::stable_sort(c.series.begin(), c.series.end(), [](const DicomSeriesInfo& a, const DicomSeriesInfo& b) {
    if (a.localizer != b.localizer) return !a.localizer;
    if (a.axial != b.axial) return a.axial;
    return a.slices > b.slices;
  });
  return c;
}

}  // namespace hyb::detail
