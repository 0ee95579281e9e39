// The volume reader for InVesalius 3 projects: a gzip tar holds main.plist (matrix shape, dtype, spacing) and the
// matrix as raw samples in C order (z, y, x), native (little-endian) byte order.
#include "volume/volume_io.h"

#include <archive.h>
#include <archive_entry.h>

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
#include "volume/plist.h"
#include "volume/reader_util.h"
#include "volume/text_reader.h"

namespace hyb {

namespace fs = std::filesystem;
using namespace detail;  // the readers' shared helpers

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

}  // namespace hyb
