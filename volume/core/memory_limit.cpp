#include "volume/core/memory_limit.h"

#include <unistd.h>

#include <atomic>
#include <cstdio>

#include "volume/core/error.h"

namespace hyb {

namespace {
std::atomic<uint64_t> gLimit{0};  // 0: the default, computed on first use
}  // namespace

uint64_t defaultMemoryLimit() {
  const long pages = ::sysconf(_SC_PHYS_PAGES), pageSize = ::sysconf(_SC_PAGESIZE);
  if (pages <= 0 || pageSize <= 0) return uint64_t(4) << 30;
  return uint64_t(pages) * uint64_t(pageSize) / 2;
}

void setMemoryLimit(uint64_t bytes) { gLimit.store(bytes); }

uint64_t memoryLimit() {
  const uint64_t limit = gLimit.load();
  return limit ? limit : defaultMemoryLimit();
}

std::string formatBytes(uint64_t bytes) {
  static const char* kUnits[] = {"KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
  if (bytes < 1024) return std::to_string(bytes) + " bytes";
  double v = double(bytes);
  int unit = -1;
  while (v >= 1024.0 && unit < 5) v /= 1024.0, ++unit;
  char text[32];
  std::snprintf(text, sizeof text, "%.1f %s", v, kUnits[unit]);
  return text;
}

void checkMemory(const std::string& file, uint64_t bytes, const std::string& what) {
  const uint64_t limit = memoryLimit();
  if (bytes <= limit) return;
  HYB_THROW(IoError, file, ": ", what, " need ", bytes, " bytes (", formatBytes(bytes), "), more than the memory limit of ",
            formatBytes(limit), " (expected a volume that fits; the limit, --memory-limit MB on the command line, is by default half the physical memory)");
}

}  // namespace hyb
