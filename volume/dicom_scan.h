// What a folder of DICOM files holds, read from the files' headers alone: a patient CD (its DICOMDIR's
// directory records: patient, study, series, image and the files they name), or a folder tree
// scanned recursively. Headers are parsed here, bounded by the file and by nesting, without GDCM
// (which asserts on malformed files and reads more than the tags needed): a 2,000-file tree is
// scanned in well under a second from the page cache. Decoding pixels stays in dicom_io.cpp.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "volume/core/file_util.h"
#include "volume/core/progress.h"
#include "volume/volume_io.h"

namespace hyb::detail {

/// A DICOM tag as one number, group in the high half: (0020,0032) is 0x00200032.
constexpr uint32_t dicomTag(uint16_t group, uint16_t element) { return uint32_t(group) << 16 | element; }

/// The elements of a data set read from a file's header: the values of the tags asked for (as
/// their bytes: text for string VRs, little-endian binary otherwise) and the items of the
/// sequences asked for, each a data set of its own.
class DicomDataSet {
 public:
  /// The value of @p tag trimmed of padding (spaces and NULs); empty when absent.
  std::string text(uint32_t tag) const;
  /// Backslash-separated decimal numbers (DS, IS); empty when absent or malformed.
  std::vector<double> numbers(uint32_t tag) const;
  /// An unsigned 16-bit value (US), or a decimal string (IS) holding one; none when absent.
  std::optional<long> integer(uint32_t tag) const;
  /// The items of sequence @p tag; null when absent.
  const std::vector<DicomDataSet>* items(uint32_t tag) const;
  bool has(uint32_t tag) const { return mValues.count(tag) || mItems.count(tag); }
  /// Sets @p tag's value (its bytes).
  void set(uint32_t tag, std::string value) { mValues[tag] = std::move(value); }

 private:
  friend class DicomHeaderParser;
  std::map<uint32_t, std::string> mValues;
  std::map<uint32_t, std::vector<DicomDataSet>> mItems;
  bool mBinaryUs = true;  // US values are binary (the data set's byte order made little-endian)
};

/// A DICOM file's header: its file meta information and its data set up to the pixel data.
struct DicomHeader {
  std::string transferSyntax;  ///< (0002,0010), or empty without meta information
  std::string mediaStorage;    ///< (0002,0002): the SOP class the file holds
  DicomDataSet data;
  bool pixelData = false;      ///< whether (7FE0,0010) is there
};

/// Reads @p path's header. None when the file is not DICOM at all (no "DICM" prefix, no data set
/// starting at group 0002 or 0008); @p why then says so.
/// @throw IoError naming the file when it is DICOM but its header is damaged (a length past the
///        end of the file, sequences nested more than 16 deep).
std::optional<DicomHeader> readDicomHeader(const std::string& path, std::string* why = nullptr);

/// Whether @p file is DICOM (the "DICM" prefix, or a data set starting at group 0002 or 0008 as old
/// files do), walking all of it as GDCM will read it: every length within the file, sequences and
/// items well formed, the image module's value representations those GDCM's typed reading expects.
/// Returns its transfer syntax (0002,0010), empty without meta information; none when not DICOM.
/// @throw IoError naming the file and the byte when it is DICOM that would make GDCM assert or
///        allocate what the file does not hold.
std::optional<std::string> checkDicomFile(const InputFile& file);

/// A UID's most characters (PS3.5 9.1): messages show whole UIDs, which a user copies into --series.
inline constexpr size_t kUidChars = 64;

/// The deflated transfer syntax's UID: its lengths lie inside the compressed stream.
inline constexpr const char* kDeflatedTransferSyntax = "1.2.840.10008.1.2.1.99";

/// Refuses a transfer syntax the reader cannot decode, naming @p where and the syntax (HTJ2K, JPEG XL,
/// video and private ones); empty (no meta information: implicit little endian) passes.
/// @throw IoError naming @p where, the UID and what is expected.
void checkTransferSyntax(const std::string& uid, const std::string& where);

/// Where one slice's plane lies and how its values are rescaled: an image of one frame, or one
/// frame of an enhanced multi-frame image (its Per-frame Functional Groups).
struct DicomFrame {
  std::string file;
  int frame = -1;               ///< the frame's index in a multi-frame file, -1 for a single-frame image
  glm::dvec3 position{0.0};     ///< Image Position (Patient) of its first pixel, LPS mm
  bool hasPosition = false;
  std::vector<double> orientation;  ///< Image Orientation (Patient): six cosines, or empty
  double slope = 1.0, intercept = 0.0;
  bool localizer = false;       ///< ImageType holds LOCALIZER
  std::string sopInstance;      ///< SOP Instance UID (0008,0018): a copy of the image has the same
};

/// One image instance (a file) of a series.
struct DicomInstance {
  std::string file;
  uint64_t bytes = 0;
  std::string sopClass, studyUid, seriesUid;
  std::string transferSyntax;  ///< (0002,0010), or empty without meta information
  int rows = 0, columns = 0, frames = 1;
  glm::dvec2 pixelSpacing{0.0};  ///< between columns, between rows (Pixel Spacing's second and first); 0 when absent
  std::string patientPosition, thickness, tilt;
  std::vector<DicomFrame> planes;  ///< one per frame
  std::string defect;  ///< what makes its frames unreadable as a series (refused when its series is read), or empty
};

/// A folder's catalog: its image series (with their instances) and what was skipped.
struct DicomCatalog {
  std::string root;
  bool dicomdir = false;  ///< read from a DICOMDIR's records
  size_t files = 0;       ///< files looked at
  std::vector<DicomSeriesInfo> series;                  ///< the default choice first (DicomListing's order)
  std::map<std::string, std::vector<DicomInstance>> instances;  ///< by series UID
  std::vector<std::pair<std::string, size_t>> skipped;  ///< reason, count
  std::vector<std::pair<std::string, std::string>> damaged;  ///< DICOM files whose header is damaged: file, message
  std::vector<std::pair<std::string, std::string>> skippedFiles;  ///< files read and skipped: file, reason
};

/// The catalog of @p dir: from its DICOMDIR when it holds one (the files it names), else from every
/// file of its tree (@p recursive) or of the folder alone. @p progress hears of the files read
/// ("DICOM headers").
/// @throw IoError naming @p dir when it holds no image series (saying what it found), or naming the
///        DICOMDIR when its records are damaged or name files that are not there.
DicomCatalog catalogDicom(const std::string& dir, bool recursive = true, const Progress* progress = nullptr);

/// One line naming series @p s: 'UID' (CT, description, N slices of WxH).
std::string describeSeries(const DicomSeriesInfo& s);

/// Whether the SOP class UID @p sopClass is an image storage this product reads (CT, MR, PET,
/// NM, the enhanced ones, secondary capture, X-ray angiography...), and when not, why in words
/// ("structured report", "presentation state", "RT object", ...).
std::string nonImageReason(const std::string& sopClass);

}  // namespace hyb::detail
