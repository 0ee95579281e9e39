// Helpers the volume readers share (volume/*_io.cpp), and the scene file that stores samples too.
#pragma once

#include <cstdint>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "volume/volume.h"

namespace hyb::detail {

/// @p s without leading and trailing whitespace.
std::string trim(const std::string& s);
/// @p s in lower case (ASCII).
std::string lower(std::string s);
/// Widens [@p lo, @p hi] to the range of the @p count samples of type @p t at @p data.
void widenSampleRange(const uint8_t* data, size_t count, ScalarType t, bool bigEndian, double* lo, double* hi);
/// @p count zero samples held as @p stored (float unless an 8- or 16-bit integer type).
SampleArray allocateSamples(ScalarType stored, size_t count);
/// Calls @p f with a value of @p t's C++ type (uint8_t … double).
template <class F>
decltype(auto) withFileType(ScalarType t, F&& f) {
  switch (t) {
    case ScalarType::UInt8: return f(uint8_t());
    case ScalarType::Int8: return f(int8_t());
    case ScalarType::UInt16: return f(uint16_t());
    case ScalarType::Int16: return f(int16_t());
    case ScalarType::UInt32: return f(uint32_t());
    case ScalarType::Int32: return f(int32_t());
    case ScalarType::Float32: return f(float());
    case ScalarType::Float64: break;
  }
  return f(double());
}
/// Converts the @p count samples of type @p t at @p data into @p out (whatever type it holds) from
/// sample @p first on.
void decodeInto(const uint8_t* data, size_t count, ScalarType t, bool bigEndian, SampleArray* out, size_t first);
/// The @p count samples of type @p t, fed in pieces by @p eachPiece (called with a function
/// use(data, first, n) that it calls for every piece, in any order, twice for 32-bit integers),
/// in the type a volume holds them in (storageTypeFor their type and range).
template <class EachPiece>
SampleArray decodePieces(ScalarType t, bool bigEndian, size_t count, const EachPiece& eachPiece) {
  double lo = 0, hi = 0;
  if (t == ScalarType::UInt32 || t == ScalarType::Int32) {  // held in 16 bits when their range allows
    lo = std::numeric_limits<double>::max();
    hi = -lo;
    eachPiece([&](const uint8_t* data, size_t, size_t n) { widenSampleRange(data, n, t, bigEndian, &lo, &hi); });
  }
  SampleArray out = allocateSamples(storageTypeFor(t, lo, hi), count);
  eachPiece([&](const uint8_t* data, size_t first, size_t n) { decodeInto(data, n, t, bigEndian, &out, first); });
  return out;
}
/// The @p count samples of type @p t at @p data (any alignment, @p bigEndian byte order) in the
/// type a volume holds them in (storageTypeFor their type and range).
SampleArray decodeSamples(const uint8_t* data, size_t count, ScalarType t, bool bigEndian);
/// @p values (from text) held as type @p t where every value is one of its integers, else as float.
SampleArray samplesOfType(std::vector<float> values, ScalarType t);
/// @p count samples for values rescaled from type @p t: type @p t itself for 8- and 16-bit values
/// not rescaled, int16 when @p slope and @p intercept are integers and @p t is an integer type (a
/// CT's Hounsfield units), else float.
SampleArray rescaleTarget(ScalarType t, double slope, double intercept, size_t count);
/// Writes slice * slope + intercept into @p samples from sample @p first on. @p samples stays in its
/// 16- or 8-bit type while every value is an integer of it; otherwise it becomes float first.
void rescaleSamples(SampleArray* samples, size_t first, const SampleArray& slice, double slope, double intercept);
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

/// A volume of @p dims and @p spacing whose samples (file type @p t) are not read yet: its range
/// reads [0, 0], its stored type is the one the samples will be held in.
Volume describedVolume(const glm::ivec3& dims, const glm::dvec3& spacing, ScalarType t, const std::string& path);
/// @p v with @p from's patient frame, info and warnings.
Volume placedAs(Volume v, const Volume& from);
/// The volume @p description describes, with its @p samples (frame, info and warnings kept).
Volume filled(const Volume& description, SampleArray samples, const std::string& path);
/// @p v with the patient frame and the reader's warnings.
Volume placed(Volume v, const PatientFrame& frame, const std::vector<std::string>& warnings);

}  // namespace hyb::detail
