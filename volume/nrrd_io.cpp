// The volume reader for NRRD (http://teem.sourceforge.net/nrrd/format.html)
#include "volume/volume_io.h"

#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <optional>
#include <filesystem>
#include <iomanip>
#include <sstream>

#include "volume/core/file_util.h"
#include "volume/core/memory_limit.h"
#include "volume/inflate.h"
#include "volume/patient_frame.h"
#include "volume/plane_source.h"
#include "volume/reader_util.h"
#include "volume/text_reader.h"

namespace hyb {

namespace fs = std::filesystem;
using namespace detail;  // the readers' shared helpers

namespace {

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

namespace {

// A NRRD header: the volume it describes and where its samples lie.
struct NrrdLayout {
  Volume description;
  SampleData data;
  std::string encoding;  // raw, gzip or ascii (and their synonyms)
};

NrrdLayout parseNrrd(const std::string& path) {
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

  const bool compressed = encoding == "gzip" || encoding == "gz";
  if (encoding != "raw" && !compressed && encoding != "ascii" && encoding != "text" && encoding != "txt")
    HYB_THROW(IoError, path, ": encoding ", quotedExcerpt(encoding), " unsupported (expected raw, gzip or ascii)");
  return NrrdLayout{placed(describedVolume(dims, spacing, type, path), frame, warnings),
                    SampleData{data.path(), dataStart, byteSkip, "byte skip", compressed, type, endian == "big"}, encoding};
}

}  // namespace

Volume readNrrd(const std::string& path) {
  const NrrdLayout l = parseNrrd(path);
  const glm::ivec3 dims = l.description.dims();
  const bool ascii = l.encoding != "raw" && !l.data.compressed;
  return filled(l.description, ascii ? readAsciiSamples(InputFile(l.data.path), l.data.offset, dims, l.data.type) : readSampleData(l.data, dims),
                path);
}

void writeNrrd(const Volume& volume, const std::string& path) {
  const char* type = "float";
  switch (volume.storedType()) {
    case ScalarType::UInt8: type = "uchar"; break;
    case ScalarType::Int8: type = "signed char"; break;
    case ScalarType::UInt16: type = "ushort"; break;
    case ScalarType::Int16: type = "short"; break;
    default: break;
  }
  std::ostringstream h;
  h << std::setprecision(17);
  auto vec = [&h](const glm::dvec3& v) { h << '(' << v.x << ',' << v.y << ',' << v.z << ')'; };
  const glm::ivec3 d = volume.dims();
  h << "NRRD0004\ntype: " << type << "\ndimension: 3\nspace: left-posterior-superior\nsizes: " << d.x << ' ' << d.y << ' ' << d.z
    << "\nspace directions: ";
  for (int a = 0; a < 3; ++a) {
    vec(volume.frame().direction[a] * volume.spacing()[a]);
    h << (a < 2 ? " " : "\n");
  }
  h << "kinds: domain domain domain\nspace origin: ";
  vec(volume.frame().origin);
  h << "\nendian: " << (std::endian::native == std::endian::little ? "little" : "big") << "\nencoding: raw\n\n";
  const std::string header = h.str();
  writeFileAtomically(path, [&](std::ostream& out) {
    out.write(header.data(), std::streamsize(header.size()));
    volume.visitSamples([&](const auto* samples) {
      out.write(reinterpret_cast<const char*>(samples), std::streamsize(volume.voxelCount() * sizeof(*samples)));
    });
  });
}

std::unique_ptr<PlaneSource> detail::nrrdPlanes(const std::string& path) {
  NrrdLayout l = parseNrrd(path);
  if (l.encoding != "raw" && !l.data.compressed) return nullptr;
  if (!streams(l.data.type)) return nullptr;
  return streamedPlanes(l.data, std::move(l.description), path);
}

}  // namespace hyb
