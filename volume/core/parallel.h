// Exceptions out of OpenMP loops.
#pragma once

#include <atomic>
#include <exception>
#include <mutex>

namespace hyb {

/// Carries the first exception thrown by an OpenMP loop's iterations (a progress callback that
/// stops the work, an allocation that fails) out of the loop: an exception cannot cross the end of
/// an OpenMP region, where the process would end in std::terminate. Iterations after a failure are
/// skipped; rethrow() after the loop throws it.
class ParallelFailure {
 public:
  /// Runs @p iteration unless an iteration failed; keeps what it throws. Says whether it ran to
  /// its end.
  template <class F>
  bool run(F&& iteration) noexcept {
    if (mFailed.load(std::memory_order_relaxed)) return false;
    try {
      iteration();
      return true;
    } catch (...) {
      const std::lock_guard<std::mutex> lock(mMutex);
      if (!mFailure) mFailure = std::current_exception();
      mFailed.store(true, std::memory_order_relaxed);
      return false;
    }
  }
  /// Throws what an iteration threw, if one did (after the loop).
  void rethrow() const {
    if (mFailure) std::rethrow_exception(mFailure);
  }

 private:
  std::atomic<bool> mFailed{false};
  std::mutex mMutex;
  std::exception_ptr mFailure;
};

}  // namespace hyb
