// Running the command line in-process, for the tests that drive `hybrid-octree` as a user would.
#pragma once

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <sstream>
#include <string>
#include <vector>

#include "apps/cli/cli.h"

namespace hyb::test {

struct CliRun {
  int status;
  std::string out, err;
};

/// Runs `hybrid-octree args...` in this process.
inline CliRun run(std::vector<std::string> args) {
  args.insert(args.begin(), "hybrid-octree");
  std::vector<const char*> argv;
  for (const auto& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int status = app::runMain(int(argv.size()), argv.data(), out, err);
  return {status, out.str(), err.str()};
}

inline size_t lines(const std::string& s) { return size_t(std::count(s.begin(), s.end(), '\n')); }

/// Bad input: exit status 2 and exactly one line on stderr mentioning @p named.
inline void expectBadInput(const std::vector<std::string>& args, const std::string& named) {
  const CliRun r = run(args);
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_EQ(lines(r.err), size_t(1)) << r.err;
  EXPECT_THAT(r.err, ::testing::HasSubstr(named));
}

}  // namespace hyb::test
