// The clock of a home on real time: now() follows the machine's steady clock, and timers run
// on the clock's own thread when their time has come.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <utility>

#include "icars/clock/clock.h"
#include "icars/clock/timer_queue.h"

namespace icars {

class WallClock final : public Clock {
 public:
  // Day 0 is the local day the clock starts on, so now() is the local time of day (a policy's
  // "22:00" is ten at night); `start` gives another start instead (a house's start time).
  WallClock();
  explicit WallClock(Time start);
  // Pending timers never run; a timer running on the clock's thread is waited for, so the
  // clock must not be destroyed from inside one of its own timers.
  ~WallClock() override;
  WallClock(const WallClock&) = delete;
  WallClock& operator=(const WallClock&) = delete;

  Time now() const override;
  std::uint64_t schedule_at(Time t, std::function<void()> fn) override;
  std::uint64_t schedule_after(Time delay, std::function<void()> fn) override;
  bool cancel(std::uint64_t id) override;

  std::size_t pending() const;

 private:
  void run();
  std::chrono::steady_clock::time_point wall_for(Time t) const;

  const std::chrono::steady_clock::time_point origin_;
  const Time start_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  detail::TimerQueue timers_;
  bool stopping_ = false;
  std::thread thread_;
};

}  // namespace icars
