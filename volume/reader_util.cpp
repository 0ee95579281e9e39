#include "volume/reader_util.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <type_traits>
#include <bit>
#include <cctype>
#include <cstring>
#include <mutex>

#include <unistd.h>

namespace hyb::detail {

std::string trim(const std::string& s) {
  const size_t b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  const size_t e = s.find_last_not_of(" \t\r\n");
  return s.substr(b, e - b + 1);
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

namespace {

// Sample @p i of @p data (type T in the file, any alignment and byte order).
template <class T>
T fileSample(const uint8_t* data, size_t i, bool swap) {
  uint8_t b[sizeof(T)];
  std::memcpy(b, data + i * sizeof(T), sizeof(T));
  if (swap) std::reverse(b, b + sizeof(T));
  T v;
  std::memcpy(&v, b, sizeof(T));
  return v;
}

bool swapFor(bool bigEndian) { return bigEndian != (std::endian::native == std::endian::big); }

}  // namespace

void widenSampleRange(const uint8_t* data, size_t count, ScalarType t, bool bigEndian, double* lo, double* hi) {
  const bool swap = swapFor(bigEndian);
  withFileType(t, [&](auto zero) {
    using T = decltype(zero);
    for (size_t i = 0; i < count; ++i) {
      const double v = double(fileSample<T>(data, i, swap));
      *lo = std::min(*lo, v);
      *hi = std::max(*hi, v);
    }
  });
}

SampleArray allocateSamples(ScalarType stored, size_t count) {
  switch (stored) {
    case ScalarType::UInt8: return std::vector<uint8_t>(count);
    case ScalarType::Int8: return std::vector<int8_t>(count);
    case ScalarType::UInt16: return std::vector<uint16_t>(count);
    case ScalarType::Int16: return std::vector<int16_t>(count);
    default: return std::vector<float>(count);
  }
}

void decodeInto(const uint8_t* data, size_t count, ScalarType t, bool bigEndian, SampleArray* out, size_t first) {
  HYB_CHECK(first + count <= sampleCount(*out));
  const bool swap = swapFor(bigEndian);
  withFileType(t, [&](auto zero) {
    using T = decltype(zero);
    std::visit(
        [&](auto& dst) {
          using U = typename std::remove_reference_t<decltype(dst)>::value_type;
          U* o = dst.data() + first;
#pragma omp parallel for schedule(static)
          for (size_t i = 0; i < count; ++i) o[i] = U(fileSample<T>(data, i, swap));
        },
        *out);
  });
}

SampleArray decodeSamples(const uint8_t* data, size_t count, ScalarType t, bool bigEndian) {
  return decodePieces(t, bigEndian, count, [&](const auto& use) { use(data, size_t(0), count); });
}

SampleArray samplesOfType(std::vector<float> values, ScalarType t) {
  // 32-bit integers narrow as decodeSamples narrows them; the text must hold integers of the type.
  const auto [lo, hi] = std::minmax_element(values.begin(), values.end());
  const ScalarType stored = values.empty() ? t : storageTypeFor(t, *lo, *hi);
  if (stored == ScalarType::Float32 || stored == ScalarType::Float64) return values;
  SampleArray out = allocateSamples(stored, values.size());
  const bool exact = std::visit(
      [&](auto& dst) {
        using U = typename std::remove_reference_t<decltype(dst)>::value_type;
        if (!std::all_of(values.begin(), values.end(), [](float v) { return holdsExactly<U>(v); })) return false;
        std::copy(values.begin(), values.end(), dst.begin());
        return true;
      },
      out);
  return exact ? out : SampleArray(std::move(values));
}

SampleArray rescaleTarget(ScalarType t, double slope, double intercept, size_t count) {
  const bool integral = t != ScalarType::Float32 && t != ScalarType::Float64 && slope == std::floor(slope) && intercept == std::floor(intercept);
  if (integral && slope == 1.0 && intercept == 0.0 && scalarSize(t) <= 2) return allocateSamples(t, count);
  return allocateSamples(integral ? ScalarType::Int16 : ScalarType::Float32, count);
}

void rescaleSamples(SampleArray* samples, size_t first, const SampleArray& slice, double slope, double intercept) {
  const size_t count = sampleCount(slice);
  HYB_CHECK(first + count <= sampleCount(*samples));
  // Writes the slice while its values are ones the array's type holds; false at the first that is not.
  const auto write = [&] {
    return std::visit(
        [&](const auto& in, auto& out) {
          using T = typename std::remove_reference_t<decltype(out)>::value_type;
          for (size_t i = 0; i < count; ++i) {
            const double v = double(in[i]) * slope + intercept;
            if (!holdsExactly<T>(v)) return false;
            out[first + i] = T(v);
          }
          return true;
        },
        slice, *samples);
  };
  if (write()) return;
  // A value the 8- or 16-bit array cannot hold: everything moves to float, and the slice is written again.
  std::vector<float> wide(sampleCount(*samples));
  std::visit([&](const auto& old) { std::copy(old.begin(), old.end(), wide.begin()); }, *samples);
  *samples = SampleArray();  // frees the old array before the wide one is kept
  *samples = std::move(wide);
  write();
}

// @p v with the patient frame and the reader's warnings.
Volume describedVolume(const glm::ivec3& dims, const glm::dvec3& spacing, ScalarType t, const std::string& path) {
  return Volume::withoutSamples({dims, spacing, t, storageTypeFor(t, 0.0, 0.0)}, 0.0f, 0.0f, path);
}

Volume placedAs(Volume v, const Volume& from) {
  v.setFrame(from.frame());
  for (const auto& [key, value] : from.info()) v.addInfo(key, value);
  for (const std::string& w : from.warnings()) v.addWarning(w);
  return v;
}

Volume filled(const Volume& description, SampleArray samples, const std::string& path) {
  return placedAs(Volume(description.dims(), description.spacing(), description.sourceType(), std::move(samples), path), description);
}

Volume placed(Volume v, const PatientFrame& frame, const std::vector<std::string>& warnings) {
  v.setFrame(frame);
  for (const std::string& w : warnings) v.addWarning(w);
  return v;
}

namespace {
std::mutex gStderrMutex;  // one capture at a time: they swap the same descriptor
}  // namespace

StderrCapture::StderrCapture() {
  gStderrMutex.lock();
  std::fflush(stderr);
  mFile = std::tmpfile();
  mSaved = mFile ? ::dup(2) : -1;
  if (mSaved < 0 || ::dup2(fileno(mFile), 2) < 0) {
    if (mSaved >= 0) ::close(mSaved);
    mSaved = -1;
  }
}

StderrCapture::~StderrCapture() { finish(); }

std::string StderrCapture::finish() {
  if (!mFile) return "";
  std::string first;
  std::fflush(stderr);
  if (mSaved >= 0) {
    ::dup2(mSaved, 2);
    ::close(mSaved);
    std::rewind(mFile);
    char line[256];
    if (std::fgets(line, sizeof line, mFile)) first = trim(line);
  }
  std::fclose(mFile);
  mFile = nullptr;
  mSaved = -1;
  gStderrMutex.unlock();
  return first;
}

}  // namespace hyb::detail
