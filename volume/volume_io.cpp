#include "volume/volume_io.h"

#include <archive.h>
#include <archive_entry.h>
#include <gdcmDirectory.h>
#include <gdcmIPPSorter.h>
#include <gdcmImageReader.h>
#include <gdcmScanner.h>
#include <gdcmTrace.h>
#include <nifti2_io.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <iomanip>
#include <map>
#include <memory>
#include <optional>
#include <sstream>

#include "volume/file_util.h"
#include "volume/inflate.h"
#include "volume/memory_limit.h"
#include "volume/patient_frame.h"
#include "volume/plist.h"
#include "volume/reader_util.h"

namespace hyb {

namespace fs = std::filesystem;

namespace {

using detail::decodeSamples;
using detail::lower;
using detail::placed;
using detail::trim;

// ---------------------------------------------------------------------------------------------
// Shared helpers

// Parses exactly @p n whitespace-separated numbers from @p text.
template <typename T>
bool parseNumbers(const std::string& text, int n, T* out) {
  std::istringstream s(text);
  for (int i = 0; i < n; ++i)
    if (!(s >> out[i])) return false;
  std::string rest;
  return !(s >> rest);
}

uint64_t expectedBytes(const glm::ivec3& dims, ScalarType t) {
  return uint64_t(dims.x) * uint64_t(dims.y) * uint64_t(dims.z) * scalarSize(t);
}

// Checks that exactly @p expected bytes of samples are present, with messages naming the file.
void checkByteCount(const std::string& file, uint64_t expected, uint64_t actual, const glm::ivec3& dims,
                    ScalarType t) {
  if (actual == expected) return;
  const std::string layout = detail::concat(dims.x, "x", dims.y, "x", dims.z, " ", scalarName(t));
  if (actual < expected)
    HYB_THROW(IoError, file, ": truncated data: expected ", expected, " bytes for ", layout, ", found ", actual);
  HYB_THROW(IoError, file, ": header/data size mismatch: expected ", expected, " bytes for ", layout, ", found ",
            actual);
}

// "4x3x5 int16", for messages.
std::string layoutName(const glm::ivec3& dims, ScalarType t) {
  return detail::concat(dims.x, "x", dims.y, "x", dims.z, " ", scalarName(t));
}

// Checks memory for @p extra bytes of file data held while decoding plus the float samples.
void checkSampleMemory(const std::string& file, uint64_t extra, const glm::ivec3& dims, ScalarType t) {
  const uint64_t count = uint64_t(dims.x) * uint64_t(dims.y) * uint64_t(dims.z);
  checkMemory(file, extra + count * sizeof(float), layoutName(dims, t) + " samples");
}

// The raw samples of @p f from byte @p offset on: @p skip bytes are skipped first (-1: the
// samples are the file's last bytes) and exactly the samples must remain. Sizes are checked
// against the file before anything is allocated. @p field names the skip in messages.
std::vector<float> readRawSamples(const InputFile& f, uint64_t offset, long long skip, const char* field, const glm::ivec3& dims,
                                  ScalarType t, bool bigEndian) {
  const uint64_t expected = expectedBytes(dims, t);
  const uint64_t present = f.size() - std::min(offset, f.size());
  if (skip == -1) {
    if (present < expected) checkByteCount(f.path(), expected, present, dims, t);
    offset = f.size() - expected;
  } else if (skip < 0 || uint64_t(skip) > present) {
    HYB_THROW(IoError, f.path(), ": ", field, " ", skip, " invalid for the ", present, " bytes of data (expected 0 to ", present, ", or -1)");
  } else {
    offset += uint64_t(skip);
  }
  checkByteCount(f.path(), expected, f.size() - offset, dims, t);
  checkSampleMemory(f.path(), expected, dims, t);
  const std::vector<uint8_t> bytes = f.bytes(offset, expected);
  return decodeSamples(bytes.data(), size_t(expected / scalarSize(t)), t, bigEndian);
}

// The samples of the gzip or zlib stream that makes up @p f from byte @p offset on, after
// @p skip decompressed bytes; inflation is capped at what the header declares.
std::vector<float> readCompressedSamples(const InputFile& f, uint64_t offset, long long skip, const glm::ivec3& dims, ScalarType t,
                                         bool bigEndian) {
  if (skip < 0) HYB_THROW(IoError, f.path(), ": byte skip ", skip, " invalid for compressed data (expected 0 or more)");
  const uint64_t expected = expectedBytes(dims, t), total = expected + uint64_t(skip);
  const uint64_t compressed = f.size() - std::min(offset, f.size());
  if (detail::maxInflatedBytes(compressed) < total)
    HYB_THROW(IoError, f.path(), ": ", compressed, " bytes of compressed data cannot hold the ", total, " bytes of ", layoutName(dims, t),
              " samples the header declares (expected at least ", (total - 1024) / detail::kMaxDeflateRatio,
              " bytes: deflate inflates at most ", detail::kMaxDeflateRatio, ":1)");
  checkSampleMemory(f.path(), compressed + total, dims, t);
  const std::vector<uint8_t> packed = f.bytes(offset, compressed);
  const std::vector<uint8_t> raw = detail::inflateExactly(packed.data(), packed.size(), total, f.path() + " (compressed data)");
  return decodeSamples(raw.data() + skip, size_t(expected / scalarSize(t)), t, bigEndian);
}

// Whitespace- or comma-separated ASCII samples of @p f from byte @p offset on.
std::vector<float> readAsciiSamples(const InputFile& f, uint64_t offset, const glm::ivec3& dims, ScalarType t) {
  const uint64_t count = uint64_t(dims.x) * uint64_t(dims.y) * uint64_t(dims.z);
  const uint64_t present = f.size() - std::min(offset, f.size());
  if (present < 2 * count - 1)  // a digit each, separated
    HYB_THROW(IoError, f.path(), ": truncated ASCII data: ", present, " bytes cannot hold the ", count, " samples of ", layoutName(dims, t),
              " (expected at least ", 2 * count - 1, " bytes)");
  checkSampleMemory(f.path(), present, dims, t);
  const std::vector<uint8_t> text = f.bytes(offset, present);
  const char* p = reinterpret_cast<const char*>(text.data());
  const char* end = p + text.size();
  std::vector<float> out;
  out.reserve(size_t(count));
  auto separator = [](char c) { return std::isspace(static_cast<unsigned char>(c)) || c == ','; };
  while (p < end) {
    while (p < end && separator(*p)) ++p;
    if (p >= end) break;
    const std::string token(p, std::find_if(p, end, separator));
    char* next = nullptr;
    const double v = std::strtod(token.c_str(), &next);
    if (next == token.c_str() || *next) HYB_THROW(IoError, f.path(), ": expected a number in ASCII data, found ", quotedExcerpt(token));
    if (out.size() == count) HYB_THROW(IoError, f.path(), ": ASCII data holds more than the ", count, " samples the header declares");
    out.push_back(float(v));
    p += token.size();
  }
  if (out.size() != count) HYB_THROW(IoError, f.path(), ": ASCII data holds ", out.size(), " samples, expected ", count);
  return out;
}

// The offset just past @p lines line ends in @p f from @p offset on (NRRD "line skip").
uint64_t skipLines(const InputFile& f, uint64_t offset, long long lines) {
  uint8_t buf[1 << 16];
  for (long long l = 0; l < lines;) {
    if (offset >= f.size()) HYB_THROW(IoError, f.path(), ": cannot skip ", lines, " lines (file too short)");
    const uint64_t n = std::min<uint64_t>(sizeof buf, f.size() - offset);
    f.read(offset, n, buf);
    uint64_t i = 0;
    for (; i < n && l < lines; ++i)
      if (buf[i] == '\n') ++l;
    offset += i;
  }
  return offset;
}

// Longest text header and header line accepted (NRRD, MetaImage): real ones are a few KB.
constexpr uint64_t kMaxHeaderBytes = uint64_t(1) << 20;
constexpr size_t kMaxHeaderLine = size_t(64) << 10;

// The header lines of @p f up to the line @p last accepts (NRRD: the blank line, dropped;
// MetaImage: ElementDataFile, kept) or the end of the file, with the offset of the data after
// them. '\r' before '\n' is dropped. Read within kMaxHeaderBytes and kMaxHeaderLine.
template <class Last>
std::vector<std::string> readHeaderLines(const InputFile& f, const Last& last, uint64_t* dataOffset) {
  const uint64_t n = std::min(f.size(), kMaxHeaderBytes);
  std::vector<uint8_t> head(static_cast<size_t>(n));
  f.read(0, n, head.data());
  std::vector<std::string> lines;
  size_t pos = 0;
  while (pos < head.size()) {
    const uint8_t* nl = static_cast<const uint8_t*>(std::memchr(head.data() + pos, '\n', head.size() - pos));
    if (!nl && f.size() > n)
      HYB_THROW(IoError, f.path(), ": header is longer than ", kMaxHeaderBytes, " bytes (expected a text header that ends before the data)");
    const size_t end = nl ? size_t(nl - head.data()) : head.size();
    if (end - pos > kMaxHeaderLine)
      HYB_THROW(IoError, f.path(), ": header line ", lines.size() + 1, " is longer than ", kMaxHeaderLine, " bytes (expected a text header)");
    std::string line(reinterpret_cast<const char*>(head.data() + pos), end - pos);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    pos = nl ? end + 1 : end;
    bool keep = true;
    if (last(line, &keep)) {
      if (keep) lines.push_back(std::move(line));
      *dataOffset = pos;
      return lines;
    }
    lines.push_back(std::move(line));
  }
  *dataOffset = f.size();
  return lines;
}

// Three sample counts from header field @p field, each in 1..kMaxDim, with a product in range.
glm::ivec3 parseDims(const std::string& text, const char* field, const std::string& path) {
  long long sizes[3];
  if (!parseNumbers(text, 3, sizes))
    HYB_THROW(IoError, path, ": ", field, " ", quotedExcerpt(text), " malformed (expected three integers)");
  for (long long s : sizes)
    if (s <= 0 || s > kMaxDim) HYB_THROW(IoError, path, ": ", field, " ", quotedExcerpt(text), " invalid (expected 1..", kMaxDim, " per axis)");
  const glm::ivec3 dims{int(sizes[0]), int(sizes[1]), int(sizes[2])};
  validateDims(dims, path);
  return dims;
}

// ---------------------------------------------------------------------------------------------
// NRRD (http://teem.sourceforge.net/nrrd/format.html)

bool nrrdType(const std::string& name, ScalarType* t) {
  static const std::map<std::string, ScalarType> kTypes = {
      {"signed char", ScalarType::Int8},         {"int8", ScalarType::Int8},
      {"int8_t", ScalarType::Int8},              {"uchar", ScalarType::UInt8},
      {"unsigned char", ScalarType::UInt8},      {"uint8", ScalarType::UInt8},
      {"uint8_t", ScalarType::UInt8},            {"short", ScalarType::Int16},
      {"short int", ScalarType::Int16},          {"signed short", ScalarType::Int16},
      {"signed short int", ScalarType::Int16},   {"int16", ScalarType::Int16},
      {"int16_t", ScalarType::Int16},            {"ushort", ScalarType::UInt16},
      {"unsigned short", ScalarType::UInt16},    {"unsigned short int", ScalarType::UInt16},
      {"uint16", ScalarType::UInt16},            {"uint16_t", ScalarType::UInt16},
      {"int", ScalarType::Int32},                {"signed int", ScalarType::Int32},
      {"int32", ScalarType::Int32},              {"int32_t", ScalarType::Int32},
      {"uint", ScalarType::UInt32},              {"unsigned int", ScalarType::UInt32},
      {"uint32", ScalarType::UInt32},            {"uint32_t", ScalarType::UInt32},
      {"float", ScalarType::Float32},            {"double", ScalarType::Float64}};
  const auto it = kTypes.find(name);
  if (it == kTypes.end()) return false;
  *t = it->second;
  return true;
}

// Parses @p n parenthesised 3-vectors such as "(0.9,0,0) (0,0.9,0) (0,0,1.5)" (NRRD "space
// directions", n = 3; "space origin", n = 1).
bool parseVectors(const std::string& text, int n, double* out) {
  std::string s = text;
  for (char& c : s)
    if (c == '(' || c == ')' || c == ',') c = ' ';
  return parseNumbers(s, 3 * n, out);
}

// Signs that take a vector of NRRD space @p space into LPS; false for a space this reader does not
// know. @p assumed says when the space is not anatomical and its axes are taken as LPS's.
bool nrrdSpaceToLps(const std::string& space, glm::dvec3* sign, bool* assumed) {
  static const std::map<std::string, glm::dvec3> kAnatomical = {
      {"right-anterior-superior", {-1, -1, 1}}, {"ras", {-1, -1, 1}},
      {"left-anterior-superior", {1, -1, 1}},   {"las", {1, -1, 1}},
      {"left-posterior-superior", {1, 1, 1}},   {"lps", {1, 1, 1}}};
  *assumed = false;
  if (const auto it = kAnatomical.find(space); it != kAnatomical.end()) {
    *sign = it->second;
    return true;
  }
  *sign = glm::dvec3(1.0);
  *assumed = space == "scanner-xyz" || space == "3d-right-handed" || space == "3d-left-handed";
  return *assumed;
}

// Millimetres in one NRRD "space units" entry (quoted), or 0 when unknown.
double unitMillimetres(const std::string& unit) {
  static const std::map<std::string, double> kUnits = {{"mm", 1.0}, {"m", 1000.0}, {"cm", 10.0}, {"um", 1e-3}, {"µm", 1e-3}, {"", 1.0}};
  const auto it = kUnits.find(unit);
  return it == kUnits.end() ? 0.0 : it->second;
}

// The grid's spacing and patient frame from a NRRD header's space fields (@p field returns a
// field's value or null).
template <class Field>
void nrrdGeometry(const Field& field, const std::string& path, glm::dvec3* spacing, PatientFrame* frame, std::vector<std::string>* warnings) {
  const std::string* directions = field("space directions");
  const std::string* spacings = field("spacings");
  if (!directions) {
    *spacing = glm::dvec3(1.0);
    if (spacings && !parseNumbers(*spacings, 3, &spacing->x))
      HYB_THROW(IoError, path, ": spacings ", quotedExcerpt(*spacings), " malformed (expected three numbers)");
    validateSpacing(*spacing, path);
    if (field("space origin")) HYB_THROW(IoError, path, ": space origin without space directions (expected both, or neither)");
    warnings->push_back(path + ": no 'space directions': orientation unknown, the grid's axes are taken as LPS with the origin at 0");
    frame->assumed = true;
    return;
  }
  const std::string* spaceField = field("space");
  const std::string space = spaceField ? lower(*spaceField) : "";
  glm::dvec3 sign(1.0);
  bool assumed = true;
  if (spaceField && !nrrdSpaceToLps(space, &sign, &assumed))
    HYB_THROW(IoError, path, ": space ", quotedExcerpt(*spaceField), " unsupported (expected right-anterior-superior, left-anterior-superior, "
              "left-posterior-superior or scanner-xyz: a 3D volume)");
  if (assumed)
    warnings->push_back(path + ": space '" + (spaceField ? *spaceField : std::string("(none)")) +
                        "' is not anatomical: its axes are taken as LPS (x left, y posterior, z superior)");
  double v[9];
  if (!parseVectors(*directions, 3, v))
    HYB_THROW(IoError, path, ": space directions ", quotedExcerpt(*directions), " malformed (expected three 3-vectors such as (0.9,0,0))");
  glm::dvec3 units(1.0);  // millimetres per unit of each space axis
  if (const std::string* u = field("space units")) {
    std::istringstream in(*u);
    for (int a = 0; a < 3; ++a) {
      std::string unit;
      if (!(in >> std::quoted(unit)) || (units[a] = unitMillimetres(lower(unit))) == 0.0)
        HYB_THROW(IoError, path, ": space units ", hyb::quotedExcerpt(*u), " unsupported (expected three of \"mm\", \"cm\", \"m\", \"um\")");
    }
  }
  glm::dmat3 d;
  for (int a = 0; a < 3; ++a) {
    d[a] = glm::dvec3(v[3 * a], v[3 * a + 1], v[3 * a + 2]) * units * sign;
    (*spacing)[a] = glm::length(d[a]);
  }
  validateSpacing(*spacing, path + " (lengths of the space directions)");
  glm::dvec3 origin(0.0);
  if (const std::string* o = field("space origin")) {
    if (!parseVectors(*o, 1, &origin.x)) HYB_THROW(IoError, path, ": space origin ", quotedExcerpt(*o), " malformed (expected one 3-vector (x,y,z))");
    origin *= sign * units;
  }
  *frame = makePatientFrame(d, origin, path);
  frame->assumed = assumed;
}

}  // namespace

Volume readNrrd(const std::string& path) {
  const InputFile file(path);
  uint8_t magic[7] = {};
  if (file.size() >= sizeof magic) file.read(0, sizeof magic, magic);
  if (std::memcmp(magic, "NRRD000", sizeof magic) != 0)
    HYB_THROW(IoError, path, ": not a NRRD file (expected magic 'NRRD000x' on the first line)");
  uint64_t dataStart = 0;
  const std::vector<std::string> lines = readHeaderLines(
      file, [](const std::string& line, bool* keep) { return !(*keep = !line.empty()); }, &dataStart);
  std::map<std::string, std::string> fields;
  for (size_t i = 1; i < lines.size(); ++i) {
    const std::string& line = lines[i];
    if (line[0] == '#') continue;
    const size_t colon = line.find(": ");
    if (colon == std::string::npos) {
      if (line.find(":=") != std::string::npos) continue;  // key/value pairs carry no layout
      HYB_THROW(IoError, path, ": malformed header line ", i + 1, " ", quotedExcerpt(line), " (expected 'field: value')");
    }
    fields[lower(trim(line.substr(0, colon)))] = trim(line.substr(colon + 2));
  }
  auto field = [&](const char* name) -> const std::string* {
    const auto it = fields.find(name);
    return it == fields.end() ? nullptr : &it->second;
  };
  auto required = [&](const char* name) -> const std::string& {
    const std::string* v = field(name);
    if (!v) HYB_THROW(IoError, path, ": missing required field ", quotedExcerpt(name), "");
    return *v;
  };

  ScalarType type;
  if (!nrrdType(lower(required("type")), &type))
    HYB_THROW(IoError, path, ": unknown or unsupported type ", quotedExcerpt(required("type")),
              " (expected int8/uint8/int16/uint16/int32/uint32/float/double)");
  int dimension = 0;
  if (!parseNumbers(required("dimension"), 1, &dimension) || dimension != 3)
    HYB_THROW(IoError, path, ": dimension ", quotedExcerpt(required("dimension")), " unsupported (expected 3)");
  const glm::ivec3 dims = parseDims(required("sizes"), "sizes", path);

  glm::dvec3 spacing(1.0);
  PatientFrame frame;
  std::vector<std::string> warnings;
  nrrdGeometry(field, path, &spacing, &frame, &warnings);

  const std::string encoding = lower(required("encoding"));
  const std::string* endianField = field("endian");
  if (scalarSize(type) > 1 && encoding != "ascii" && encoding != "text" && encoding != "txt" && !endianField)
    HYB_THROW(IoError, path, ": missing field 'endian' (required for multi-byte ", scalarName(type), " samples)");
  const std::string endian = endianField ? lower(*endianField) : "little";
  if (endian != "little" && endian != "big")
    HYB_THROW(IoError, path, ": endian ", quotedExcerpt(endian), " invalid (expected little or big)");
  long long byteSkip = 0, lineSkip = 0;
  if (const std::string* s = field("byte skip"); s && !parseNumbers(*s, 1, &byteSkip))
    HYB_THROW(IoError, path, ": byte skip ", quotedExcerpt(*s), " malformed");
  if (const std::string* s = field("line skip"); s && (!parseNumbers(*s, 1, &lineSkip) || lineSkip < 0))
    HYB_THROW(IoError, path, ": line skip ", quotedExcerpt(*s), " malformed");

  // Data: detached file or attached after the blank line.
  std::optional<InputFile> detached;
  const std::string* dataFile = field("data file") ? field("data file") : field("datafile");
  if (dataFile) {
    if (dataFile->rfind("LIST", 0) == 0 || dataFile->find('%') != std::string::npos ||
        dataFile->find(' ') != std::string::npos)
      HYB_THROW(IoError, path, ": multi-file 'data file' lists are not supported (expected one file)");
    fs::path p(*dataFile);
    if (p.is_relative()) p = fs::path(path).parent_path() / p;
    std::error_code ec;
    if (!fs::exists(p, ec)) HYB_THROW(IoError, path, ": data file ", quotedExcerpt(p.string(), 4096), " does not exist");
    detached.emplace(p.string());
    dataStart = 0;
  } else if (fileExtension(path) == ".nhdr") {
    HYB_THROW(IoError, path, ": detached header has no 'data file' field");
  }
  const InputFile& data = detached ? *detached : file;
  dataStart = skipLines(data, dataStart, lineSkip);

  std::vector<float> samples;
  if (encoding == "raw")
    samples = readRawSamples(data, dataStart, byteSkip, "byte skip", dims, type, endian == "big");
  else if (encoding == "gzip" || encoding == "gz")
    samples = readCompressedSamples(data, dataStart, byteSkip, dims, type, endian == "big");
  else if (encoding == "ascii" || encoding == "text" || encoding == "txt")
    samples = readAsciiSamples(data, dataStart, dims, type);
  else
    HYB_THROW(IoError, path, ": encoding ", quotedExcerpt(encoding), " unsupported (expected raw, gzip or ascii)");
  return placed(Volume(dims, spacing, type, std::move(samples), path), frame, warnings);
}

// ---------------------------------------------------------------------------------------------
// MetaImage (https://itk.org/Wiki/ITK/MetaIO/Documentation)

namespace {

// The patient frame of a MetaImage header (ITK's MetaImageIO): the origin from Offset (or its
// synonyms Position, Origin), the axes from TransformMatrix (or Rotation, Orientation), whose
// i-th row of three is the direction of axis i, in LPS. AnatomicalOrientation (letters naming the
// side each axis comes from, "RAI" for LPS axes) is only metadata to ITK: it places the axes here
// when no matrix is given, and a matrix that disagrees with it is warned about.
PatientFrame metaImageFrame(const std::map<std::string, std::string>& fields, const std::string& path, std::vector<std::string>* warnings) {
  auto first = [&](std::initializer_list<const char*> keys) -> std::pair<const char*, const std::string*> {
    for (const char* k : keys)
      if (const auto it = fields.find(k); it != fields.end()) return {k, &it->second};
    return {nullptr, nullptr};
  };
  glm::dvec3 origin(0.0);
  if (const auto [key, value] = first({"Offset", "Position", "Origin"}); key && !parseNumbers(*value, 3, &origin.x))
    HYB_THROW(IoError, path, ": ", key, " ", quotedExcerpt(*value), " malformed (expected three numbers)");
  // AnatomicalOrientation names where each axis comes from: its opposite letters are where it points.
  glm::dmat3 fromCode(1.0);
  bool haveCode = false;
  if (const auto [key, value] = first({"AnatomicalOrientation"}); key && *value != "???") {
    std::string to;
    for (char c : *value) {
      const char u = char(std::toupper(static_cast<unsigned char>(c)));
      static const std::map<char, char> kOpposite = {{'L', 'R'}, {'R', 'L'}, {'P', 'A'}, {'A', 'P'}, {'S', 'I'}, {'I', 'S'}};
      const auto it = kOpposite.find(u);
      to += it == kOpposite.end() ? '?' : it->second;
    }
    if (!directionFromCode(to, &fromCode))
      HYB_THROW(IoError, path, ": AnatomicalOrientation ", quotedExcerpt(*value), " malformed (expected three letters, one of R/L, A/P, S/I each, e.g. RAI)");
    haveCode = true;
  }
  glm::dmat3 direction(1.0);
  if (const auto [key, value] = first({"TransformMatrix", "Rotation", "Orientation"}); key) {
    double m[9];
    if (!parseNumbers(*value, 9, m)) HYB_THROW(IoError, path, ": ", key, " ", quotedExcerpt(*value), " malformed (expected nine numbers)");
    for (int a = 0; a < 3; ++a) direction[a] = glm::dvec3(m[3 * a], m[3 * a + 1], m[3 * a + 2]);
    const PatientFrame frame = makePatientFrame(direction, origin, path);
    if (haveCode && orientationCode(frame.direction) != orientationCode(fromCode))
      warnings->push_back(path + ": AnatomicalOrientation '" + fields.at("AnatomicalOrientation") + "' disagrees with " + key + " (" +
                          orientationCode(frame.direction) + "); the matrix is used, as ITK does");
    return frame;
  }
  if (!haveCode) warnings->push_back(path + ": no TransformMatrix or AnatomicalOrientation: the grid's axes are taken as LPS, as ITK does");
  PatientFrame frame = makePatientFrame(haveCode ? fromCode : direction, origin, path);
  frame.assumed = !haveCode;
  return frame;
}

}  // namespace


Volume readMetaImage(const std::string& path) {
  const InputFile file(path);
  std::map<std::string, std::string> fields;
  uint64_t dataStart = 0;
  const std::vector<std::string> lines = readHeaderLines(
      file, [](const std::string& line, bool*) { return trim(line.substr(0, line.find('='))) == "ElementDataFile"; }, &dataStart);
  for (const std::string& line : lines) {
    if (trim(line).empty()) continue;
    const size_t eq = line.find('=');
    if (eq == std::string::npos)
      HYB_THROW(IoError, path, ": malformed header line ", quotedExcerpt(trim(line)), " (expected 'Key = Value')");
    fields[trim(line.substr(0, eq))] = trim(line.substr(eq + 1));
  }
  auto required = [&](const char* name) -> const std::string& {
    const auto it = fields.find(name);
    if (it == fields.end()) HYB_THROW(IoError, path, ": missing required field ", quotedExcerpt(name), "");
    return it->second;
  };
  if (fields.count("ObjectType") && fields["ObjectType"] != "Image")
    HYB_THROW(IoError, path, ": ObjectType ", quotedExcerpt(fields["ObjectType"]), " unsupported (expected Image)");
  int ndims = 0;
  if (!parseNumbers(required("NDims"), 1, &ndims) || ndims != 3)
    HYB_THROW(IoError, path, ": NDims ", quotedExcerpt(required("NDims")), " unsupported (expected 3)");
  const glm::ivec3 dims = parseDims(required("DimSize"), "DimSize", path);
  if (fields.count("ElementNumberOfChannels") && trim(fields["ElementNumberOfChannels"]) != "1")
    HYB_THROW(IoError, path, ": ElementNumberOfChannels ", fields["ElementNumberOfChannels"], " unsupported (expected 1)");

  static const std::map<std::string, ScalarType> kTypes = {
      {"MET_UCHAR", ScalarType::UInt8},   {"MET_CHAR", ScalarType::Int8},    {"MET_USHORT", ScalarType::UInt16},
      {"MET_SHORT", ScalarType::Int16},   {"MET_UINT", ScalarType::UInt32},  {"MET_INT", ScalarType::Int32},
      {"MET_FLOAT", ScalarType::Float32}, {"MET_DOUBLE", ScalarType::Float64}};
  const auto typeIt = kTypes.find(required("ElementType"));
  if (typeIt == kTypes.end())
    HYB_THROW(IoError, path, ": ElementType ", quotedExcerpt(required("ElementType")), " unsupported (expected MET_UCHAR, MET_CHAR, ",
              "MET_USHORT, MET_SHORT, MET_UINT, MET_INT, MET_FLOAT or MET_DOUBLE)");
  const ScalarType type = typeIt->second;

  glm::dvec3 spacing(1.0);
  const char* spacingKey = fields.count("ElementSpacing") ? "ElementSpacing" : (fields.count("ElementSize") ? "ElementSize" : nullptr);
  if (spacingKey && !parseNumbers(fields[spacingKey], 3, &spacing.x))
    HYB_THROW(IoError, path, ": ", spacingKey, " ", quotedExcerpt(fields[spacingKey]), " malformed (expected three numbers)");
  validateSpacing(spacing, path);
  std::vector<std::string> warnings;
  const PatientFrame frame = metaImageFrame(fields, path, &warnings);

  auto isTrue = [&](const char* key) { return fields.count(key) && lower(fields[key]) == "true"; };
  const bool bigEndian = isTrue("ElementByteOrderMSB") || isTrue("BinaryDataByteOrderMSB");
  const bool compressed = isTrue("CompressedData");

  const std::string& dataFile = required("ElementDataFile");
  std::optional<InputFile> detached;
  if (dataFile != "LOCAL") {
    if (dataFile.rfind("LIST", 0) == 0 || dataFile.find('%') != std::string::npos)
      HYB_THROW(IoError, path, ": multi-file ElementDataFile is not supported (expected one file or LOCAL)");
    fs::path p(dataFile);
    if (p.is_relative()) p = fs::path(path).parent_path() / p;
    std::error_code ec;
    if (!fs::exists(p, ec)) HYB_THROW(IoError, path, ": data file ", quotedExcerpt(p.string(), 4096), " does not exist");
    detached.emplace(p.string());
    dataStart = 0;
  }
  const InputFile& data = detached ? *detached : file;
  long long headerSize = 0;
  if (fields.count("HeaderSize") && !parseNumbers(fields["HeaderSize"], 1, &headerSize))
    HYB_THROW(IoError, path, ": HeaderSize ", quotedExcerpt(fields["HeaderSize"]), " malformed");
  std::vector<float> samples = compressed ? readCompressedSamples(data, dataStart, 0, dims, type, bigEndian)
                                          : readRawSamples(data, dataStart, headerSize, "HeaderSize", dims, type, bigEndian);
  return placed(Volume(dims, spacing, type, std::move(samples), path), frame, warnings);
}

// ---------------------------------------------------------------------------------------------
// NIfTI through nifti_clib

namespace {

// The patient frame of a NIfTI image, with the precedence of ITK (5.x) and nibabel: the sform when
// its code is set and its axes are orthogonal (spacing: its columns' lengths), else the qform
// (nifti_clib's qto_xyz: quaternion, qfac and pixdim), else NIfTI's method 1 (RAS axes, origin 0)
// with a warning. NIfTI's world is RAS; the frame is LPS.
PatientFrame niftiFrame(const nifti_image& nim, const std::string& path, glm::dvec3* spacing, std::vector<std::string>* warnings) {
  const double unit = nim.xyz_units == NIFTI_UNITS_METER ? 1000.0 : nim.xyz_units == NIFTI_UNITS_MICRON ? 1e-3 : 1.0;
  auto fromMatrix = [&](const nifti_dmat44& m, const char* name) {
    glm::dmat3 d;
    for (int c = 0; c < 3; ++c) {
      d[c] = rasToLps(glm::dvec3(m.m[0][c], m.m[1][c], m.m[2][c]) * unit);
      (*spacing)[c] = glm::length(d[c]);
    }
    return makePatientFrame(d, rasToLps(glm::dvec3(m.m[0][3], m.m[1][3], m.m[2][3]) * unit), path + " (" + name + ")");
  };
  if (nim.sform_code > 0) {
    try {
      return fromMatrix(nim.sto_xyz, "sform");
    } catch (const ValueError& e) {
      if (nim.qform_code <= 0) throw;
      warnings->push_back(std::string(e.what()) + "; the qform is used instead, as ITK does");
    }
  }
  if (nim.qform_code > 0) return fromMatrix(nim.qto_xyz, "qform");
  warnings->push_back(path + ": qform_code and sform_code are 0 (no orientation): read as NIfTI's method 1 does, RAS axes with the origin at 0");
  *spacing *= unit;
  PatientFrame frame = makePatientFrame(glm::dmat3(glm::dvec3(-1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1)), glm::dvec3(0.0), path);
  frame.assumed = true;
  return frame;
}

}  // namespace

namespace {

// Checks the data file nifti_clib will read against the header's claim before it allocates:
// a plain file must hold the bytes, a gzip one must be able to inflate to them.
void checkNiftiData(const nifti_image& nim, const std::string& path) {
  if (!nim.iname) HYB_THROW(IoError, path, ": NIfTI header names no data file");
  const InputFile data(nim.iname);
  const uint64_t offset = uint64_t(std::max<int64_t>(0, nim.iname_offset));
  const uint64_t bytes = uint64_t(nim.nvox) * uint64_t(nim.nbyper);
  const uint64_t needed = offset + bytes;
  const bool gz = fileExtension(nim.iname).ends_with(".gz");
  if (!gz && data.size() < needed)
    HYB_THROW(IoError, data.path(), ": truncated NIfTI data: expected ", bytes, " bytes of samples from byte ", offset, ", found ",
              data.size() > offset ? data.size() - offset : 0);
  if (gz && detail::maxInflatedBytes(data.size()) < needed)
    HYB_THROW(IoError, data.path(), ": ", data.size(), " bytes of compressed data cannot hold the ", needed,
              " bytes the header declares (expected more: deflate inflates at most ", detail::kMaxDeflateRatio, ":1)");
  checkMemory(path, bytes + uint64_t(nim.nvox) * sizeof(float), detail::concat(nim.nvox, " NIfTI samples"));
}

}  // namespace

Volume readNifti(const std::string& path) {
  const InputFile header(path);  // refuses FIFOs and directories before nifti_clib opens them
  nifti_set_debug_level(0);  // we report errors ourselves, in one line
  // The header first: the data is loaded only once its size is proven by the file. nifti_clib
  // prints some errors whatever its debug level; they are captured and quoted in ours.
  detail::StderrCapture capture;
  std::unique_ptr<nifti_image, void (*)(nifti_image*)> nim(nifti_image_read(path.c_str(), 0), nifti_image_free);
  const std::string said = capture.finish();
  if (!nim)
    HYB_THROW(IoError, path, ": not a readable NIfTI-1/2 image", said.empty() ? "" : " (nifti_clib: " + quotedExcerpt(said, 120) + ")",
              " (expected a NIfTI-1 or NIfTI-2 header)");
  for (int d = 4; d <= nim->ndim && d < 8; ++d)
    if (nim->dim[d] > 1)
      HYB_THROW(IoError, path, ": NIfTI image has ", nim->ndim, " dimensions with extent ", nim->dim[d],
                " along axis ", d, " (expected one 3D volume)");
  if (nim->nx < 1 || nim->nx > kMaxDim || nim->ny > kMaxDim || nim->nz > kMaxDim || nim->nvox < 1 || nim->nbyper < 1 || nim->nbyper > 32)
    HYB_THROW(IoError, path, ": NIfTI dims ", nim->nx, "x", nim->ny, "x", nim->nz, " invalid (expected 1..", kMaxDim, " per axis)");
  checkNiftiData(*nim, path);
  detail::StderrCapture loadCapture;
  const bool loaded = nifti_image_load(nim.get()) == 0 && nim->data;
  const std::string loadSaid = loadCapture.finish();
  if (!loaded)
    HYB_THROW(IoError, path, ": NIfTI data could not be read", loadSaid.empty() ? "" : " (nifti_clib: " + quotedExcerpt(loadSaid, 120) + ")",
              " (expected ", uint64_t(nim->nvox) * uint64_t(nim->nbyper), " bytes of samples)");
  const glm::ivec3 dims(int(nim->nx), int(std::max<int64_t>(1, nim->ny)), int(std::max<int64_t>(1, nim->nz)));
  validateDims(dims, path);
  ScalarType type;
  switch (nim->datatype) {
    case DT_UINT8: type = ScalarType::UInt8; break;
    case DT_INT8: type = ScalarType::Int8; break;
    case DT_UINT16: type = ScalarType::UInt16; break;
    case DT_INT16: type = ScalarType::Int16; break;
    case DT_UINT32: type = ScalarType::UInt32; break;
    case DT_INT32: type = ScalarType::Int32; break;
    case DT_FLOAT32: type = ScalarType::Float32; break;
    case DT_FLOAT64: type = ScalarType::Float64; break;
    default:
      HYB_THROW(IoError, path, ": NIfTI datatype ", nim->datatype, " unsupported (expected a real scalar type)");
  }
  glm::dvec3 spacing(std::fabs(nim->dx), std::fabs(nim->dy > 0 ? nim->dy : 1.0), std::fabs(nim->dz > 0 ? nim->dz : 1.0));
  std::vector<std::string> warnings;
  const PatientFrame frame = niftiFrame(*nim, path, &spacing, &warnings);
  validateSpacing(spacing, path);
  const size_t count = size_t(dims.x) * dims.y * dims.z;
  // nifti_clib has already swapped to native byte order.
  std::vector<float> samples = decodeSamples(static_cast<const uint8_t*>(nim->data), count, type,
                                             std::endian::native == std::endian::big);
  const double slope = nim->scl_slope, inter = nim->scl_inter;
  if (std::isfinite(slope) && slope != 0.0 && std::isfinite(inter) && (slope != 1.0 || inter != 0.0)) {
    for (float& v : samples) v = float(v * slope + inter);
    type = ScalarType::Float32;
  }
  return placed(Volume(dims, spacing, type, std::move(samples), path), frame, warnings);
}

// ---------------------------------------------------------------------------------------------
// InVesalius 3 project: a gzip tar holding main.plist (matrix shape, dtype, spacing) and the
// matrix as raw samples in C order (z, y, x), native (little-endian) byte order.

namespace {

// The patient frame of an InVesalius project. Projects keep no orientation of their own (format 1;
// Cranium.inv3 among them): InVesalius builds the matrix from DICOM with the columns as they
// come (towards the patient's left in axial CT), the rows flipped (posterior to anterior) and the
// slices ordered inferior to superior, whatever the acquisition's plane, so the matrix is LAS.
// Projects made from NIfTI (InVesalius 3.1+) store "affine": the inverse of the rigid part of the
// RAS+ canonical image's affine, whose rows InVesalius flipped into its matrix; it is undone here.
PatientFrame inv3Frame(const detail::PlistValue& plist, const glm::ivec3& dims, const glm::dvec3& spacing, const std::string& path,
                       std::vector<std::string>* warnings) {
  const glm::dmat3 las(glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1));
  const detail::PlistValue* affine = plist.find("affine");
  std::vector<double> m;
  if (affine && affine->kind == detail::PlistValue::Kind::Array) {
    for (const detail::PlistValue& row : affine->items) {
      double x;
      if (row.kind == detail::PlistValue::Kind::Array) {
        for (const detail::PlistValue& e : row.items)
          if (e.number(&x)) m.push_back(x);
      } else if (row.number(&x)) {
        m.push_back(x);
      }
    }
    if (m.size() != 16) HYB_THROW(IoError, path, ": main.plist affine has ", m.size(), " numbers (expected a 4x4 matrix)");
  }
  glm::dmat4 a(1.0);
  for (size_t r = 0; r < m.size() / 4; ++r)
    for (int c = 0; c < 4; ++c) a[c][int(r)] = m[r * 4 + size_t(c)];
  if (m.empty() || a == glm::dmat4(1.0)) return makePatientFrame(las, glm::dvec3(0.0), path);
  // Canonical RAS voxel (i, ny−1−j, k) of the NIfTI InVesalius read is our voxel (i, j, k).
  const glm::dmat4 rigid = glm::inverse(a);
  const glm::dmat3 r(rigid);
  const glm::dvec3 t(rigid[3]);
  const glm::dmat3 flip(glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1));
  const glm::dvec3 shift(0.0, double(dims.y - 1) * spacing.y, 0.0);
  const glm::dmat3 toLps(glm::dvec3(-1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1));
  warnings->push_back(path + ": the project's affine is read as InVesalius's NIfTI import writes it (the inverse of the source's rigid RAS transform)");
  return makePatientFrame(toLps * r * flip, toLps * (r * shift + t), path + ":main.plist affine");
}

}  // namespace

namespace {

using ArchivePtr = std::unique_ptr<archive, int (*)(archive*)>;

// The .inv3 at @p path opened as a (gzip) tar; @p file proved it a regular file.
ArchivePtr openInv3(const InputFile& file) {
  ArchivePtr ar(archive_read_new(), archive_read_free);
  archive_read_support_filter_all(ar.get());
  archive_read_support_format_tar(ar.get());
  if (archive_read_open_filename(ar.get(), file.path().c_str(), 1 << 16) != ARCHIVE_OK)
    HYB_THROW(IoError, file.path(), ": not an InVesalius project (expected a gzip tar archive: ", archive_error_string(ar.get()), ")");
  return ar;
}

// The current entry's data, exactly @p size bytes (its declared size, checked by the caller):
// an entry that yields more or fewer is refused.
std::vector<uint8_t> readEntry(archive* ar, const std::string& path, const std::string& name, uint64_t size) {
  checkMemory(path + ":" + name, size, "the archive entry");
  std::vector<uint8_t> content(static_cast<size_t>(size));
  uint64_t got = 0;
  for (;;) {
    uint8_t spill;  // reading one byte past the size proves a longer entry
    uint8_t* out = got < size ? content.data() + got : &spill;
    const la_ssize_t n = archive_read_data(ar, out, got < size ? size_t(std::min<uint64_t>(size - got, 1 << 20)) : 1);
    if (n < 0)
      HYB_THROW(IoError, path, ": truncated or corrupt archive entry ", quotedExcerpt(name), " (", archive_error_string(ar), ")");
    if (n == 0) break;
    if (got == size) HYB_THROW(IoError, path, ": archive entry ", quotedExcerpt(name), " holds more than its declared ", size, " bytes");
    got += uint64_t(n);
  }
  if (got != size) HYB_THROW(IoError, path, ": archive entry ", quotedExcerpt(name), " ends after ", got, " of its declared ", size, " bytes");
  return content;
}

// One pass over the archive: main.plist (when @p plist is empty) and the entry named
// @p matrixName (when given and @p matrix is empty), whose declared size must be that of @p dims
// samples of @p type; every other entry is skipped unread. Returns whether the matrix was found.
bool scanInv3(const InputFile& file, std::string* plist, const std::string& matrixName, const glm::ivec3& dims, ScalarType type,
              std::vector<uint8_t>* matrix) {
  const ArchivePtr ar = openInv3(file);
  const std::string& path = file.path();
  archive_entry* entry = nullptr;
  int rc;
  while ((rc = archive_read_next_header(ar.get(), &entry)) == ARCHIVE_OK) {
    const char* entryPath = archive_entry_pathname(entry);
    const std::string name = entryPath ? fs::path(entryPath).filename().string() : std::string();
    const la_int64_t declared = archive_entry_size(entry);
    if (plist->empty() && name == "main.plist") {
      if (declared < 0 || uint64_t(declared) > detail::kMaxPlistBytes)
        HYB_THROW(IoError, path, ": main.plist declares ", declared, " bytes (expected at most ", detail::kMaxPlistBytes, ")");
      const std::vector<uint8_t> text = readEntry(ar.get(), path, name, uint64_t(declared));
      plist->assign(text.begin(), text.end());
      if (plist->empty()) HYB_THROW(IoError, path, ": main.plist is empty (expected an InVesalius 3 project)");
    } else if (!matrixName.empty() && matrix->empty() && name == matrixName) {
      const uint64_t expected = expectedBytes(dims, type);
      checkByteCount(path + ":" + name, expected, uint64_t(std::max<la_int64_t>(declared, 0)), dims, type);
      *matrix = readEntry(ar.get(), path, name, expected);
      if (!plist->empty()) return true;
    }
  }
  if (rc != ARCHIVE_EOF) HYB_THROW(IoError, path, ": truncated or corrupt archive (", archive_error_string(ar.get()), ")");
  return !matrix->empty();
}

}  // namespace

Volume readInv3(const std::string& path) {
  const InputFile file(path);
  std::string mainPlist;
  std::vector<uint8_t> matrixBytes;
  scanInv3(file, &mainPlist, "", glm::ivec3(1), ScalarType::UInt8, &matrixBytes);
  if (mainPlist.empty()) HYB_THROW(IoError, path, ": archive has no main.plist (expected an InVesalius 3 project)");

  const detail::PlistValue plist = detail::parsePlist(mainPlist, path + ":main.plist");
  const detail::PlistValue* matrix = plist.find("matrix");
  const detail::PlistValue* spacingList = plist.find("spacing");
  if (!matrix || !matrix->find("shape") || !matrix->find("filename") || !matrix->find("dtype") || !spacingList)
    HYB_THROW(IoError, path, ": main.plist lacks matrix shape/filename/dtype or spacing");
  const auto& shape = matrix->find("shape")->items;
  double shapeValues[3], spacingValues[3];
  if (shape.size() != 3 || spacingList->items.size() != 3)
    HYB_THROW(IoError, path, ": main.plist matrix shape and spacing must have 3 entries");
  for (int a = 0; a < 3; ++a)
    if (!shape[size_t(a)].number(&shapeValues[a]) || !spacingList->items[size_t(a)].number(&spacingValues[a]))
      HYB_THROW(IoError, path, ": main.plist matrix shape or spacing entry ", a, " is not a number");
  for (double s : shapeValues)
    if (s < 1 || s > kMaxDim || s != std::floor(s))
      HYB_THROW(IoError, path, ": main.plist matrix shape entry ", s, " invalid (expected 1..", kMaxDim, ")");
  const glm::ivec3 dims{int(shapeValues[2]), int(shapeValues[1]), int(shapeValues[0])};  // shape is (z, y, x)
  validateDims(dims, path);
  const glm::dvec3 spacing(spacingValues[0], spacingValues[1], spacingValues[2]);
  validateSpacing(spacing, path);
  static const std::map<std::string, ScalarType> kTypes = {
      {"int16", ScalarType::Int16}, {"uint16", ScalarType::UInt16}, {"uint8", ScalarType::UInt8},
      {"int8", ScalarType::Int8},   {"int32", ScalarType::Int32},   {"uint32", ScalarType::UInt32},
      {"float32", ScalarType::Float32}, {"float64", ScalarType::Float64}};
  const std::string dtype = matrix->find("dtype")->text;
  const auto typeIt = kTypes.find(dtype);
  if (typeIt == kTypes.end()) HYB_THROW(IoError, path, ": matrix dtype ", quotedExcerpt(dtype), " unsupported");
  const std::string matrixName = fs::path(matrix->find("filename")->text).filename().string();
  const ScalarType type = typeIt->second;
  const uint64_t expected = expectedBytes(dims, type);
  checkSampleMemory(path, expected, dims, type);
  // A second pass reads the matrix alone, now that its name and size are known.
  if (matrixName.empty() || !scanInv3(file, &mainPlist, matrixName, dims, type, &matrixBytes))
    HYB_THROW(IoError, path, ": archive has no matrix file ", quotedExcerpt(matrixName), "");
  std::vector<std::string> warnings;
  const PatientFrame frame = inv3Frame(plist, dims, spacing, path, &warnings);
  Volume v = placed(Volume(dims, spacing, type, decodeSamples(matrixBytes.data(), size_t(dims.x) * dims.y * dims.z, type, false), path),
                    frame, warnings);
  for (const char* key : {"modality", "name"})
    if (const detail::PlistValue* value = plist.find(key); value && value->kind == detail::PlistValue::Kind::String)
      v.addInfo(key, value->text);
  return v;
}

// ---------------------------------------------------------------------------------------------
// Raw

Volume readRaw(const std::string& path, const RawLayout& layout) {
  validateDims(layout.dims, "--raw-dims");
  validateSpacing(layout.spacing, "--raw-spacing");
  const InputFile file(path);
  if (layout.headerBytes > file.size())
    HYB_THROW(IoError, path, ": header of ", layout.headerBytes, " bytes is longer than the ", file.size(), "-byte file");
  Volume v(layout.dims, layout.spacing, layout.type,
           readRawSamples(file, layout.headerBytes, 0, "header", layout.dims, layout.type, layout.bigEndian), path);
  v.addWarning(path + ": raw samples carry no orientation: the grid's axes are taken as LPS with the origin at 0");
  PatientFrame frame;
  frame.assumed = true;
  v.setFrame(frame);
  return v;
}

namespace {

// @p message with control characters escaped: a reader's error stays one line whatever it quotes.
std::string oneLine(const std::string& message) {
  std::string out;
  for (const char c : message) {
    if (static_cast<unsigned char>(c) >= 0x20 && c != 0x7f) {
      out += c;
    } else {
      static const char* kHex = "0123456789abcdef";
      out += "\\x";
      out += kHex[static_cast<unsigned char>(c) >> 4];
      out += kHex[c & 15];
    }
  }
  return out;
}

Volume readByFormat(const std::string& path, const RawLayout* raw, const std::string& series, const Progress* progress) {
  if (raw) return readRaw(path, *raw);
  std::error_code ec;
  if (!fs::exists(path, ec)) HYB_THROW(IoError, path, ": file does not exist");
  if (fs::is_directory(path, ec)) return readDicomSeries(path, series, progress);
  if (!series.empty()) HYB_THROW(ValueError, "--series needs a DICOM directory (", path, " is a file)");
  const std::string ext = fileExtension(path);
  if (ext == ".nrrd" || ext == ".nhdr") return readNrrd(path);
  if (ext == ".mhd" || ext == ".mha") return readMetaImage(path);
  if (ext == ".nii" || ext == ".nii.gz" || ext == ".hdr") return readNifti(path);
  if (ext == ".inv3") return readInv3(path);
  if (ext == ".raw")
    HYB_THROW(ValueError, path, ": raw data needs --raw-dims X,Y,Z and --raw-type (and optionally --raw-spacing, --raw-endian)");
  HYB_THROW(IoError, path, ": unknown volume format '", ext,
            "' (expected .nrrd .nhdr .mhd .mha .nii .nii.gz .inv3, a DICOM directory, or raw with --raw-dims)");
}

}  // namespace

Volume readVolume(const std::string& path, const RawLayout* raw, const std::string& series, const Progress* progress) {
  try {
    return readByFormat(path, raw, series, progress);
  } catch (const IoError& e) {
    throw IoError(oneLine(e.what()));
  } catch (const ValueError& e) {
    throw ValueError(oneLine(e.what()));
  } catch (const RuntimeError& e) {
    throw RuntimeError(oneLine(e.what()));
  } catch (const std::bad_alloc&) {
    HYB_THROW(RuntimeError, oneLine(path), ": out of memory while reading (expected a volume that fits; lower the memory limit to refuse it early)");
  }
}

}  // namespace hyb
