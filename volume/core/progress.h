// Progress of long computations (a reference frame, a Hausdorff check, a surface's
// reconstruction, a large read or build), reported to whoever started them. The library only counts;
// the command line draws a bar on a terminal or prints lines when its output is piped.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>

namespace hyb {

/// Where a computation's progress goes. Thread-safe: tasks advance from any thread.
class Progress {
 public:
  /// Receives a task's name and the fraction of it done, in whole percents from 0 to 1 (1 once,
  /// when the task ends); never called by two threads at once. It may throw to stop the work (an
  /// exception from the end's report is dropped).
  using Callback = std::function<void(const std::string& task, double fraction)>;
  explicit Progress(Callback callback) : mCallback(std::move(callback)) {}

 private:
  friend class ProgressTask;
  void report(const std::string& task, double fraction) const {
    const std::lock_guard<std::mutex> lock(mMutex);
    mCallback(task, fraction);
  }
  // Reports @p percent when it is above *reported, under the lock: in order from any thread.
  void reportAbove(const std::string& task, int percent, std::atomic<int>* reported) const {
    const std::lock_guard<std::mutex> lock(mMutex);
    if (percent <= reported->load(std::memory_order_relaxed)) return;
    reported->store(percent, std::memory_order_relaxed);
    mCallback(task, percent / 100.0);
  }
  Callback mCallback;
  mutable std::mutex mMutex;
};

/// One task of @p total units of work: advance() from any thread; the callback hears of each new
/// whole percent, in order, and of the end when the task is destroyed. A null Progress makes it a
/// no-op.
class ProgressTask {
 public:
  ProgressTask(const Progress* progress, std::string name, uint64_t total)
      : mProgress(progress), mName(std::move(name)), mTotal(total > 0 ? total : 1) {
    if (mProgress) mProgress->report(mName, 0.0);
  }
  ProgressTask(const ProgressTask&) = delete;
  ProgressTask& operator=(const ProgressTask&) = delete;
  ~ProgressTask() {
    if (!mProgress) return;
    try {
      mProgress->report(mName, 1.0);
    } catch (...) {  // a callback that throws stops the task where it was: not again while unwinding
    }
  }
  /// Records @p units more done.
  void advance(uint64_t units = 1) {
    if (!mProgress) return;
    const uint64_t done = mDone.fetch_add(units, std::memory_order_relaxed) + units;
    const int percent = int(std::min<uint64_t>(99, done * 100 / mTotal));  // 100 % is the end's
    if (percent > mPercent.load(std::memory_order_relaxed)) mProgress->reportAbove(mName, percent, &mPercent);
  }

 private:
  const Progress* mProgress;
  std::string mName;
  uint64_t mTotal;
  std::atomic<uint64_t> mDone{0};
  std::atomic<int> mPercent{0};
};

}  // namespace hyb
