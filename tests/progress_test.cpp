#include "volume/core/progress.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "volume/core/parallel.h"

namespace hyb {
namespace {

// The first exception of an OpenMP loop's iterations comes out of it after the loop; the
// iterations after it are skipped, those before it done.
TEST(ParallelFailure, TheFirstExceptionOfALoopIsThrownAfterIt) {
  constexpr int kCount = 10000, kThrowAt = 100;
  std::vector<char> done(kCount, 0);
  ParallelFailure failure;
#pragma omp parallel for schedule(static, 1)
  for (int i = 0; i < kCount; ++i)
    failure.run([&] {
      if (i == kThrowAt) throw std::out_of_range("iteration 100");
      done[size_t(i)] = 1;
    });
  try {
    failure.rethrow();
    ADD_FAILURE() << "nothing thrown";
  } catch (const std::out_of_range& e) {
    EXPECT_STREQ(e.what(), "iteration 100");
  }
  EXPECT_EQ(done[kThrowAt], 0);
  EXPECT_LT(std::count(done.begin(), done.end(), 1), kCount - 1);  // some skipped
  // Without a failure, every iteration runs and nothing is thrown.
  ParallelFailure none;
  int ran = 0;
#pragma omp parallel for reduction(+ : ran)
  for (int i = 0; i < kCount; ++i) EXPECT_TRUE(none.run([&] { ++ran; }));
  EXPECT_NO_THROW(none.rethrow());
  EXPECT_EQ(ran, kCount);
}

TEST(Progress, TasksReportWholePercentsInOrderFromAnyThread) {
  std::vector<std::pair<std::string, double>> seen;
  const Progress progress([&](const std::string& task, double f) { seen.emplace_back(task, f); });
  {
    ProgressTask task(&progress, "work", 1000);
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t)
      threads.emplace_back([&] {
        for (int i = 0; i < 250; ++i) task.advance();
      });
    for (std::thread& t : threads) t.join();
  }
  ASSERT_GE(seen.size(), 3u);
  EXPECT_EQ(seen.front(), std::make_pair(std::string("work"), 0.0));
  EXPECT_EQ(seen.back(), std::make_pair(std::string("work"), 1.0));
  // Each whole percent once (the end's 100 % apart): 0, 1 ... 99 reported at most once each.
  EXPECT_LE(seen.size(), 101u);
  for (size_t i = 1; i < seen.size(); ++i) {
    EXPECT_NEAR(seen[i].second * 100, std::round(seen[i].second * 100), 1e-9);
    EXPECT_GT(seen[i].second, seen[i - 1].second);
  }
  ProgressTask none(nullptr, "nothing", 10);  // no progress: a no-op
  none.advance(5);
}

}  // namespace
}  // namespace hyb
