// Helpers every volume reader shares (volume/*_io.cpp); internal to volume/.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "volume/volume.h"

namespace hyb::detail {

/// @p s without leading and trailing whitespace.
std::string trim(const std::string& s);
/// @p s in lower case (ASCII).
std::string lower(std::string s);
/// Converts @p count samples of type @p t at @p data (any alignment, @p bigEndian byte order) to float.
std::vector<float> decodeSamples(const uint8_t* data, size_t count, ScalarType t, bool bigEndian);
/// Captures what C libraries print on stderr (file descriptor 2) while it lives, for libraries
/// that print regardless of their settings (nifti_clib). Process-wide: other threads' stderr
/// output in that time is captured too, so keep the scope to the library call. One at a time.
class StderrCapture {
 public:
  StderrCapture();
  ~StderrCapture();
  StderrCapture(const StderrCapture&) = delete;
  StderrCapture& operator=(const StderrCapture&) = delete;
  /// Restores stderr and returns the first line printed, "" if none (later calls return "").
  std::string finish();

 private:
  int mSaved = -1;
  std::FILE* mFile = nullptr;
};

/// @p v with the patient frame and the reader's warnings.
Volume placed(Volume v, const PatientFrame& frame, const std::vector<std::string>& warnings);

}  // namespace hyb::detail
