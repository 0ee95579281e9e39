#include "volume/reader_util.h"

#include <algorithm>
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

// Converts @p count samples of type @p t at @p data (any alignment) to float.
std::vector<float> decodeSamples(const uint8_t* data, size_t count, ScalarType t, bool bigEndian) {
  const size_t size = scalarSize(t);
  std::vector<float> out(count);
  const bool swap = bigEndian != (std::endian::native == std::endian::big);
#pragma omp parallel for schedule(static)
  for (size_t i = 0; i < count; ++i) {
    uint8_t b[8];
    std::memcpy(b, data + i * size, size);
    if (swap) std::reverse(b, b + size);
    switch (t) {
      case ScalarType::UInt8: out[i] = b[0]; break;
      case ScalarType::Int8: out[i] = static_cast<int8_t>(b[0]); break;
      case ScalarType::UInt16: { uint16_t v; std::memcpy(&v, b, 2); out[i] = v; break; }
      case ScalarType::Int16: { int16_t v; std::memcpy(&v, b, 2); out[i] = v; break; }
      case ScalarType::UInt32: { uint32_t v; std::memcpy(&v, b, 4); out[i] = float(v); break; }
      case ScalarType::Int32: { int32_t v; std::memcpy(&v, b, 4); out[i] = float(v); break; }
      case ScalarType::Float32: { float v; std::memcpy(&v, b, 4); out[i] = v; break; }
      case ScalarType::Float64: { double v; std::memcpy(&v, b, 8); out[i] = float(v); break; }
    }
  }
  return out;
}

// @p v with the patient frame and the reader's warnings.
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
