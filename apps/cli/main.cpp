// hybrid-octree: the command-line entry point; all logic is in apps/cli/cli.cpp.
#include <cstdio>
#include <iostream>
#include <sstream>
#include <string>

#include "apps/cli/cli.h"
#include "apps/ranks/ranks.h"

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // piped output arrives line by line, as it happens
  const hyb::app::Ranks ranks = hyb::app::startRanks(&argc, &argv);
  if (ranks.root()) {
    const int rc = hyb::app::runMain(argc, argv, std::cout, std::cerr);
    hyb::app::endRanks(ranks, rc);
    return rc;
  }
  // Other ranks: rank 0 speaks for the run; a rank's own failure is said, named, before it ends the run.
  std::ostringstream out, err;
  const int rc = hyb::app::runMain(argc, argv, out, err);
  if (rc != 0) {
    std::istringstream lines(err.str());
    for (std::string line; std::getline(lines, line);) std::cerr << "[rank " << ranks.rank << "/" << ranks.size << "] " << line << "\n";
    std::cerr.flush();
  }
  hyb::app::endRanks(ranks, rc);
  return rc;
}
