// The thread of a clock driver (RealTimeDriver, LockStepDriver): a loop started on its own
// thread, paced by waits that a stop request cuts short, and joined by stop().
#pragma once

#include <chrono>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>

namespace icars::detail {

class DriverThread {
 public:
  DriverThread() = default;
  ~DriverThread() { stop(); }
  DriverThread(const DriverThread&) = delete;
  DriverThread& operator=(const DriverThread&) = delete;

  // Runs `loop` on a new thread; false (and nothing runs) when one is running already.
  bool start(std::function<void()> loop);
  // Asks the loop to stop and joins it; no-op when none runs.
  void stop();
  // Asks the loop to stop without waiting (from any thread, the loop's own included).
  void request_stop();
  bool running() const;   // started and not yet joined
  bool stopping() const;  // a stop was asked for since start()
  // For the loop: waits until `wall` or a stop request; false when stopping.
  bool wait_until(std::chrono::steady_clock::time_point wall);

 private:
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread thread_;
};

}  // namespace icars::detail
