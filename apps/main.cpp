// hybrid-octree: the command-line entry point; all logic is in apps/cli.cpp.
#include <malloc.h>

#include <cstdio>
#include <iostream>

#include "apps/cli.h"

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // piped output arrives line by line, as it happens
  // Blocks of 128 KB and more (brick streams, textures, surfaces) are mapped and unmapped, never
  // kept in the heap: glibc otherwise raises this threshold after the first such free, and a
  // frame's many mid-sized blocks then fragment the heap (docs/scale.md: 1.1–1.3 GB RSS for a
  // clinical frame with its surface against 0.87 GB).
  mallopt(M_MMAP_THRESHOLD, 128 * 1024);
  return hyb::app::runMain(argc, argv, std::cout, std::cerr);
}
