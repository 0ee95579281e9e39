// Volume readers: NRRD, MetaImage, NIfTI, DICOM series, InVesalius .inv3 and raw.
//
// Every reader validates at the boundary (STYLE 5): dims, type, byte counts and sample values are
// checked, and any problem is thrown as IoError/ValueError with a one-line message that starts
// with the offending file and says what was expected. Every reader also places the grid in the
// patient (Volume::frame, LPS mm), converting its format's convention; what it had to assume is
// in Volume::warnings.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "volume/core/progress.h"
#include "volume/volume.h"

namespace hyb {

/// Default input: the CT shipped by Debian's invesalius-examples package.
inline constexpr const char* kDefaultVolumePath = "/usr/share/doc/invesalius-examples/examples/Cranium.inv3";

/// Layout of a headerless raw file.
struct RawLayout {
  glm::ivec3 dims{0};                  ///< samples per axis
  ScalarType type = ScalarType::UInt8; ///< sample type
  glm::dvec3 spacing{1.0};             ///< mm between voxel centres
  bool bigEndian = false;              ///< byte order of multi-byte samples
  uint64_t headerBytes = 0;            ///< bytes to skip before the samples
};

class PlaneSource;

/// The format a volume file's extension names: NRRD (.nrrd .nhdr), MetaImage (.mhd .mha), NIfTI
/// (.nii .nii.gz .hdr) or InVesalius (.inv3); None for any other (raw samples, a scene file).
enum class VolumeFormat { None, Nrrd, MetaImage, Nifti, Inv3 };

/// One format the readers know: the row that readVolume's and the streamed planes' dispatch, the
/// raw flags' refusal, the "unknown format" message, the flags' help and the viewer's file list
/// read (a new format is one row here and its reader's file).
struct VolumeFormatRow {
  VolumeFormat format;
  const char* name;                                                  ///< "NRRD"
  std::vector<std::string> extensions;                               ///< lower case, with the dot: ".nrrd", ".nhdr"
  Volume (*read)(const std::string& path);                          ///< the whole reader
  std::unique_ptr<PlaneSource> (*planes)(const std::string& path);  ///< the streamed one; null when the format is read whole
};
/// The formats, in the order messages list them.
const std::vector<VolumeFormatRow>& volumeFormats();
/// The row of the format @p path's extension names, or null (raw samples, a scene file, unknown).
const VolumeFormatRow* volumeFormatRow(const std::string& path);
VolumeFormat volumeFormatOf(const std::string& path);
/// Every extension the readers know, space-separated (".nrrd .nhdr .mhd ..."), for help and messages.
std::string volumeExtensionsText();

/// Reads any supported volume, chosen by extension (.nrrd .nhdr .mhd .mha .nii .nii.gz .inv3), by
/// being a directory (DICOM series: @p series names one by its Series Instance UID), or by @p raw
/// being non-null (raw samples).
/// @throw IoError / ValueError with a message naming @p path.
Volume readVolume(const std::string& path, const RawLayout* raw = nullptr, const std::string& series = "", const Progress* progress = nullptr);

/// NRRD with attached (.nrrd) or detached (.nhdr) data; raw, gzip or ascii encoding; 3 dimensions.
/// Geometry from "space", "space directions", "space origin" and "space units" (RAS, LAS and
/// LPS spaces; scanner-xyz and 3D-right-handed taken as LPS with a warning), or "spacings" alone.
Volume readNrrd(const std::string& path);
/// MetaImage (.mhd with a data file, .mha with LOCAL data); raw or zlib-compressed data. Geometry
/// from Offset and TransformMatrix (rows: the axes' directions, LPS) as ITK reads them, or
/// AnatomicalOrientation when no matrix is given.
Volume readMetaImage(const std::string& path);
/// NIfTI-1 or NIfTI-2 (.nii, .nii.gz, .hdr/.img) through nifti_clib; scl_slope/scl_inter applied.
/// Geometry from the sform, else the qform, else method 1 (ITK's and nibabel's precedence), RAS
/// converted to LPS.
Volume readNifti(const std::string& path);

/// One image series of a DICOM folder, folder tree or patient CD.
struct DicomSeriesInfo {
  std::string uid, number, description, modality;
  std::string date;                         ///< Series Date (YYYYMMDD), or empty
  std::string studyUid, studyDate, studyDescription;
  std::string patientName, patientId;
  size_t slices = 0;                        ///< images: each frame of a multi-frame image counts
  size_t files = 0;
  int columns = 0, rows = 0;
  uint64_t bytes = 0;                       ///< its files' sizes
  bool localizer = false;                   ///< ImageType LOCALIZER, or one slice across its study's main series
  bool axial = false;                       ///< its slices' normal nearest the patient's z axis
};
/// What a DICOM folder holds: its series (the default, the largest axial one that is not a
/// localizer, first; then by size) and the files that are not image series, by reason.
struct DicomListing {
  std::string dir;
  std::vector<DicomSeriesInfo> series;
  size_t files = 0;                                      ///< files looked at
  std::vector<std::pair<std::string, size_t>> skipped;  ///< reason ("not DICOM", "structured report"...), count
  bool dicomdir = false;                                 ///< read from a DICOMDIR's records
};
/// The series in @p dir: from its DICOMDIR when it holds one, else from every file of its tree
/// (@p recursive) or of the folder alone (headers only). @p progress hears of the files read ("DICOM headers").
/// @throw IoError when it holds no image series, saying what it found.
DicomListing listDicomSeries(const std::string& dir, const Progress* progress = nullptr, bool recursive = true);
/// One DICOM series of @p dir (a folder, a folder tree or a CD with its DICOMDIR): the one whose
/// Series Instance UID is @p seriesUid, or the default (the largest axial series that is not a
/// localizer; a warning names it when there are several). Planes (single-frame images, or the
/// frames of enhanced multi-frame images) are ordered along the normal of Image Orientation
/// (Patient); when they are unevenly spaced or their positions leave the normal (a gantry tilt) they
/// are resampled onto an orthogonal regular grid (plane_stack.h), a missing slice refused; rescale
/// slope/intercept applied per plane (CT comes out in HU). The frame: i along the rows' direction,
/// j along the columns', k along the normal. Info: modality, series, patient position, slice
/// thickness, rescale. @p progress hears of the headers and slices read; @p recursive false reads
/// the folder's own files only.
Volume readDicomSeries(const std::string& dir, const std::string& seriesUid = "", const Progress* progress = nullptr, bool recursive = true);
/// A DICOM folder named by a file in it: a CD's DICOMDIR (the folder, the series asked for), or one
/// image of a series (the folder holding it, its own files only, and that image's series).
struct DicomFolder {
  std::string dir, series;
  bool recursive = true;
};
/// The folder @p path names when it is a DICOMDIR or a DICOM image (of no other format), else none.
/// @throw ValueError when @p series names another series than the image's; IoError naming the file
///        when it is DICOM with a damaged header.
std::optional<DicomFolder> dicomFolderOf(const std::string& path, const std::string& series);
/// An InVesalius 3 project (.inv3: gzip tar with main.plist and the raw matrix). InVesalius keeps
/// its matrix LAS (its DICOM import's layout) unless the project stores an affine (NIfTI import).
Volume readInv3(const std::string& path);
/// Headerless samples with the given layout; the file size must match exactly. No orientation:
/// identity frame, with a warning.
Volume readRaw(const std::string& path, const RawLayout& layout);

/// Writes @p volume as one NRRD file (raw encoding, the host's byte order) in its stored type, on its
/// grid: "space: left-posterior-superior", "space directions" the frame's axes times the spacing,
/// "space origin" the frame's origin, each number to 17 significant digits, so readNrrd gives back
/// the same grid. Written atomically (volume/core/file_util.h).
/// @throw IoError naming @p path when it cannot be written.
void writeNrrd(const Volume& volume, const std::string& path);
/// Writes @p volume as one NIfTI-1 file (.nii, or .nii.gz as one gzip stream), in its stored type
/// (float32 for what is stored as float), the host's byte order, on its grid: the sform and the
/// qform (codes 1, scanner, or 2, aligned when the frame was assumed) both the frame in RAS (x and y
/// negated), pixdim the spacing and qfac the handedness, mm units, the samples from byte 352 (no
/// extension). The affine is stored as float, as NIfTI-1 has it. Written atomically.
/// @throw IoError naming @p path when it cannot be written or an axis exceeds NIfTI-1's 32767.
void writeNifti(const Volume& volume, const std::string& path);

/// The extensions writeVolume knows, space-separated (".nrrd .nii .nii.gz"), for messages.
std::string writableVolumeExtensionsText();
/// Whether writeVolume knows @p path's extension.
bool writableVolume(const std::string& path);
/// Writes @p volume in the format its extension names: writeNrrd (.nrrd) or writeNifti (.nii .nii.gz).
/// @throw IoError naming @p path when it cannot be written or the extension is none of them.
void writeVolume(const Volume& volume, const std::string& path);

}  // namespace hyb
