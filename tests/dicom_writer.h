// DICOM written the way scanners and patient CDs write it, for the tests and benchmarks: CT slices
// with a study and a series (tilted, unevenly spaced, localizers), enhanced multi-frame CT with
// per-frame functional groups, structured reports, and a DICOMDIR naming extensionless files in
// nested folders. Pixels come from an analytic field sampled where each pixel lies in the patient.
#pragma once

#include <glm/glm.hpp>

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace hyb::test {

/// The patient and study a file belongs to.
struct DicomStudy {
  std::string patientName = "TEST^PATIENT", patientId = "HYB001";
  std::string uid = "1.2.826.0.1.3680043.8.498.1";
  std::string date = "20240301", description = "CT HEAD";
};

/// One CT image (or one frame of an enhanced image): its series, geometry and stored pixels.
struct DicomImage {
  std::string seriesUid = "1.2.826.0.1.3680043.8.498.2";
  int seriesNumber = 2;
  std::string seriesDescription = "HEAD 2.5";
  std::string imageType = "ORIGINAL\\PRIMARY\\AXIAL";
  int instance = 1;
  glm::ivec2 size{16, 16};         ///< columns, rows
  glm::dvec2 spacing{1.0};         ///< mm between columns, between rows
  glm::dvec3 position{0.0};        ///< Image Position (Patient): the first pixel, LPS mm
  double cosines[6] = {1, 0, 0, 0, 1, 0};  ///< Image Orientation (Patient): rows' direction, columns'
  double slope = 1.0, intercept = -1024.0;
  double tilt = 0.0;               ///< Gantry/Detector Tilt (0018,1120), written when not 0
  double thickness = 2.0;
  std::string transferSyntax = "1.2.840.10008.1.2.1";  ///< (0002,0010): explicit VR little endian, or deflated; others only named
  std::vector<int16_t> pixels;     ///< stored values, x fastest
  /// The LPS position of pixel (i, j).
  glm::dvec3 at(int i, int j) const;
};

/// @p image's pixels sampled from @p hu (Hounsfield units at an LPS point), stored as (HU − intercept) / slope.
void sampleField(DicomImage* image, const std::function<double(const glm::dvec3&)>& hu);

/// A single-frame CT image file.
void writeCtImage(const std::string& path, const DicomStudy& study, const DicomImage& image);
/// One Enhanced CT Image file holding @p frames (one series; size and spacing of the first), each
/// frame's position and rescale in its Per-frame Functional Groups, the orientation shared.
void writeEnhancedCt(const std::string& path, const DicomStudy& study, const std::vector<DicomImage>& frames);
/// A Basic Text structured report (no pixel data) in series @p seriesUid.
void writeStructuredReport(const std::string& path, const DicomStudy& study, const std::string& seriesUid);
/// A DICOMDIR in @p root naming @p files (paths relative to @p root, '/'-separated) in PATIENT,
/// STUDY, SERIES and IMAGE (or SR DOCUMENT) records, read back from the files.
void writeDicomdir(const std::string& root, const std::vector<std::string>& files);

/// A series of @p count axial slices through @p hu: slice k at @p first + k·@p step (LPS mm), with
/// the image plane given by @p cosines; files "<dir>/<prefix><k>" (no extension) written in a
/// shuffled order. Returns the images written.
std::vector<DicomImage> writeSeries(const std::string& dir, const std::string& prefix, const DicomStudy& study, DicomImage model,
                                    const std::vector<glm::dvec3>& positions, const std::function<double(const glm::dvec3&)>& hu);

}  // namespace hyb::test
