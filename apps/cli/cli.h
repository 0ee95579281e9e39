// The `hybrid-octree` command line: subcommands over the libraries, nothing more (STYLE 11).
#pragma once

#include <iosfwd>

namespace hyb::app {

/// Runs the command line @p argv, writing results to @p out and diagnostics to @p err.
/// Returns the exit status: 0 success, 1 runtime failure, 2 bad usage or bad input (one line on
/// @p err naming the file or flag and what was expected).
int runMain(int argc, const char* const* argv, std::ostream& out, std::ostream& err);

}  // namespace hyb::app
