#include "volume/core/error.h"

#include <cstdio>
#include <cstdlib>

namespace hyb::detail {

void checkFailed(const char* expr, const char* file, int line) {
  std::fprintf(stderr, "hybrid-octree: internal check failed: %s (%s:%d)\n", expr, file, line);
  std::abort();
}

}  // namespace hyb::detail
