// How the command line shows the progress of long steps: a bar redrawn in place on a terminal,
// a line every second or so when its error stream is piped, or nothing.
#pragma once

#include <chrono>
#include <iosfwd>
#include <optional>
#include <string>

#include "volume/core/progress.h"

namespace hyb::app {

enum class ProgressMode { Auto, Bar, Lines, Off };

/// Parses "auto", "bar", "lines" or "off"; false for anything else.
bool parseProgressMode(const std::string& text, ProgressMode* mode);

/// Draws a Progress's reports on @p err: a bar (after a task has run 0.3 s, so quick steps stay
/// silent), or lines (one a second at most, and the end of a task that printed one). Auto is a bar
/// when @p terminal, lines otherwise.
class ProgressDisplay {
 public:
  ProgressDisplay(ProgressMode mode, std::ostream& err, bool terminal);
  /// What library calls report to; null when the mode is Off.
  const Progress* progress() const { return mProgress ? &*mProgress : nullptr; }

 private:
  using Clock = std::chrono::steady_clock;
  void report(const std::string& task, double fraction);

  bool mBar = false;
  std::ostream& mErr;
  std::optional<Progress> mProgress;
  Clock::time_point mStart, mLast;
  bool mShown = false;  // the current task has printed something
};

}  // namespace hyb::app
