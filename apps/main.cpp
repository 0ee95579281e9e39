// hybrid-octree: the command-line entry point; all logic is in apps/cli.cpp.
#include <cstdio>
#include <iostream>

#include "apps/cli.h"

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // piped output arrives line by line, as it happens
  return hyb::app::runMain(argc, argv, std::cout, std::cerr);
}
