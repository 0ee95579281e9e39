// hybrid-octree: the command-line entry point; all logic is in apps/cli.cpp.
#include <iostream>

#include "apps/cli.h"

int main(int argc, char** argv) { return hyb::app::runMain(argc, argv, std::cout, std::cerr); }
