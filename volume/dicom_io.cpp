// DICOM series through GDCM, behind a firewall: GDCM asserts (aborting the process) on some
// malformed files and prints to the terminal, so every file is checked here first (its file meta
// information byte by byte, then the pixel module's tags and the pixel data's length) and GDCM's
// output is captured; what GDCM still refuses becomes one line naming the file and the slice.
// A series is read whole (readDicomSeries) or slice by slice (detail::dicomPlanes), by the same
// per-slice steps and checks.
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmStringFilter.h>
#include <gdcmTrace.h>
#include <sys/stat.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <type_traits>
#include <variant>

#include "volume/core/file_util.h"
#include "volume/core/memory_limit.h"
#include "volume/dicom_scan.h"
#include "volume/plane_source.h"
#include "volume/plane_stack.h"
#include "volume/reader_util.h"
#include "volume/volume_io.h"

namespace hyb {

namespace fs = std::filesystem;
using detail::catalogDicom;
using detail::decodeSamples;
using detail::describeSeries;
using detail::DicomCatalog;
using detail::DicomFrame;
using detail::DicomInstance;
using detail::placed;
using detail::trim;

namespace {

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

uint16_t le16(const uint8_t* p) { return uint16_t(p[0] | p[1] << 8); }
uint32_t le32(const uint8_t* p) { return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24; }

// ---------------------------------------------------------------------------------------------
// Pixel module, checked before GDCM decodes it: GDCM asserts on palette colour without its
// tables, 1-bit pixels, unused bits in 8- or 32-bit pixels, zero samples per pixel; a length that
// is not the image's lets a small file claim a huge slice.

const gdcm::Tag kRows(0x0028, 0x0010), kColumns(0x0028, 0x0011), kPixelData(0x7fe0, 0x0010), kSamplesPerPixel(0x0028, 0x0002), kPhotometric(0x0028, 0x0004), kFrames(0x0028, 0x0008),
    kBitsAllocated(0x0028, 0x0100), kBitsStored(0x0028, 0x0101), kHighBit(0x0028, 0x0102), kPixelRepresentation(0x0028, 0x0103);

// What one slice's pixel module declares.
struct PixelModule {
  int rows = 0, columns = 0, bitsAllocated = 0, frames = 1;
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

// Checks what GDCM needs to decode @p file (its transfer syntax @p syntax) without asserting; @p where
// names it and its slice.
PixelModule checkPixelModule(const InputFile& file, const std::string& syntax, const std::string& where) {
  detail::checkTransferSyntax(syntax, where);
  gdcm::Reader reader;
  reader.SetFileName(file.path().c_str());
  // GDCM stops early only in an uncompressed stream; a deflated one is inflated whole.
  const bool deflated = syntax == detail::kDeflatedTransferSyntax;
  if (!(deflated ? reader.Read() : reader.ReadUpToTag(kPixelData, {kPixelData})))
    HYB_THROW(IoError, where, ": not a readable DICOM file (expected a DICOM image)");
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
  if (frames > (long(1) << 20)) refuse("Number of Frames", frames, "at most 1048576");
  PixelModule m;
  m.frames = int(std::max(1L, frames));
  const long rows = number(kRows), columns = number(kColumns);
  if (rows < 1 || rows > kMaxDim) refuse("Rows", rows, "1 to 32768");
  if (columns < 1 || columns > kMaxDim) refuse("Columns", columns, "1 to 32768");
  m.rows = int(rows);
  m.columns = int(columns);
  m.bitsAllocated = int(allocated);
  // The pixel data's length must be the image's (odd lengths padded by one byte, PS3.5 7.1.1).
  const gdcm::TransferSyntax& ts = reader.GetFile().GetHeader().GetDataSetTransferSyntax();
  if (ts == gdcm::TransferSyntax::DeflatedExplicitVRLittleEndian) return m;  // positions are in the inflated stream
  const uint64_t expected = uint64_t(rows) * uint64_t(columns) * uint64_t(allocated / 8) * uint64_t(m.frames);
  const int64_t length = pixelDataLength(file, reader.GetStreamCurrentPosition(), ts);
  if (length < 0) HYB_THROW(IoError, where, ": no Pixel Data (expected a DICOM image)");
  if (length == 0xffffffff) {
    if (!ts.IsEncapsulated()) HYB_THROW(IoError, where, ": Pixel Data of undefined length in an uncompressed transfer syntax");
    return m;
  }
  if (uint64_t(length) != expected && uint64_t(length) != expected + (expected & 1))
    HYB_THROW(IoError, where, ": Pixel Data holds ", length, " bytes (expected ", expected, " for ", m.frames > 1 ? detail::concat(m.frames, " frames of ") : "",
              columns, "x", rows, " pixels of ", allocated, " bits)");
  if (reader.GetStreamCurrentPosition() + uint64_t(length) > file.size())
    HYB_THROW(IoError, where, ": Pixel Data of ", length, " bytes runs past the end of the file (expected ", expected, " bytes in the file)");
  return m;
}


// A series chosen in a folder, its geometry checked and its planes ordered: what the whole
// reader and the streamed planes share.
struct SeriesLayout {
  std::string dir;
  DicomSeriesInfo chosen;
  std::vector<std::string> warnings;
  std::vector<DicomFrame> slices;  // ordered along the normal
  PlaneStack stack;                // their geometry
  StackGrid grid;                  // the orthogonal grid they are drawn on
  std::string patientPosition, thickness;
};

// One plane named for messages: its file, its frame in a multi-frame file, its place in the series.
std::string sliceWhere(const SeriesLayout& l, size_t s) {
  const DicomFrame& f = l.slices[s];
  return detail::concat(f.file, f.frame >= 0 ? detail::concat(" (frame ", f.frame + 1, ")") : "", " (slice ", s + 1, " of ", l.slices.size(), ")");
}

// Orders and checks the planes of the series @p seriesUid of @p dir's catalog (the default when empty).
SeriesLayout seriesLayout(const std::string& dir, const std::string& seriesUid, const Progress* progress, bool recursive) {
  silenceGdcm();
  const DicomCatalog catalog = catalogDicom(dir, recursive, progress);
  SeriesLayout l;
  l.dir = dir;
  std::string listing;
  std::set<std::string> studies;
  for (const DicomSeriesInfo& s : catalog.series) {
    listing += (listing.empty() ? "" : "; ") + describeSeries(s);
    studies.insert(s.studyUid);
  }
  const DicomSeriesInfo* chosen = &catalog.series.front();
  if (!seriesUid.empty()) {
    auto it = std::find_if(catalog.series.begin(), catalog.series.end(), [&](const DicomSeriesInfo& s) { return s.uid == seriesUid; });
    // A Series Number (the listing's #N) stands for its series when no other has that number.
    if (it == catalog.series.end() && seriesUid.find_first_not_of("0123456789") == std::string::npos) {
      const auto numbered = [&](const DicomSeriesInfo& s) { return trim(s.number) == seriesUid; };
      it = std::find_if(catalog.series.begin(), catalog.series.end(), numbered);
      if (std::count_if(catalog.series.begin(), catalog.series.end(), numbered) > 1)
        HYB_THROW(ValueError, "--series ", seriesUid, ": several series in ", dir, " are numbered ", seriesUid, " (expected a UID: ", listing, ")");
    }
    if (it == catalog.series.end()) HYB_THROW(ValueError, "--series ", quotedExcerpt(seriesUid, detail::kUidChars), ": no such series in ", dir, " (it holds ", listing, ")");
    chosen = &*it;
  } else if (catalog.series.size() > 1) {
    l.warnings.push_back(detail::concat(dir, ": ", catalog.series.size(), " series", studies.size() > 1 ? detail::concat(" in ", studies.size(), " studies") : "",
                                        "; reading the largest", chosen->localizer ? "" : chosen->axial ? " axial one that is not a localizer" : " that is not a localizer",
                                        ", ", describeSeries(*chosen), " (choose another by its UID, --series or Python's open(series=...): ", listing, ")"));
  }
  l.chosen = *chosen;
  const std::vector<DicomInstance>& instances = catalog.instances.at(chosen->uid);
  // A damaged file beside the series' images may be one of them: refused; one elsewhere is named.
  std::set<fs::path> folders;
  for (const DicomInstance& in : instances) folders.insert(fs::path(in.file).parent_path());
  for (const auto& [file, message] : catalog.damaged) {
    if (!folders.count(fs::path(file).parent_path())) {
      l.warnings.push_back(message + " (skipped: not in the folder of the series read)");
      continue;
    }
    (void)detail::checkDicomFile(InputFile(file));  // its own words where GDCM's guard has them
    throw IoError(message);
  }

  // The planes: every frame of every image; localizer images among others are left out.
  size_t localizers = 0;
  for (const DicomInstance& in : instances)
    for (const DicomFrame& f : in.planes) {
      if (f.localizer && !chosen->localizer) ++localizers;
      else l.slices.push_back(f);
    }
  if (localizers)
    l.warnings.push_back(detail::concat(dir, ": ", localizers, " localizer image", localizers == 1 ? "" : "s", " of series ", quotedExcerpt(chosen->uid, detail::kUidChars), " left out"));
  const DicomInstance* first = nullptr;
  for (const DicomInstance& in : instances) {
    if (std::none_of(l.slices.begin(), l.slices.end(), [&](const DicomFrame& f) { return f.file == in.file; })) continue;
    detail::checkTransferSyntax(in.transferSyntax, in.file);
    if (!in.defect.empty()) HYB_THROW(IoError, in.file, ": ", in.defect);
    if (!first) first = &in;
    if (in.columns != first->columns || in.rows != first->rows)
      HYB_THROW(IoError, dir, ": series ", quotedExcerpt(chosen->uid, detail::kUidChars), " holds images of two sizes, ", first->columns, "x", first->rows, " (", first->file,
                ") and ", in.columns, "x", in.rows, " (", in.file, "; expected one size for a volume)");
    if (glm::length(in.pixelSpacing - first->pixelSpacing) > 1e-4 * std::max(1.0, glm::length(first->pixelSpacing)))
      HYB_THROW(IoError, dir, ": series ", quotedExcerpt(chosen->uid, detail::kUidChars), " holds images of two pixel spacings, ", first->pixelSpacing.x, " x ",
                first->pixelSpacing.y, " mm (", first->file, ") and ", in.pixelSpacing.x, " x ", in.pixelSpacing.y, " mm (", in.file,
                "; expected one spacing for a volume)");
  }

  // Geometry (DICOM PS3.3 C.7.6.2): the rows' and columns' directions from Image Orientation
  // (Patient), the planes ordered by Image Position (Patient) along their normal.
  const DicomFrame& top = l.slices.front();
  const std::vector<double>& iop = top.orientation;
  glm::dmat3 direction(1.0);
  const bool oriented = iop.size() == 6;
  if (oriented) {
    direction[0] = glm::dvec3(iop[0], iop[1], iop[2]);
    direction[1] = glm::dvec3(iop[3], iop[4], iop[5]);
    direction[2] = glm::cross(direction[0], direction[1]);
  } else if (l.slices.size() > 1) {
    HYB_THROW(IoError, top.file, ": Image Orientation (Patient) missing or malformed (expected six cosines to order the slices)");
  } else {
    l.warnings.push_back(top.file + ": no Image Orientation (Patient): the slice's axes are taken as LPS");
  }
  const PatientFrame axes = makePatientFrame(direction, glm::dvec3(0.0), top.file + " (Image Orientation (Patient))");
  for (const DicomFrame& f : l.slices) {
    if (!f.hasPosition && l.slices.size() > 1) {
      if (f.frame >= 0)
        HYB_THROW(IoError, f.file, " (frame ", f.frame + 1, "): Image Position (Patient) of its Plane Position Sequence (0020,9113) missing or malformed (expected three numbers in the frame's Per-frame Functional Groups item, or the Shared one, to order the frames)");
      HYB_THROW(IoError, f.file, ": Image Position (Patient) missing or malformed (expected three numbers to order the slices)");
    }
    bool same = !oriented || f.orientation.size() == 6;
    for (size_t c = 0; oriented && same && c < 6; ++c) same = std::abs(f.orientation[c] - iop[c]) <= 1e-4;
    if (!same)
      HYB_THROW(IoError, f.file, ": Image Orientation (Patient) differs from ", top.file, "'s (expected one orientation for the series: mixed orientations are not one volume)");
  }
  std::stable_sort(l.slices.begin(), l.slices.end(), [&](const DicomFrame& a, const DicomFrame& b) {
    return glm::dot(a.position, axes.direction[2]) < glm::dot(b.position, axes.direction[2]);
  });
  // The same image twice (a copy beside the original, as exports leave them): one is read.
  std::vector<DicomFrame> kept;
  size_t copies = 0;
  for (DicomFrame& f : l.slices) {
    const DicomFrame* last = kept.empty() ? nullptr : &kept.back();
    if (last && !f.sopInstance.empty() && f.sopInstance == last->sopInstance && f.frame == last->frame && f.position == last->position) {
      if (copies++ == 0)
        l.warnings.push_back(detail::concat(f.file, " is a copy of ", last->file, " (the same SOP Instance UID and position): left out"));
      continue;
    }
    kept.push_back(std::move(f));
  }
  if (copies > 1) l.warnings.back() += detail::concat(", and ", copies - 1, " more copies");
  l.slices = std::move(kept);
  glm::dvec2 spacing = first->pixelSpacing;
  if (spacing.x <= 0.0 || spacing.y <= 0.0) {
    spacing = glm::dvec2(1.0);
    l.warnings.push_back(first->file + ": no Pixel Spacing (0028,0030): 1 mm between pixels assumed");
  }
  l.patientPosition = first->patientPosition;
  l.thickness = first->thickness;
  PlaneStack& stack = l.stack;
  stack.axes = axes.direction;
  stack.pixelSpacing = spacing;
  stack.size = {first->columns, first->rows};
  for (size_t s = 0; s < l.slices.size(); ++s) {
    stack.origins.push_back(l.slices[s].position);
    stack.names.push_back(sliceWhere(l, s));
  }
  if (const double t = std::strtod(l.thickness.c_str(), nullptr); std::isfinite(t) && t > 0.0) stack.singleSpacing = t;
  try {
    l.grid = stackGrid(stack, dir, first->tilt.empty() ? "" : "Gantry/Detector Tilt (0018,1120) says " + first->tilt + " degrees");
  } catch (const IoError& e) {
    // A slice the scan skipped (no pixel data, not DICOM, empty) is often the one the stack misses.
    std::string beside;
    size_t named = 0;
    for (const auto& [file, reason] : catalog.skippedFiles)
      if (folders.count(fs::path(file).parent_path()) && named++ < 3) beside += detail::concat(beside.empty() ? "" : ", ", file, ": ", reason);
    if (beside.empty()) throw;
    throw IoError(detail::concat(e.what(), "; skipped in the series' folder: ", beside, named > 3 ? detail::concat(" and ", named - 3, " more") : ""));
  }
  return l;
}

// Refuses a slice whose Columns and Rows (@p module) are not the first slice's (@p dims).
void checkSliceSize(const std::string& where, const PixelModule& module, const glm::ivec3& dims) {
  if (module.columns != dims.x || module.rows != dims.y)
    HYB_THROW(IoError, where, ": slice is ", module.columns, "x", module.rows, ", expected ", dims.x, "x", dims.y, " like the first slice");
}

// One image as GDCM reads it, its pixels not decoded yet.
struct SliceImage {
  gdcm::ImageReader reader;
  ScalarType type = ScalarType::Int16;  // of the decoded pixels
  glm::ivec2 size{0};
  int frames = 1;
  // The values GDCM can decode: the type's range, or Bits Stored's where GDCM clears the unused bits
  // of 16-bit pixels (ImageCodec::DoOverlayCleanup, run by its raw and RLE decoders with the
  // header's pixel format; the JPEG family's decoders may take another from the stream).
  double lo = 0.0, hi = 0.0;
};

// Reads image @p file (its pixel module @p module checked) with GDCM, checking what it decodes to.
void readSliceImage(const std::string& file, const std::string& where, const PixelModule& module, SliceImage* out) {
  gdcm::ImageReader& reader = out->reader;
  reader.SetFileName(file.c_str());
  if (!reader.Read()) HYB_THROW(IoError, where, ": not a readable DICOM image (GDCM refused its data set; expected a well-formed DICOM file)");
  const gdcm::Image& image = reader.GetImage();
  const gdcm::PixelFormat& pf = image.GetPixelFormat();
  if (pf.GetSamplesPerPixel() != 1)
    HYB_THROW(IoError, where, ": ", pf.GetSamplesPerPixel(), " samples per pixel (expected 1, greyscale)");
  out->frames = image.GetNumberOfDimensions() == 3 ? int(image.GetDimension(2)) : 1;
  if (out->frames != module.frames)
    HYB_THROW(IoError, where, ": GDCM decodes ", out->frames, " frames (expected the ", module.frames, " of Number of Frames)");
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
  const bool isFloat = out->type == ScalarType::Float32 || out->type == ScalarType::Float64;
  const bool isSigned = out->type == ScalarType::Int8 || out->type == ScalarType::Int16 || out->type == ScalarType::Int32;
  int bits = int(scalarSize(out->type)) * 8;
  const gdcm::TransferSyntax& ts = image.GetTransferSyntax();
  if (pf.GetBitsAllocated() == 16 && bits == 16 && (!ts.IsEncapsulated() || ts == gdcm::TransferSyntax::RLELossless)) bits = pf.GetBitsStored();
  out->lo = isFloat ? -std::numeric_limits<double>::infinity() : isSigned ? -std::ldexp(1.0, bits - 1) : 0.0;
  out->hi = isFloat ? std::numeric_limits<double>::infinity() : std::ldexp(1.0, isSigned ? bits - 1 : bits) - 1.0;
}

// What one plane's header decided when the series was opened.
struct SliceHeader {
  ScalarType type;
  double slope, intercept;
  double lo, hi;  // the pixel values GDCM can decode
};

// Samples are held as float at widest: a rescale whose values leave its range would make infinities.
void checkRescale(const std::string& where, const SliceHeader& h) {
  const bool isFloat = !std::isfinite(h.lo);
  const double a = isFloat ? 0.0 : h.lo * h.slope + h.intercept, b = isFloat ? 0.0 : h.hi * h.slope + h.intercept;
  if (!std::isfinite(h.slope) || !std::isfinite(h.intercept) || !std::isfinite(a) || !std::isfinite(b) ||
      std::max(std::abs(a), std::abs(b)) > double(std::numeric_limits<float>::max()))
    HYB_THROW(IoError, where, ": Rescale Slope (0028,1053) ", h.slope, " and Rescale Intercept (0028,1052) ", h.intercept, " take the pixel values ",
              h.lo, "..", h.hi, " beyond the float range (expected rescaled values within +-3.4e38)");
}

// The @p image's decoded pixels (every frame) in the type a volume holds them in (decodeSamples).
SampleArray imageSamples(const SliceImage& image, const std::string& where) {
  const size_t count = size_t(image.size.x) * size_t(image.size.y) * size_t(image.frames);
  const gdcm::Image& im = image.reader.GetImage();
  if (im.GetBufferLength() != count * scalarSize(image.type))
    HYB_THROW(IoError, where, ": decoded pixel data holds ", im.GetBufferLength(), " bytes (expected ", count * scalarSize(image.type), ")");
  std::vector<char> buffer(im.GetBufferLength());
  if (!im.GetBuffer(buffer.data())) HYB_THROW(IoError, where, ": pixel data missing or truncated");
  return decodeSamples(reinterpret_cast<const uint8_t*>(buffer.data()), count, image.type, std::endian::native == std::endian::big);
}

// Plane @p frame of @p all (planes of @p planeSize samples).
SampleArray framePlane(const SampleArray& all, int frame, size_t planeSize) {
  return std::visit(
      [&](const auto& v) -> SampleArray {
        using T = typename std::remove_reference_t<decltype(v)>::value_type;
        const auto from = v.begin() + ptrdiff_t(size_t(std::max(frame, 0)) * planeSize);
        return std::vector<T>(from, from + ptrdiff_t(planeSize));
      },
      all);
}

// What GDCM needs to decode plane @p s's file without asserting, checked (the file may have changed
// since the series was opened), with its size the series'.
PixelModule checkedModule(const SeriesLayout& l, size_t s) {
  const std::string where = sliceWhere(l, s);
  const InputFile file(l.slices[s].file);
  const std::optional<std::string> syntax = detail::checkDicomFile(file);
  if (!syntax) HYB_THROW(IoError, where, ": not a DICOM file (expected the slice the series was opened with)");
  const PixelModule module = checkPixelModule(file, *syntax, where);
  checkSliceSize(where, module, glm::ivec3(l.stack.size, 0));
  return module;
}

// Decodes the planes of a series one at a time: an image file for each single-frame plane; a
// multi-frame image decoded whole once (GDCM decodes a file at a time) while its frames are read.
class PlaneDecoder {
 public:
  explicit PlaneDecoder(const SeriesLayout& l) : mLayout(l) {}
  /// Plane @p s's header (its pixel type, the values it can decode, its rescale as the file holds it
  /// now), every check made on its file first; its pixels are not decoded.
  SliceHeader header(size_t s) {
    open(s, false);
    return mHeader;
  }
  /// Plane @p s's pixels (not rescaled), and its header.
  SampleArray decode(size_t s, SliceHeader* header) {
    const DicomFrame& f = mLayout.slices[s];
    open(s, true);
    *header = mHeader;
    if (f.frame < 0) return std::move(mAll);
    return framePlane(mAll, f.frame, size_t(mLayout.stack.size.x) * size_t(mLayout.stack.size.y));
  }

 private:
  // Reads plane @p s's image (a multi-frame image once for all its frames) and, when @p pixels, decodes it.
  void open(size_t s, bool pixels) {
    const DicomFrame& f = mLayout.slices[s];
    const std::string where = sliceWhere(mLayout, s);
    if (f.frame < 0 || f.file != mFile || (pixels && !mDecoded)) {
      const PixelModule module = checkedModule(mLayout, s);
      SliceImage image;
      readSliceImage(f.file, where, module, &image);
      mHeader = {image.type, f.slope, f.intercept, image.lo, image.hi};
      if (f.frame < 0) {  // the rescale the file holds now: it may have been rewritten since the series was opened
        const gdcm::DataSet& ds = image.reader.GetFile().GetDataSet();
        gdcm::StringFilter sf;
        sf.SetFile(image.reader.GetFile());
        auto value = [&](uint16_t element, double otherwise) {
          const gdcm::Tag t(0x0028, element);
          if (!ds.FindDataElement(t) || ds.GetDataElement(t).IsEmpty()) return otherwise;
          const std::string text = trim(sf.ToString(t));
          char* end = nullptr;
          const double v = std::strtod(text.c_str(), &end);
          return end == text.c_str() ? otherwise : v;
        };
        mHeader.slope = value(0x1053, 1.0);
        mHeader.intercept = value(0x1052, 0.0);
      }
      mFrames = image.frames;
      mDecoded = pixels;
      if (pixels) mAll = imageSamples(image, where);  // the reader and its copy of the pixel data go with `image`
      mFile = f.frame < 0 ? std::string() : f.file;  // single-frame images are not kept
    } else {
      mHeader.slope = f.slope;
      mHeader.intercept = f.intercept;
    }
    checkRescale(where, mHeader);
    if (f.frame >= mFrames) HYB_THROW(IoError, where, ": holds ", mFrames, " frames (expected frame ", f.frame + 1, ")");
  }

  const SeriesLayout& mLayout;
  std::string mFile;     // the multi-frame image read last
  bool mDecoded = false;  // whether its pixels are in mAll
  SliceHeader mHeader{};
  int mFrames = 1;
  SampleArray mAll;
};

// The series' frame, info and warnings on @p v (the whole volume or its description).
Volume placedSeries(Volume v, const SeriesLayout& l, double slopeFirst, double interceptFirst, bool rescaled) {
  v = placed(std::move(v), makePatientFrame(l.stack.axes, l.stack.origins.front(), l.dir), l.warnings);
  v.addInfo("modality", l.chosen.modality.empty() ? "(none)" : l.chosen.modality);
  v.addInfo("series", describeSeries(l.chosen) + (l.chosen.number.empty() ? "" : ", number " + l.chosen.number));
  if (!l.patientPosition.empty()) v.addInfo("position", l.patientPosition + " (Patient Position)");
  if (!l.thickness.empty())
    v.addInfo("thickness", l.thickness + " mm (Slice Thickness; slices " + detail::concat(l.grid.spacing.z) + " mm apart" +
                               (l.grid.resampled ? " after resampling" : "") + ")");
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

// The planes of a DICOM series in the order of its stack, each decoded when it is read: the file
// is checked as the whole reader checks it (it may have changed since the series was opened) and
// its samples rescaled as readDicomSeries rescales them, into the stored type its headers decided.
class DicomPlanes final : public PlaneSource {
 public:
  DicomPlanes(Volume description, SeriesLayout layout, std::vector<SliceHeader> headers)
      : PlaneSource(std::move(description), layout.dir), mLayout(std::move(layout)), mHeaders(std::move(headers)), mDecoder(mLayout) {}
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
    const std::string where = sliceWhere(mLayout, z);
    const SliceHeader& h = mHeaders[z];
    SliceHeader now;
    const SampleArray slice = mDecoder.decode(z, &now);
    if (now.type != h.type || now.slope != h.slope || now.intercept != h.intercept)
      HYB_THROW(IoError, where, ": changed since the series was opened: ", scalarName(now.type), " pixels, rescale slope ", now.slope, ", intercept ",
                now.intercept, " (expected ", scalarName(h.type), ", slope ", h.slope, ", intercept ", h.intercept, ")");
    if (sampleCount(mPlane) != planeSize() || hyb::storedType(mPlane) != storedType()) mPlane = detail::allocateSamples(storedType(), planeSize());
    detail::rescaleSamples(&mPlane, 0, slice, h.slope, h.intercept);
    if (hyb::storedType(mPlane) != storedType())  // (GDCM decoded values outside the range its header gives)
      HYB_THROW(IoError, where, ": decoded values that ", scalarName(storedType()), " samples do not hold (expected values within the range of "
                "its Bits Stored and Pixel Representation, rescaled)");
  }

  SeriesLayout mLayout;
  std::vector<SliceHeader> mHeaders;  // per plane
  PlaneDecoder mDecoder;
  int mNext = 0;
  SampleArray mPlane;  // the plane last decoded, rescaled
};

// The planes of the series in its stack's order, not resampled.
std::unique_ptr<PlaneSource> stackPlanes(SeriesLayout layout) {
  const size_t n = layout.slices.size();
  // Every plane's header, checked as the whole reader checks it; the stored type is decided by the
  // whole reader's rule (rescaleTarget of the first plane, widened to float when a rescaled value
  // does not fit) applied to the range each header allows, or where that range does not fit, to
  // the values, decoded once more a plane at a time.
  const glm::ivec3 dims(layout.stack.size, int(n));
  validateDims(dims, layout.dir);
  ScalarType stored = ScalarType::Int16;
  bool rescaled = false, byValues = false;
  std::vector<SliceHeader> headers(n);
  {
    PlaneDecoder decoder(layout);
    for (size_t s = 0; s < n; ++s) {
      headers[s] = decoder.header(s);
      const SliceHeader& h = headers[s];
      if (s == 0) stored = storedType(detail::rescaleTarget(h.type, h.slope, h.intercept, 0));
      byValues = byValues || !holdsAll(stored, h.lo, h.hi, h.slope, h.intercept);
      if (h.slope != 1.0 || h.intercept != 0.0) rescaled = true;
    }
  }
  // The values decide (an int16 CT with 16 bits stored and an intercept, GE's): rescaled as the whole
  // reader rescales them, a plane at a time, float as soon as one is not of the stored type.
  if (byValues) {
    PlaneDecoder decoder(layout);
    for (size_t s = 0; s < n; ++s) {
      SliceHeader h;
      const SampleArray pixels = decoder.decode(s, &h);
      SampleArray plane = detail::allocateSamples(stored, size_t(dims.x) * size_t(dims.y));
      detail::rescaleSamples(&plane, 0, pixels, h.slope, h.intercept);
      if (storedType(plane) != stored) {
        stored = ScalarType::Float32;
        break;
      }
    }
  }
  // (The spacing along the normal of a stack to be resampled is its grid's, which replaces it.)
  const glm::dvec3 spacing(layout.stack.pixelSpacing, layout.grid.resampled ? 1.0 : layout.grid.spacing.z);
  Volume description = placedSeries(Volume::withoutSamples({dims, spacing, headers.front().type, stored}, 0.0f, 0.0f, layout.dir), layout,
                                    headers.front().slope, headers.front().intercept, rescaled);
  return std::make_unique<DicomPlanes>(std::move(description), std::move(layout), std::move(headers));
}

}  // namespace

DicomListing listDicomSeries(const std::string& dir, const Progress* progress, bool recursive) {
  const DicomCatalog c = catalogDicom(dir, recursive, progress);
  DicomListing out;
  out.dir = dir;
  out.series = c.series;
  out.files = c.files;
  out.skipped = c.skipped;
  out.dicomdir = c.dicomdir;
  return out;
}

Volume readDicomSeries(const std::string& dir, const std::string& seriesUid, const Progress* progress, bool recursive) {
  SeriesLayout layout = seriesLayout(dir, seriesUid, progress, recursive);
  const StackGrid grid = layout.grid;
  const size_t n = layout.slices.size();
  glm::ivec3 dims(layout.stack.size, int(n));
  validateDims(dims, dir);
  ScalarType type = ScalarType::Int16;
  SampleArray samples;
  bool rescaled = false;
  double slopeFirst = 1.0, interceptFirst = 0.0;
  ProgressTask task(progress, "DICOM slices", n);
  PlaneDecoder decoder(layout);
  const size_t planeSize = size_t(dims.x) * size_t(dims.y);
  for (size_t s = 0; s < n; ++s, task.advance()) {
    if (s == 0) {  // the whole series is allocated up front (float at worst): what its first slice claims must fit
      checkedModule(layout, 0);
      checkMemory(sliceWhere(layout, 0), planeSize * (n * sizeof(float) + 2 * sizeof(double)),
                  detail::concat(n, " slices of ", dims.x, "x", dims.y, " samples"));
    }
    SliceHeader h;
    const SampleArray slice = decoder.decode(s, &h);
    if (s == 0) {
      type = h.type;
      slopeFirst = h.slope;
      interceptFirst = h.intercept;
      samples = detail::rescaleTarget(type, slopeFirst, interceptFirst, planeSize * n);
    }
    if (h.slope != 1.0 || h.intercept != 0.0) rescaled = true;
    detail::rescaleSamples(&samples, s * planeSize, slice, h.slope, h.intercept);
  }
  const glm::dvec3 spacing(layout.stack.pixelSpacing, grid.resampled ? 1.0 : grid.spacing.z);
  validateSpacing(spacing, dir);
  Volume v = placedSeries(Volume(dims, spacing, type, std::move(samples), dir), layout, slopeFirst, interceptFirst, rescaled);
  if (!grid.resampled) return v;
  // Tilted or unevenly spaced: the stack read whole, drawn on its orthogonal grid.
  return detail::readAllPlanes(*resampledPlanes(detail::planesOwning(std::make_shared<const Volume>(std::move(v)), dir), grid));
}

namespace detail {

std::unique_ptr<PlaneSource> dicomPlanes(const std::string& dir, const std::string& seriesUid, bool recursive) {
  SeriesLayout layout = seriesLayout(dir, seriesUid, nullptr, recursive);
  const StackGrid grid = layout.grid;
  return resampledPlanes(stackPlanes(std::move(layout)), grid);
}

}  // namespace detail

}  // namespace hyb
