// A volume's samples plane by plane (z slices, in order), for a build whose memory must not grow
// with the volume: raw files, NRRD, MetaImage and NIfTI data (raw or gzip/zlib) and DICOM series
// (a slice file at a time) are read as they are needed; other inputs are read whole first.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <memory>
#include <string>

#include "volume/core/progress.h"
#include "volume/volume.h"
#include "volume/volume_io.h"

namespace hyb {

/// The samples of one volume, read forward plane by plane, as often as asked (rewind()).
class PlaneSource {
 public:
  virtual ~PlaneSource() = default;
  /// The volume without its samples: grid, types, patient frame, info and warnings. Its range is
  /// unknown until the samples are read (it reads [0, 0]).
  const Volume& description() const { return mDescription; }
  /// The file read (or "volume" for one in memory), for messages.
  const std::string& name() const { return mName; }
  const glm::ivec3& dims() const { return mDescription.dims(); }
  ScalarType storedType() const { return mDescription.storedType(); }
  /// Samples in a plane.
  size_t planeSize() const { return size_t(dims().x) * size_t(dims().y); }
  /// Whether the volume was read whole (the input format does not stream).
  virtual bool whole() const { return false; }
  /// Starts again at plane 0.
  virtual void rewind() = 0;
  /// Decodes the next @p count planes into @p out (which holds storedType()) from sample @p first on.
  /// @throw IoError naming the file when the data are short or corrupt.
  virtual void read(int count, SampleArray* out, size_t first) = 0;

 protected:
  PlaneSource(Volume description, std::string name) : mDescription(std::move(description)), mName(std::move(name)) {}

 private:
  Volume mDescription;
  std::string mName;
};

/// The planes of @p volume, which must outlive the source.
std::unique_ptr<PlaneSource> planesOf(const Volume& volume);

/// The planes of a volume file, by the rules of readVolume(): raw files, NRRD, MetaImage and
/// NIfTI files of 8- and 16-bit integer or float samples in raw or gzip/zlib encoding (NIfTI's not
/// rescaled), and DICOM series (detail::dicomPlanes), are read plane by plane; anything else
/// (InVesalius, ASCII, 32-bit integers) is read whole.
/// @throw IoError / ValueError naming @p path, as readVolume().
std::unique_ptr<PlaneSource> openPlanes(const std::string& path, const RawLayout* raw = nullptr, const std::string& series = "",
                                        const Progress* progress = nullptr);

namespace detail {

/// Where a file's samples lie: @p skip bytes after @p offset of @p data (−1: its last bytes; for
/// compressed data the skip counts inflated bytes), raw or a gzip/zlib stream.
struct SampleData {
  std::string path;  ///< the file holding the samples
  uint64_t offset = 0;
  long long skip = 0;
  const char* skipField = "byte skip";
  bool compressed = false;
  ScalarType type = ScalarType::UInt8;
  bool bigEndian = false;
};

/// The samples @p data holds for a grid of @p dims, read whole (raw or compressed; not ASCII).
SampleArray readSampleData(const SampleData& data, const glm::ivec3& dims);

/// Planes streamed from @p data for the volume @p description (grid, stored type, frame, info) of
/// the file @p path (its header). Sizes are checked against the file here, before anything is read.
std::unique_ptr<PlaneSource> streamedPlanes(const SampleData& data, Volume description, const std::string& path);

/// The streamed planes of a NRRD (raw or gzip) or MetaImage file, or null when its samples do not
/// stream (ASCII, 32-bit integers).
std::unique_ptr<PlaneSource> nrrdPlanes(const std::string& path);
std::unique_ptr<PlaneSource> metaImagePlanes(const std::string& path);
/// The streamed planes of a NIfTI file (.nii, .nii.gz, .hdr with its .img), or null when its
/// samples do not stream (32-bit integers, or rescaled by scl_slope and scl_inter).
std::unique_ptr<PlaneSource> niftiPlanes(const std::string& path);
/// The streamed planes of the DICOM series @p seriesUid in @p dir (the largest when empty): what
/// readDicomSeries() reads (grid, types, frame, info, warnings; the samples bit for bit), each
/// plane decoded from its slice file when read() asks for it, compressed transfer syntaxes too
/// (GDCM decodes a file at a time). Every slice's header is read and checked here. The whole reader
/// holds the samples in rescaleTarget() of the first slice and widens them to float at the first
/// rescaled value that type does not hold; here the type is decided from every value the headers
/// allow (each slice's pixel type, its Bits Stored for 16-bit pixels uncompressed or RLE, its slope
/// and intercept), and where that range does not fit the type (int16 with 16 bits stored and an
/// intercept, values down to -33792; a fractional slope after integer ones; an intercept after a
/// first slice without one), from the values, each slice decoded once more here.
/// @throw IoError / ValueError as readDicomSeries() for the series and its headers; read() throws
///        IoError naming the slice file when a slice is damaged or changed since.
std::unique_ptr<PlaneSource> dicomPlanes(const std::string& dir, const std::string& seriesUid, bool recursive = true);
/// The streamed planes of @p path by the rules of readVolume(), or null when it is read whole.
/// @p progress hears of a DICOMweb series' retrieval.
std::unique_ptr<PlaneSource> openStreamedPlanes(const std::string& path, const RawLayout* raw, const std::string& series,
                                                const Progress* progress = nullptr);

/// Whether samples of file type @p t stream: their stored type does not depend on their range.
inline bool streams(ScalarType t) { return t != ScalarType::UInt32 && t != ScalarType::Int32; }

}  // namespace detail

}  // namespace hyb
