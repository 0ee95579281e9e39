#include "apps/cli/progress_display.h"

#include <cmath>
#include <iomanip>
#include <ostream>
#include <sstream>

namespace hyb::app {

bool parseProgressMode(const std::string& text, ProgressMode* mode) {
  if (text == "auto") *mode = ProgressMode::Auto;
  else if (text == "bar") *mode = ProgressMode::Bar;
  else if (text == "lines") *mode = ProgressMode::Lines;
  else if (text == "off") *mode = ProgressMode::Off;
  else return false;
  return true;
}

ProgressDisplay::ProgressDisplay(ProgressMode mode, std::ostream& err, bool terminal) : mErr(err) {
  if (mode == ProgressMode::Off) return;
  mBar = mode == ProgressMode::Bar || (mode == ProgressMode::Auto && terminal);
  mProgress.emplace([this](const std::string& task, double fraction) { report(task, fraction); });
}

void ProgressDisplay::report(const std::string& task, double fraction) {
  const Clock::time_point now = Clock::now();
  if (fraction == 0.0) {
    mStart = mLast = now;
    mShown = false;
    return;
  }
  const double seconds = std::chrono::duration<double>(now - mStart).count();
  const bool done = fraction >= 1.0;
  std::ostringstream line;
  if (mBar) {
    if (seconds < 0.3 && !mShown) return;
    const int width = 30, filled = int(std::lround(fraction * width));
    line << "\r" << std::left << std::setw(20) << task << " [" << std::string(size_t(filled), '#') << std::string(size_t(width - filled), ' ')
         << "] " << std::right << std::setw(3) << int(std::lround(fraction * 100)) << " %";
    if (done) line << std::fixed << std::setprecision(1) << ", " << seconds << " s\n";
  } else {
    if (done ? !mShown : std::chrono::duration<double>(now - mLast).count() < 1.0) return;
    line << "progress " << task << ": ";
    if (done) line << "done in " << std::fixed << std::setprecision(1) << seconds << " s\n";
    else line << int(std::lround(fraction * 100)) << " %\n";
  }
  mErr << line.str() << std::flush;
  mShown = !done;
  mLast = now;
}

}  // namespace hyb::app
