// The volume reader for MetaImage (https://itk.org/Wiki/ITK/MetaIO/Documentation)
#include "volume/volume_io.h"

#include <algorithm>
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
#include "volume/patient_frame.h"
#include "volume/plane_source.h"
#include "volume/reader_util.h"
#include "volume/text_reader.h"

namespace hyb {

namespace fs = std::filesystem;
using namespace detail;  // the readers' shared helpers

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

namespace {

// A MetaImage header: the volume it describes and where its samples lie.
struct MetaImageLayout {
  Volume description;
  SampleData data;
};

MetaImageLayout parseMetaImage(const std::string& path) {
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
  return MetaImageLayout{placed(describedVolume(dims, spacing, type, path), frame, warnings),
                         SampleData{data.path(), dataStart, compressed ? 0 : headerSize, "HeaderSize", compressed, type, bigEndian}};
}

}  // namespace

Volume readMetaImage(const std::string& path) {
  const MetaImageLayout l = parseMetaImage(path);
  return filled(l.description, readSampleData(l.data, l.description.dims()), path);
}

std::unique_ptr<PlaneSource> detail::metaImagePlanes(const std::string& path) {
  MetaImageLayout l = parseMetaImage(path);
  if (!streams(l.data.type)) return nullptr;
  return streamedPlanes(l.data, std::move(l.description), path);
}

}  // namespace hyb
