// Volume readers: NRRD, MetaImage, NIfTI, DICOM series, InVesalius .inv3 and raw.
//
// Every reader validates at the boundary (STYLE 5): dims, type, byte counts and sample values are
// checked, and any problem is thrown as IoError/ValueError with a one-line message that starts
// with the offending file and says what was expected.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <string>

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

/// Reads any supported volume, chosen by extension (.nrrd .nhdr .mhd .mha .nii .nii.gz .inv3), by
/// being a directory (DICOM series), or by @p raw being non-null (raw samples).
/// @throw IoError / ValueError with a message naming @p path.
Volume readVolume(const std::string& path, const RawLayout* raw = nullptr);

/// NRRD with attached (.nrrd) or detached (.nhdr) data; raw, gzip or ascii encoding; 3 dimensions.
Volume readNrrd(const std::string& path);
/// MetaImage (.mhd with a data file, .mha with LOCAL data); raw or zlib-compressed data.
Volume readMetaImage(const std::string& path);
/// NIfTI-1 or NIfTI-2 (.nii, .nii.gz, .hdr/.img) through nifti_clib; scl_slope/scl_inter applied.
Volume readNifti(const std::string& path);
/// A directory holding one DICOM series (the largest if there are several), sorted by image
/// position along the slice normal, rescale slope/intercept applied (CT comes out in HU).
Volume readDicomSeries(const std::string& dir);
/// An InVesalius 3 project (.inv3: gzip tar with main.plist and the raw matrix).
Volume readInv3(const std::string& path);
/// Headerless samples with the given layout; the file size must match exactly.
Volume readRaw(const std::string& path, const RawLayout& layout);

}  // namespace hyb
