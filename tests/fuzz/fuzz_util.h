// What the libFuzzer targets share: the input written to a file the readers open by name, and the
// errors a hostile input may end in (anything else, a crash or a sanitizer report, is a finding).
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>

#include "volume/core/error.h"
#include "volume/core/memory_limit.h"

namespace hyb::fuzz {

/// A directory of this process's own, made once.
inline const std::filesystem::path& scratch() {
  static const std::filesystem::path dir = [] {
    const auto d = std::filesystem::temp_directory_path() / ("hyb-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    hyb::setMemoryLimit(uint64_t(512) << 20);  // a run stays far below libFuzzer's 2 GB rss limit
    return d;
  }();
  return dir;
}

/// Writes @p size bytes at @p data to scratch()/@p name and returns its path.
inline std::string writeInput(const std::string& name, const uint8_t* data, size_t size) {
  const std::string path = (scratch() / name).string();
  if (FILE* f = std::fopen(path.c_str(), "wb")) {
    if (size) std::fwrite(data, 1, size, f);
    std::fclose(f);
  }
  return path;
}

/// Runs @p f, accepting the project's own errors (one line for the user) as a clean refusal.
template <class F>
void refuseOrSucceed(F&& f) {
  try {
    f();
  } catch (const hyb::Error&) {
  }
}

}  // namespace hyb::fuzz
