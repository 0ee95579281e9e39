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
#include <sstream>

#include "volume/file_util.h"
#include "volume/patient_frame.h"
#include "volume/plist.h"

namespace hyb {

namespace fs = std::filesystem;

namespace {

// ---------------------------------------------------------------------------------------------
// Shared helpers

std::string trim(const std::string& s) {
  const size_t b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  const size_t e = s.find_last_not_of(" \t\r\n");
  return s.substr(b, e - b + 1);
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

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

// Converts @p count samples of type @p t at @p data (any alignment) to float.
std::vector<float> decodeSamples(const uint8_t* data, size_t count, ScalarType t, bool bigEndian) {
  const size_t size = scalarSize(t);
  std::vector<float> out(count);
  const bool swap = bigEndian != (std::endian::native == std::endian::big);
#pragma omp parallel for schedule(static)
  for (size_t i = 0; i < count; ++i) {
    uint8_t b[8];
    std::memcpy(b, data + i * size, size);
    if (swap) std::reverse(b, b + size);
    switch (t) {
      case ScalarType::UInt8: out[i] = b[0]; break;
      case ScalarType::Int8: out[i] = static_cast<int8_t>(b[0]); break;
      case ScalarType::UInt16: { uint16_t v; std::memcpy(&v, b, 2); out[i] = v; break; }
      case ScalarType::Int16: { int16_t v; std::memcpy(&v, b, 2); out[i] = v; break; }
      case ScalarType::UInt32: { uint32_t v; std::memcpy(&v, b, 4); out[i] = float(v); break; }
      case ScalarType::Int32: { int32_t v; std::memcpy(&v, b, 4); out[i] = float(v); break; }
      case ScalarType::Float32: { float v; std::memcpy(&v, b, 4); out[i] = v; break; }
      case ScalarType::Float64: { double v; std::memcpy(&v, b, 8); out[i] = float(v); break; }
    }
  }
  return out;
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

// Skips @p skip header bytes of raw data (-1: the samples are the file's last bytes), then checks
// that exactly @p expected bytes remain. @p field names the header field in messages.
void skipToSamples(const uint8_t** data, size_t* size, long long skip, uint64_t expected, const std::string& file,
                   const char* field, const glm::ivec3& dims, ScalarType t) {
  if (skip == -1) {
    if (*size < expected) checkByteCount(file, expected, *size, dims, t);
    *data += *size - expected;
    *size = size_t(expected);
  } else if (skip < 0 || uint64_t(skip) > *size) {
    HYB_THROW(IoError, file, ": ", field, " ", skip, " invalid for a ", *size, "-byte file");
  } else {
    *data += skip;
    *size -= size_t(skip);
  }
  checkByteCount(file, expected, *size, dims, t);
}

// Inflates a gzip or zlib stream (auto-detected) of unknown length.
std::vector<uint8_t> inflateAll(const uint8_t* data, size_t size, uint64_t sizeHint, const std::string& file) {
  z_stream z{};
  if (inflateInit2(&z, 15 + 32) != Z_OK) HYB_THROW(RuntimeError, file, ": zlib initialisation failed");
  std::vector<uint8_t> out(std::max<uint64_t>(sizeHint, 1024));
  z.next_in = const_cast<uint8_t*>(data);
  z.avail_in = static_cast<uInt>(std::min<size_t>(size, UINT32_MAX));
  size_t inLeft = size - z.avail_in;
  size_t produced = 0;
  int rc = Z_OK;
  while (rc != Z_STREAM_END) {
    if (produced == out.size()) out.resize(out.size() * 2);
    z.next_out = out.data() + produced;
    z.avail_out = static_cast<uInt>(std::min<size_t>(out.size() - produced, UINT32_MAX));
    const uInt before = z.avail_out;
    rc = inflate(&z, Z_NO_FLUSH);
    produced += before - z.avail_out;
    if (rc == Z_BUF_ERROR && z.avail_in == 0 && inLeft > 0) {
      const size_t chunk = std::min<size_t>(inLeft, UINT32_MAX);
      z.avail_in = static_cast<uInt>(chunk);
      inLeft -= chunk;
      continue;
    }
    if (rc == Z_BUF_ERROR && z.avail_in == 0) {
      inflateEnd(&z);
      HYB_THROW(IoError, file, ": truncated compressed data: stream ends after ", produced, " bytes");
    }
    if (rc != Z_OK && rc != Z_STREAM_END && rc != Z_BUF_ERROR) {
      const std::string msg = z.msg ? z.msg : "unknown error";
      inflateEnd(&z);
      HYB_THROW(IoError, file, ": corrupt compressed data (", msg, ")");
    }
  }
  inflateEnd(&z);
  out.resize(produced);
  return out;
}

// Parses whitespace-separated ASCII samples.
std::vector<float> parseAsciiSamples(const char* begin, const char* end, size_t count, const std::string& file) {
  std::vector<float> out;
  out.reserve(count);
  const char* p = begin;
  while (p < end) {
    while (p < end && (std::isspace(static_cast<unsigned char>(*p)) || *p == ',')) ++p;
    if (p >= end) break;
    char* next = nullptr;
    const std::string token(p, std::find_if(p, end, [](char c) { return std::isspace(static_cast<unsigned char>(c)) || c == ','; }));
    const double v = std::strtod(token.c_str(), &next);
    if (next == token.c_str()) HYB_THROW(IoError, file, ": expected a number in ASCII data, found '", token, "'");
    out.push_back(float(v));
    p += token.size();
  }
  if (out.size() != count)
    HYB_THROW(IoError, file, ": ASCII data holds ", out.size(), " samples, expected ", count);
  return out;
}

// Three sample counts from header field @p field, each in 1..kMaxDim, with a product in range.
glm::ivec3 parseDims(const std::string& text, const char* field, const std::string& path) {
  long long sizes[3];
  if (!parseNumbers(text, 3, sizes))
    HYB_THROW(IoError, path, ": ", field, " '", text, "' malformed (expected three integers)");
  for (long long s : sizes)
    if (s <= 0 || s > kMaxDim) HYB_THROW(IoError, path, ": ", field, " '", text, "' invalid (expected 1..", kMaxDim, " per axis)");
  const glm::ivec3 dims{int(sizes[0]), int(sizes[1]), int(sizes[2])};
  validateDims(dims, path);
  return dims;
}

// @p v with the patient frame and the reader's warnings.
Volume placed(Volume v, const PatientFrame& frame, const std::vector<std::string>& warnings) {
  v.setFrame(frame);
  for (const std::string& w : warnings) v.addWarning(w);
  return v;
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
      HYB_THROW(IoError, path, ": spacings '", *spacings, "' malformed (expected three numbers)");
    validateSpacing(*spacing, path);
    if (field("space origin")) HYB_THROW(IoError, path, ": space origin without space directions (expected both, or neither)");
    warnings->push_back(path + ": no 'space directions': orientation unknown, the grid's axes are taken as LPS with the origin at 0");
    return;
  }
  const std::string* spaceField = field("space");
  const std::string space = spaceField ? lower(*spaceField) : "";
  glm::dvec3 sign(1.0);
  bool assumed = true;
  if (spaceField && !nrrdSpaceToLps(space, &sign, &assumed))
    HYB_THROW(IoError, path, ": space '", *spaceField, "' unsupported (expected right-anterior-superior, left-anterior-superior, "
              "left-posterior-superior or scanner-xyz: a 3D volume)");
  if (assumed)
    warnings->push_back(path + ": space '" + (spaceField ? *spaceField : std::string("(none)")) +
                        "' is not anatomical: its axes are taken as LPS (x left, y posterior, z superior)");
  double v[9];
  if (!parseVectors(*directions, 3, v))
    HYB_THROW(IoError, path, ": space directions '", *directions, "' malformed (expected three 3-vectors such as (0.9,0,0))");
  glm::dvec3 units(1.0);  // millimetres per unit of each space axis
  if (const std::string* u = field("space units")) {
    std::istringstream in(*u);
    for (int a = 0; a < 3; ++a) {
      std::string quoted;
      if (!(in >> std::quoted(quoted)) || (units[a] = unitMillimetres(lower(quoted))) == 0.0)
        HYB_THROW(IoError, path, ": space units '", *u, "' unsupported (expected three of \"mm\", \"cm\", \"m\", \"um\")");
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
    if (!parseVectors(*o, 1, &origin.x)) HYB_THROW(IoError, path, ": space origin '", *o, "' malformed (expected one 3-vector (x,y,z))");
    origin *= sign * units;
  }
  *frame = makePatientFrame(d, origin, path);
}

// Offset of the first byte after the header's blank line (or the end of the bytes).
size_t headerEnd(const std::vector<uint8_t>& bytes, std::vector<std::string>* lines) {
  size_t pos = 0;
  while (pos < bytes.size()) {
    const uint8_t* nl = static_cast<const uint8_t*>(std::memchr(bytes.data() + pos, '\n', bytes.size() - pos));
    const size_t end = nl ? size_t(nl - bytes.data()) : bytes.size();
    std::string line(reinterpret_cast<const char*>(bytes.data() + pos), end - pos);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    pos = nl ? end + 1 : end;
    if (line.empty()) return pos;
    lines->push_back(line);
  }
  return bytes.size();
}

}  // namespace

Volume readNrrd(const std::string& path) {
  const std::vector<uint8_t> bytes = readFileBytes(path);
  std::vector<std::string> lines;
  const size_t dataStart = headerEnd(bytes, &lines);
  if (lines.empty() || lines[0].rfind("NRRD000", 0) != 0)
    HYB_THROW(IoError, path, ": not a NRRD file (expected magic 'NRRD000x' on the first line)");

  std::map<std::string, std::string> fields;
  for (size_t i = 1; i < lines.size(); ++i) {
    const std::string& line = lines[i];
    if (line[0] == '#') continue;
    const size_t colon = line.find(": ");
    if (colon == std::string::npos) {
      if (line.find(":=") != std::string::npos) continue;  // key/value pairs carry no layout
      HYB_THROW(IoError, path, ": malformed header line ", i + 1, " '", line, "' (expected 'field: value')");
    }
    fields[lower(trim(line.substr(0, colon)))] = trim(line.substr(colon + 2));
  }
  auto field = [&](const char* name) -> const std::string* {
    const auto it = fields.find(name);
    return it == fields.end() ? nullptr : &it->second;
  };
  auto required = [&](const char* name) -> const std::string& {
    const std::string* v = field(name);
    if (!v) HYB_THROW(IoError, path, ": missing required field '", name, "'");
    return *v;
  };

  ScalarType type;
  if (!nrrdType(lower(required("type")), &type))
    HYB_THROW(IoError, path, ": unknown or unsupported type '", required("type"),
              "' (expected int8/uint8/int16/uint16/int32/uint32/float/double)");
  int dimension = 0;
  if (!parseNumbers(required("dimension"), 1, &dimension) || dimension != 3)
    HYB_THROW(IoError, path, ": dimension '", required("dimension"), "' unsupported (expected 3)");
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
    HYB_THROW(IoError, path, ": endian '", endian, "' invalid (expected little or big)");
  long long byteSkip = 0, lineSkip = 0;
  if (const std::string* s = field("byte skip"); s && !parseNumbers(*s, 1, &byteSkip))
    HYB_THROW(IoError, path, ": byte skip '", *s, "' malformed");
  if (const std::string* s = field("line skip"); s && (!parseNumbers(*s, 1, &lineSkip) || lineSkip < 0))
    HYB_THROW(IoError, path, ": line skip '", *s, "' malformed");

  // Data: detached file or attached after the blank line.
  std::vector<uint8_t> detached;
  std::string dataName = path;
  const uint8_t* data = bytes.data() + dataStart;
  size_t dataSize = bytes.size() - dataStart;
  const std::string* dataFile = field("data file") ? field("data file") : field("datafile");
  if (dataFile) {
    if (dataFile->rfind("LIST", 0) == 0 || dataFile->find('%') != std::string::npos ||
        dataFile->find(' ') != std::string::npos)
      HYB_THROW(IoError, path, ": multi-file 'data file' lists are not supported (expected one file)");
    fs::path p(*dataFile);
    if (p.is_relative()) p = fs::path(path).parent_path() / p;
    dataName = p.string();
    std::error_code ec;
    if (!fs::exists(p, ec)) HYB_THROW(IoError, path, ": data file '", dataName, "' does not exist");
    detached = readFileBytes(dataName);
    data = detached.data();
    dataSize = detached.size();
  } else if (fileExtension(path) == ".nhdr") {
    HYB_THROW(IoError, path, ": detached header has no 'data file' field");
  }
  for (long long l = 0; l < lineSkip; ++l) {
    const void* nl = std::memchr(data, '\n', dataSize);
    if (!nl) HYB_THROW(IoError, dataName, ": cannot skip ", lineSkip, " lines (file too short)");
    const size_t skip = size_t(static_cast<const uint8_t*>(nl) - data) + 1;
    data += skip;
    dataSize -= skip;
  }

  const uint64_t expected = expectedBytes(dims, type);
  const size_t count = size_t(dims.x) * dims.y * dims.z;
  std::vector<float> samples;
  if (encoding == "raw") {
    skipToSamples(&data, &dataSize, byteSkip, expected, dataName, "byte skip", dims, type);
    samples = decodeSamples(data, count, type, endian == "big");
  } else if (encoding == "gzip" || encoding == "gz") {
    std::vector<uint8_t> raw = inflateAll(data, dataSize, expected, dataName);
    if (byteSkip < 0 || uint64_t(byteSkip) > raw.size())
      HYB_THROW(IoError, dataName, ": byte skip ", byteSkip, " invalid for gzip data");
    checkByteCount(dataName + " (decompressed)", expected, raw.size() - size_t(byteSkip), dims, type);
    samples = decodeSamples(raw.data() + byteSkip, count, type, endian == "big");
  } else if (encoding == "ascii" || encoding == "text" || encoding == "txt") {
    samples = parseAsciiSamples(reinterpret_cast<const char*>(data), reinterpret_cast<const char*>(data) + dataSize,
                                count, dataName);
  } else {
    HYB_THROW(IoError, path, ": encoding '", encoding, "' unsupported (expected raw, gzip or ascii)");
  }
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
    HYB_THROW(IoError, path, ": ", key, " '", *value, "' malformed (expected three numbers)");
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
      HYB_THROW(IoError, path, ": AnatomicalOrientation '", *value, "' malformed (expected three letters, one of R/L, A/P, S/I each, e.g. RAI)");
    haveCode = true;
  }
  glm::dmat3 direction(1.0);
  if (const auto [key, value] = first({"TransformMatrix", "Rotation", "Orientation"}); key) {
    double m[9];
    if (!parseNumbers(*value, 9, m)) HYB_THROW(IoError, path, ": ", key, " '", *value, "' malformed (expected nine numbers)");
    for (int a = 0; a < 3; ++a) direction[a] = glm::dvec3(m[3 * a], m[3 * a + 1], m[3 * a + 2]);
    const PatientFrame frame = makePatientFrame(direction, origin, path);
    if (haveCode && orientationCode(frame.direction) != orientationCode(fromCode))
      warnings->push_back(path + ": AnatomicalOrientation '" + fields.at("AnatomicalOrientation") + "' disagrees with " + key + " (" +
                          orientationCode(frame.direction) + "); the matrix is used, as ITK does");
    return frame;
  }
  if (!haveCode) warnings->push_back(path + ": no TransformMatrix or AnatomicalOrientation: the grid's axes are taken as LPS, as ITK does");
  return makePatientFrame(haveCode ? fromCode : direction, origin, path);
}

}  // namespace


Volume readMetaImage(const std::string& path) {
  const std::vector<uint8_t> bytes = readFileBytes(path);
  std::map<std::string, std::string> fields;
  size_t pos = 0;
  size_t dataStart = std::string::npos;
  while (pos < bytes.size()) {
    const uint8_t* nl = static_cast<const uint8_t*>(std::memchr(bytes.data() + pos, '\n', bytes.size() - pos));
    const size_t end = nl ? size_t(nl - bytes.data()) : bytes.size();
    const std::string line(reinterpret_cast<const char*>(bytes.data() + pos), end - pos);
    pos = nl ? end + 1 : end;
    if (trim(line).empty()) continue;
    const size_t eq = line.find('=');
    if (eq == std::string::npos)
      HYB_THROW(IoError, path, ": malformed header line '", trim(line), "' (expected 'Key = Value')");
    const std::string key = trim(line.substr(0, eq));
    fields[key] = trim(line.substr(eq + 1));
    if (key == "ElementDataFile") {
      dataStart = pos;
      break;
    }
  }
  auto required = [&](const char* name) -> const std::string& {
    const auto it = fields.find(name);
    if (it == fields.end()) HYB_THROW(IoError, path, ": missing required field '", name, "'");
    return it->second;
  };
  if (fields.count("ObjectType") && fields["ObjectType"] != "Image")
    HYB_THROW(IoError, path, ": ObjectType '", fields["ObjectType"], "' unsupported (expected Image)");
  int ndims = 0;
  if (!parseNumbers(required("NDims"), 1, &ndims) || ndims != 3)
    HYB_THROW(IoError, path, ": NDims '", required("NDims"), "' unsupported (expected 3)");
  const glm::ivec3 dims = parseDims(required("DimSize"), "DimSize", path);
  if (fields.count("ElementNumberOfChannels") && trim(fields["ElementNumberOfChannels"]) != "1")
    HYB_THROW(IoError, path, ": ElementNumberOfChannels ", fields["ElementNumberOfChannels"], " unsupported (expected 1)");

  static const std::map<std::string, ScalarType> kTypes = {
      {"MET_UCHAR", ScalarType::UInt8},   {"MET_CHAR", ScalarType::Int8},    {"MET_USHORT", ScalarType::UInt16},
      {"MET_SHORT", ScalarType::Int16},   {"MET_UINT", ScalarType::UInt32},  {"MET_INT", ScalarType::Int32},
      {"MET_FLOAT", ScalarType::Float32}, {"MET_DOUBLE", ScalarType::Float64}};
  const auto typeIt = kTypes.find(required("ElementType"));
  if (typeIt == kTypes.end())
    HYB_THROW(IoError, path, ": ElementType '", required("ElementType"), "' unsupported (expected MET_UCHAR, MET_CHAR, ",
              "MET_USHORT, MET_SHORT, MET_UINT, MET_INT, MET_FLOAT or MET_DOUBLE)");
  const ScalarType type = typeIt->second;

  glm::dvec3 spacing(1.0);
  const char* spacingKey = fields.count("ElementSpacing") ? "ElementSpacing" : (fields.count("ElementSize") ? "ElementSize" : nullptr);
  if (spacingKey && !parseNumbers(fields[spacingKey], 3, &spacing.x))
    HYB_THROW(IoError, path, ": ", spacingKey, " '", fields[spacingKey], "' malformed (expected three numbers)");
  validateSpacing(spacing, path);
  std::vector<std::string> warnings;
  const PatientFrame frame = metaImageFrame(fields, path, &warnings);

  auto isTrue = [&](const char* key) { return fields.count(key) && lower(fields[key]) == "true"; };
  const bool bigEndian = isTrue("ElementByteOrderMSB") || isTrue("BinaryDataByteOrderMSB");
  const bool compressed = isTrue("CompressedData");

  const std::string& dataFile = required("ElementDataFile");
  std::vector<uint8_t> detached;
  std::string dataName = path;
  const uint8_t* data = nullptr;
  size_t dataSize = 0;
  if (dataFile == "LOCAL") {
    data = bytes.data() + dataStart;
    dataSize = bytes.size() - dataStart;
  } else {
    if (dataFile.rfind("LIST", 0) == 0 || dataFile.find('%') != std::string::npos)
      HYB_THROW(IoError, path, ": multi-file ElementDataFile is not supported (expected one file or LOCAL)");
    fs::path p(dataFile);
    if (p.is_relative()) p = fs::path(path).parent_path() / p;
    dataName = p.string();
    std::error_code ec;
    if (!fs::exists(p, ec)) HYB_THROW(IoError, path, ": data file '", dataName, "' does not exist");
    detached = readFileBytes(dataName);
    data = detached.data();
    dataSize = detached.size();
  }
  long long headerSize = 0;
  if (fields.count("HeaderSize") && !parseNumbers(fields["HeaderSize"], 1, &headerSize))
    HYB_THROW(IoError, path, ": HeaderSize '", fields["HeaderSize"], "' malformed");

  const uint64_t expected = expectedBytes(dims, type);
  const size_t count = size_t(dims.x) * dims.y * dims.z;
  if (compressed) {
    const std::vector<uint8_t> raw = inflateAll(data, dataSize, expected, dataName);
    checkByteCount(dataName + " (decompressed)", expected, raw.size(), dims, type);
    return placed(Volume(dims, spacing, type, decodeSamples(raw.data(), count, type, bigEndian), path), frame, warnings);
  }
  skipToSamples(&data, &dataSize, headerSize, expected, dataName, "HeaderSize", dims, type);
  return placed(Volume(dims, spacing, type, decodeSamples(data, count, type, bigEndian), path), frame, warnings);
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
  return makePatientFrame(glm::dmat3(glm::dvec3(-1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1)), glm::dvec3(0.0), path);
}

}  // namespace

Volume readNifti(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) HYB_THROW(IoError, path, ": file does not exist");
  nifti_set_debug_level(0);  // we report errors ourselves, in one line
  std::unique_ptr<nifti_image, void (*)(nifti_image*)> nim(nifti_image_read(path.c_str(), 1), nifti_image_free);
  if (!nim) HYB_THROW(IoError, path, ": not a readable NIfTI-1/2 image (bad header, or data missing or truncated)");
  if (!nim->data) HYB_THROW(IoError, path, ": NIfTI data could not be read (missing or truncated)");
  for (int d = 4; d <= nim->ndim; ++d)
    if (nim->dim[d] > 1)
      HYB_THROW(IoError, path, ": NIfTI image has ", nim->ndim, " dimensions with extent ", nim->dim[d],
                " along axis ", d, " (expected one 3D volume)");
  if (nim->nx > kMaxDim || nim->ny > kMaxDim || nim->nz > kMaxDim)
    HYB_THROW(IoError, path, ": NIfTI dims exceed ", kMaxDim, " per axis");
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
// DICOM series through GDCM

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
// reader reports what matters in its own one-line errors instead.
void silenceGdcm() {
  gdcm::Trace::WarningOff();
  gdcm::Trace::ErrorOff();
  gdcm::Trace::DebugOff();
}

void scanDicom(const std::string& dir, DicomScan* scan) {
  silenceGdcm();
  gdcm::Directory directory;
  if (directory.Load(dir, false) == 0) HYB_THROW(IoError, dir, ": directory holds no files (expected a DICOM series)");
  for (const gdcm::Tag& t : {kSeriesUid, kSeriesNumber, kSeriesDescription, kModality, kRows, kColumns, kPosition, kOrientation, kThickness,
                             kSlope, kIntercept, kPatientPosition})
    scan->scanner.AddTag(t);
  if (!scan->scanner.Scan(directory.GetFilenames())) HYB_THROW(IoError, dir, ": cannot scan the directory for DICOM files");
  for (const std::string& f : directory.GetFilenames())
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
  return detail::concat("'", s.uid, "' (", s.modality.empty() ? "?" : s.modality, s.description.empty() ? "" : ", " + s.description, ", ",
                        s.slices, " slices of ", s.columns, "x", s.rows, ")");
}

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
  DicomScan scan;
  scanDicom(dir, &scan);
  std::vector<std::string> warnings;
  // The series: the one named, or the largest (with a line naming it when there are several).
  std::vector<DicomSeriesInfo> all;
  for (const auto& [uid, files] : scan.series) all.push_back(seriesInfo(scan, uid, files));
  std::stable_sort(all.begin(), all.end(), [](const DicomSeriesInfo& a, const DicomSeriesInfo& b) { return a.slices > b.slices; });
  std::string listing;
  for (const DicomSeriesInfo& s : all) listing += (listing.empty() ? "" : "; ") + describe(s);
  const DicomSeriesInfo* chosen = &all.front();
  if (!seriesUid.empty()) {
    const auto it = std::find_if(all.begin(), all.end(), [&](const DicomSeriesInfo& s) { return s.uid == seriesUid; });
    if (it == all.end()) HYB_THROW(ValueError, "--series '", seriesUid, "': no such series in ", dir, " (it holds ", listing, ")");
    chosen = &*it;
  } else if (all.size() > 1) {
    warnings.push_back(detail::concat(dir, ": ", all.size(), " series; reading the largest, ", describe(*chosen),
                                      " (choose another with --series UID: ", listing, ")"));
  }
  std::vector<std::string> files = scan.series.at(chosen->uid);

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
    warnings.push_back(files.front() + ": no Image Orientation (Patient): the slice's axes are taken as LPS");
  }
  const PatientFrame axes = makePatientFrame(direction, glm::dvec3(0.0), files.front() + " (Image Orientation (Patient))");
  struct Slice {
    std::string file;
    glm::dvec3 position;
    double depth;
  };
  std::vector<Slice> slices;
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
    slices.push_back({f, p, glm::dot(p, axes.direction[2])});
  }
  std::sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.depth < b.depth; });
  double zSpacing = 1.0;
  if (slices.size() > 1) {
    zSpacing = (slices.back().depth - slices.front().depth) / double(slices.size() - 1);
    for (size_t k = 1; k < slices.size(); ++k) {
      const double step = slices[k].depth - slices[k - 1].depth;
      if (step <= 1e-3 * std::max(zSpacing, 1e-3))
        HYB_THROW(IoError, slices[k].file, ": at the same position as ", slices[k - 1].file, " along the slice normal (expected one slice per position)");
      if (std::abs(step - zSpacing) > std::max(1e-3, 1e-2 * zSpacing))
        HYB_THROW(IoError, dir, ": slices are not evenly spaced along the normal (", slices[k - 1].file, " to ", slices[k].file, ": ", step,
                  " mm, the series' mean ", zSpacing, " mm; expected a regular grid)");
      // Positions must run along the normal: a gantry tilt moves them across the image plane.
      const glm::dvec3 offset = slices[k].position - slices.front().position;
      const double across = glm::length(offset - glm::dot(offset, axes.direction[2]) * axes.direction[2]);
      if (across > std::max(1e-2, 1e-3 * glm::length(offset)))
        HYB_THROW(IoError, dir, ": slice positions move ", across, " mm across the image plane by ", slices[k].file,
                  " (gantry tilt or a sheared series: the grid is not orthogonal); resample it to an orthogonal grid first "
                  "(e.g. Slicer or ITK), it is refused rather than drawn sheared");
    }
  } else if (const std::vector<double> t = decimals(scan.scanner.GetValue(slices.front().file.c_str(), kThickness)); t.size() == 1 && t[0] > 0) {
    zSpacing = t[0];
  }

  glm::ivec3 dims(0, 0, int(slices.size()));
  glm::dvec3 spacing(1.0, 1.0, zSpacing);
  ScalarType type = ScalarType::Int16;
  std::vector<float> samples;
  bool rescaled = false;
  double slopeFirst = 1.0, interceptFirst = 0.0;
  ProgressTask task(progress, "DICOM slices", slices.size());
  for (size_t s = 0; s < slices.size(); ++s, task.advance()) {
    const std::string& file = slices[s].file;
    gdcm::ImageReader reader;
    reader.SetFileName(file.c_str());
    if (!reader.Read()) HYB_THROW(IoError, file, ": not a readable DICOM image");
    const gdcm::Image& image = reader.GetImage();
    const gdcm::PixelFormat& pf = image.GetPixelFormat();
    if (pf.GetSamplesPerPixel() != 1)
      HYB_THROW(IoError, file, ": ", pf.GetSamplesPerPixel(), " samples per pixel (expected 1, greyscale)");
    if (image.GetNumberOfDimensions() == 3 && image.GetDimension(2) > 1)
      HYB_THROW(IoError, file, ": multi-frame images are not supported (expected one slice per file)");
    const glm::ivec2 size(int(image.GetDimension(0)), int(image.GetDimension(1)));
    ScalarType sliceType;
    switch (pf.GetScalarType()) {
      case gdcm::PixelFormat::UINT8: sliceType = ScalarType::UInt8; break;
      case gdcm::PixelFormat::INT8: sliceType = ScalarType::Int8; break;
      case gdcm::PixelFormat::UINT16: sliceType = ScalarType::UInt16; break;
      case gdcm::PixelFormat::INT16: sliceType = ScalarType::Int16; break;
      case gdcm::PixelFormat::UINT32: sliceType = ScalarType::UInt32; break;
      case gdcm::PixelFormat::INT32: sliceType = ScalarType::Int32; break;
      case gdcm::PixelFormat::FLOAT32: sliceType = ScalarType::Float32; break;
      case gdcm::PixelFormat::FLOAT64: sliceType = ScalarType::Float64; break;
      default: HYB_THROW(IoError, file, ": unsupported pixel format ", pf.GetScalarTypeAsString());
    }
    if (s == 0) {
      dims.x = size.x;
      dims.y = size.y;
      validateDims(dims, dir);
      const double* sp = image.GetSpacing();  // column spacing, row spacing (Pixel Spacing's second and first)
      spacing.x = sp[0];
      spacing.y = sp[1];
      type = sliceType;
      samples.resize(size_t(dims.x) * dims.y * dims.z);
      slopeFirst = image.GetSlope();
      interceptFirst = image.GetIntercept();
    } else if (size.x != dims.x || size.y != dims.y) {
      HYB_THROW(IoError, file, ": slice is ", size.x, "x", size.y, ", expected ", dims.x, "x", dims.y, " like the first slice");
    }
    const size_t sliceCount = size_t(dims.x) * dims.y;
    std::vector<char> buffer(image.GetBufferLength());
    if (buffer.size() < sliceCount * scalarSize(sliceType) || !image.GetBuffer(buffer.data()))
      HYB_THROW(IoError, file, ": pixel data missing or truncated");
    std::vector<float> slice = decodeSamples(reinterpret_cast<const uint8_t*>(buffer.data()), sliceCount, sliceType,
                                             std::endian::native == std::endian::big);
    const double slopeValue = image.GetSlope(), intercept = image.GetIntercept();
    if (slopeValue != 1.0 || intercept != 0.0) rescaled = true;
    for (size_t i = 0; i < sliceCount; ++i) samples[s * sliceCount + i] = float(slice[i] * slopeValue + intercept);
  }
  if (rescaled && type != ScalarType::Float32 && type != ScalarType::Float64) type = ScalarType::Int32;
  validateSpacing(spacing, dir);
  Volume v = placed(Volume(dims, spacing, type, std::move(samples), dir),
                    makePatientFrame(axes.direction, slices.front().position, dir), warnings);
  const std::string& first = slices.front().file;
  v.addInfo("modality", chosen->modality.empty() ? "(none)" : chosen->modality);
  v.addInfo("series", describe(*chosen) + (chosen->number.empty() ? "" : ", number " + chosen->number));
  if (const std::string pp = scan.value(first, kPatientPosition); !pp.empty()) v.addInfo("position", pp + " (Patient Position)");
  if (const std::string t = scan.value(first, kThickness); !t.empty()) v.addInfo("thickness", t + " mm (Slice Thickness; slices " +
                                                                                   detail::concat(zSpacing) + " mm apart)");
  v.addInfo("rescale", detail::concat("slope ", slopeFirst, ", intercept ", interceptFirst, rescaled ? " (applied)" : ""));
  return v;
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

Volume readInv3(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) HYB_THROW(IoError, path, ": file does not exist");
  std::unique_ptr<archive, int (*)(archive*)> ar(archive_read_new(), archive_read_free);
  archive_read_support_filter_all(ar.get());
  archive_read_support_format_tar(ar.get());
  if (archive_read_open_filename(ar.get(), path.c_str(), 1 << 16) != ARCHIVE_OK)
    HYB_THROW(IoError, path, ": not an InVesalius project (expected a gzip tar archive: ", archive_error_string(ar.get()), ")");
  // Keep main.plist and every .dat entry that may be the matrix; masks are skipped by name later.
  std::string mainPlist;
  std::map<std::string, std::vector<uint8_t>> blobs;
  archive_entry* entry = nullptr;
  int rc;
  while ((rc = archive_read_next_header(ar.get(), &entry)) == ARCHIVE_OK) {
    const std::string name = fs::path(archive_entry_pathname(entry)).filename().string();
    const bool wanted = name == "main.plist" || (name.size() > 4 && name.rfind("mask_", 0) != 0 &&
                                                 name.compare(name.size() - 4, 4, ".dat") == 0);
    if (!wanted) continue;
    std::vector<uint8_t> content;
    const la_int64_t declared = archive_entry_size(entry);
    if (declared > 0) content.reserve(size_t(declared));
    char buf[1 << 16];
    la_ssize_t n;
    while ((n = archive_read_data(ar.get(), buf, sizeof buf)) > 0) content.insert(content.end(), buf, buf + n);
    if (n < 0) HYB_THROW(IoError, path, ": truncated or corrupt archive entry '", name, "' (", archive_error_string(ar.get()), ")");
    if (name == "main.plist")
      mainPlist.assign(content.begin(), content.end());
    else
      blobs[name] = std::move(content);
  }
  if (rc != ARCHIVE_EOF) HYB_THROW(IoError, path, ": truncated or corrupt archive (", archive_error_string(ar.get()), ")");
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
  if (typeIt == kTypes.end()) HYB_THROW(IoError, path, ": matrix dtype '", dtype, "' unsupported");
  const std::string matrixName = fs::path(matrix->find("filename")->text).filename().string();
  const auto blob = blobs.find(matrixName);
  if (blob == blobs.end()) HYB_THROW(IoError, path, ": archive has no matrix file '", matrixName, "'");
  checkByteCount(path + ":" + matrixName, expectedBytes(dims, typeIt->second), blob->second.size(), dims, typeIt->second);
  std::vector<std::string> warnings;
  const PatientFrame frame = inv3Frame(plist, dims, spacing, path, &warnings);
  Volume v = placed(Volume(dims, spacing, typeIt->second,
                           decodeSamples(blob->second.data(), size_t(dims.x) * dims.y * dims.z, typeIt->second, false), path),
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
  const std::vector<uint8_t> bytes = readFileBytes(path);
  if (layout.headerBytes > bytes.size())
    HYB_THROW(IoError, path, ": header of ", layout.headerBytes, " bytes is longer than the ", bytes.size(), "-byte file");
  const uint64_t expected = expectedBytes(layout.dims, layout.type);
  checkByteCount(path, expected, bytes.size() - layout.headerBytes, layout.dims, layout.type);
  const size_t count = size_t(layout.dims.x) * layout.dims.y * layout.dims.z;
  Volume v(layout.dims, layout.spacing, layout.type, decodeSamples(bytes.data() + layout.headerBytes, count, layout.type, layout.bigEndian),
           path);
  v.addWarning(path + ": raw samples carry no orientation: the grid's axes are taken as LPS with the origin at 0");
  return v;
}

Volume readVolume(const std::string& path, const RawLayout* raw, const std::string& series, const Progress* progress) {
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

}  // namespace hyb
