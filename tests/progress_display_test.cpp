// The command line's progress display (apps/cli/progress_display): a bar on a terminal, lines when
// piped, nothing for short tasks.
#include "apps/cli/progress_display.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <sstream>
#include <thread>

#include "volume/core/progress.h"

namespace hyb {
namespace {

using ::testing::HasSubstr;

TEST(Progress, DisplayDrawsABarOrLinesOnlyForTasksThatTakeTime) {
  for (const app::ProgressMode mode : {app::ProgressMode::Lines, app::ProgressMode::Bar}) {
    std::ostringstream err;
    const app::ProgressDisplay display(mode, err, false);
    { ProgressTask quick(display.progress(), "quick", 2); quick.advance(2); }
    EXPECT_EQ(err.str(), "");  // short tasks stay silent
    {
      ProgressTask slow(display.progress(), "slow", 4);
      std::this_thread::sleep_for(std::chrono::milliseconds(1050));
      slow.advance(2);
    }
    if (mode == app::ProgressMode::Lines) {
      EXPECT_THAT(err.str(), HasSubstr("progress slow: 50 %\n"));
      EXPECT_THAT(err.str(), HasSubstr("progress slow: done in 1."));
    } else {
      EXPECT_THAT(err.str(), HasSubstr("\rslow                 [###############               ]  50 %"));
      EXPECT_THAT(err.str(), HasSubstr("] 100 %, 1."));
    }
  }
  std::ostringstream err;
  const app::ProgressDisplay off(app::ProgressMode::Off, err, true);
  EXPECT_EQ(off.progress(), nullptr);
}

}  // namespace
}  // namespace hyb
