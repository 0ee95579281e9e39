#include "volume/volume_io.h"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <string>

#include "volume/core/file_util.h"
#include "volume/dicom_scan.h"
#include "volume/dicomweb.h"
#include "volume/plane_source.h"
#include "volume/reader_util.h"
#include "volume/text_reader.h"

// The reader for each format lives in its own file: nrrd_io.cpp, metaimage_io.cpp, nifti_io.cpp,
// inv3_io.cpp, dicom_io.cpp; the raw reader and the choice by extension are here.
namespace hyb {

namespace fs = std::filesystem;
using detail::readRawSamples;

// ---------------------------------------------------------------------------------------------
// Raw

namespace {

// A raw file's volume without its samples, and where they lie.
Volume rawDescription(const std::string& path, const RawLayout& layout) {
  validateDims(layout.dims, "--raw-dims");
  validateSpacing(layout.spacing, "--raw-spacing");
  const InputFile file(path);
  if (layout.headerBytes > file.size())
    HYB_THROW(IoError, path, ": header of ", layout.headerBytes, " bytes is longer than the ", file.size(), "-byte file");
  Volume v = detail::describedVolume(layout.dims, layout.spacing, layout.type, path);
  v.addWarning(path + ": raw samples carry no orientation: the grid's axes are taken as LPS with the origin at 0");
  PatientFrame frame;
  frame.assumed = true;
  v.setFrame(frame);
  return v;
}

}  // namespace

Volume readRaw(const std::string& path, const RawLayout& layout) {
  const Volume description = rawDescription(path, layout);
  const InputFile file(path);
  return detail::filled(description, readRawSamples(file, {layout.headerBytes, 0, "header"}, layout.dims, layout.type, layout.bigEndian), path);
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

}  // namespace

const std::vector<VolumeFormatRow>& volumeFormats() {
  static const std::vector<VolumeFormatRow> kFormats = {
      {VolumeFormat::Nrrd, "NRRD", {".nrrd", ".nhdr"}, readNrrd, detail::nrrdPlanes},
      {VolumeFormat::MetaImage, "MetaImage", {".mhd", ".mha"}, readMetaImage, detail::metaImagePlanes},
      {VolumeFormat::Nifti, "NIfTI", {".nii", ".nii.gz", ".hdr"}, readNifti, detail::niftiPlanes},
      {VolumeFormat::Inv3, "InVesalius project", {".inv3"}, readInv3, nullptr}};
  return kFormats;
}

const VolumeFormatRow* volumeFormatRow(const std::string& path) {
  const std::string ext = fileExtension(path);
  for (const VolumeFormatRow& row : volumeFormats())
    if (std::find(row.extensions.begin(), row.extensions.end(), ext) != row.extensions.end()) return &row;
  return nullptr;
}

VolumeFormat volumeFormatOf(const std::string& path) {
  const VolumeFormatRow* row = volumeFormatRow(path);
  return row ? row->format : VolumeFormat::None;
}

std::string volumeExtensionsText() {
  std::string out;
  for (const VolumeFormatRow& row : volumeFormats())
    for (const std::string& e : row.extensions) out += (out.empty() ? "" : " ") + e;
  return out;
}

namespace {

// The writers, by extension.
struct VolumeWriterRow {
  const char* extension;
  void (*write)(const Volume&, const std::string&);
};
constexpr VolumeWriterRow kVolumeWriters[] = {{".nrrd", writeNrrd}, {".nii", writeNifti}, {".nii.gz", writeNifti}};

const VolumeWriterRow* volumeWriter(const std::string& path) {
  const std::string ext = fileExtension(path);
  for (const VolumeWriterRow& row : kVolumeWriters)
    if (ext == row.extension) return &row;
  return nullptr;
}

}  // namespace

std::string writableVolumeExtensionsText() {
  std::string out;
  for (const VolumeWriterRow& row : kVolumeWriters) {
    if (!out.empty()) out += ' ';
    out += row.extension;
  }
  return out;
}

bool writableVolume(const std::string& path) { return volumeWriter(path) != nullptr; }

void writeVolume(const Volume& volume, const std::string& path) {
  const VolumeWriterRow* row = volumeWriter(path);
  if (!row) HYB_THROW(IoError, path, ": no volume writer for '", fileExtension(path), "' (expected ", writableVolumeExtensionsText(), ")");
  row->write(volume, path);
}

std::optional<DicomFolder> dicomFolderOf(const std::string& path, const std::string& series) {
  std::error_code ec;
  if (isDicomWebUrl(path) || !fs::is_regular_file(path, ec) || volumeFormatRow(path)) return std::nullopt;
  const fs::path file(path);
  const std::string dir = file.has_parent_path() ? file.parent_path().string() : ".";
  std::string name = file.filename().string();
  std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return char(std::toupper(c)); });
  if (name == "DICOMDIR") return DicomFolder{dir, series};
  const std::optional<detail::DicomHeader> header = detail::readDicomHeader(path);
  if (!header || !header->pixelData) return std::nullopt;
  const std::string uid = header->data.text(detail::dicomTag(0x0020, 0x000e));
  if (uid.empty()) return std::nullopt;
  if (!series.empty() && series != uid)
    HYB_THROW(ValueError, "--series ", quotedExcerpt(series, detail::kUidChars), ": ", path, " is an image of series ", quotedExcerpt(uid, detail::kUidChars),
              " (expected its folder with --series, or the image alone)");
  return DicomFolder{dir, uid, false};
}

namespace {

// Refuses flags a DICOMweb series' address does not take: it names its series and carries its layout.
void checkDicomWebFlags(const std::string& path, const RawLayout* raw, const std::string& series) {
  if (raw) HYB_THROW(ValueError, redactUrl(path), ": a DICOMweb series carries its own layout (--raw-dims, --raw-type and --raw-spacing are for headerless raw data)");
  if (!series.empty()) HYB_THROW(ValueError, "--series is for DICOM directories (", redactUrl(path), " names its series in the address)");
}

Volume readByFormat(const std::string& path, const RawLayout* raw, const std::string& series, const Progress* progress) {
  if (isDicomWebUrl(path)) {
    checkDicomWebFlags(path, raw, series);
    return readDicomWebSeries(path, progress);
  }
  if (raw) return readRaw(path, *raw);
  std::error_code ec;
  if (!fs::exists(path, ec)) HYB_THROW(IoError, path, ": file does not exist");
  if (fs::is_directory(path, ec)) return readDicomSeries(path, series, progress);
  if (const std::optional<DicomFolder> folder = dicomFolderOf(path, series)) return readDicomSeries(folder->dir, folder->series, progress, folder->recursive);
  if (!series.empty()) HYB_THROW(ValueError, "--series needs a DICOM directory or DICOMDIR (", path, " is a file)");
  InputFile{path};  // what is not a regular file is refused here, whatever its name, before a reader opens it
  if (const VolumeFormatRow* row = volumeFormatRow(path)) return row->read(path);
  const std::string ext = fileExtension(path);
  if (ext == ".raw")
    HYB_THROW(ValueError, path, ": raw data needs --raw-dims X,Y,Z and --raw-type (and optionally --raw-spacing, --raw-endian)");
  if (ext == ".hoct")
    HYB_THROW(IoError, path, ": not a hybrid-octree scene file (expected one written by hybrid-octree build, starting with HYBOCT)");
  HYB_THROW(IoError, path, ": unknown volume format '", ext, "' (expected ", volumeExtensionsText(), ", a DICOM directory, or raw with --raw-dims)");
}

}  // namespace

namespace {

// Runs @p read with every reader error made one line, and running out of memory said by name.
template <class Read>
auto oneLineErrors(const std::string& path, const Read& read) {
  try {
    return read();
  } catch (const IoError& e) {
    throw IoError(oneLine(e.what()));
  } catch (const ValueError& e) {
    throw ValueError(oneLine(e.what()));
  } catch (const RuntimeError& e) {
    throw RuntimeError(oneLine(e.what()));
  } catch (const std::bad_alloc&) {
    HYB_THROW(RuntimeError, oneLine(redactUrl(path)), ": out of memory while reading (expected a volume that fits; lower the memory limit to refuse it early)");
  }
}

}  // namespace

Volume readVolume(const std::string& path, const RawLayout* raw, const std::string& series, const Progress* progress) {
  return oneLineErrors(path, [&] { return readByFormat(path, raw, series, progress); });
}

std::unique_ptr<PlaneSource> detail::openStreamedPlanes(const std::string& path, const RawLayout* raw, const std::string& series,
                                                        const Progress* progress) {
  return oneLineErrors(path, [&]() -> std::unique_ptr<PlaneSource> {
    std::error_code ec;
    if (isDicomWebUrl(path)) {
      checkDicomWebFlags(path, raw, series);
      return dicomWebPlanes(path, progress);
    }
    if (raw) {
      if (!streams(raw->type)) return nullptr;
      Volume description = rawDescription(path, *raw);
      return streamedPlanes(SampleData{path, raw->headerBytes, 0, "header", false, raw->type, raw->bigEndian}, std::move(description), path);
    }
    if (fs::is_directory(path, ec)) return dicomPlanes(path, series);
    if (const std::optional<DicomFolder> folder = dicomFolderOf(path, series)) return dicomPlanes(folder->dir, folder->series, folder->recursive);
    if (!series.empty()) return nullptr;  // readVolume says what is wrong
    InputFile{path};  // as readVolume: a FIFO or device is refused before any reader opens it
    const VolumeFormatRow* row = volumeFormatRow(path);
    return row && row->planes ? row->planes(path) : nullptr;  // (none: read whole by readVolume)
  });
}

}  // namespace hyb
