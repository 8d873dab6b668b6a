// The clock that behaviors, tasks and the mediating server read time from and set timers on.
//
// Nothing above the simulator knows which clock it runs on: a SimClock (deterministic,
// advanced by a test or driven faster than real time; icars/clock/sim_clock.h) in scenarios and
// tests, a WallClock (icars/clock/wall_clock.h) for a home on real time. Implementations are
// thread-safe; timers run one at a time on the clock's own thread (the one advancing a
// SimClock), never under the clock's lock, so a timer may schedule or cancel others.
#pragma once

#include <cstdint>
#include <functional>

#include "icars/clock/time.h"

namespace icars {

class Clock {
 public:
  virtual ~Clock() = default;

  virtual Time now() const = 0;
  // Runs `fn` once the clock reaches `t` (a time in the past: as soon as possible); timers with
  // equal times run in the order they were set. Returns an id for cancel(), never 0.
  virtual std::uint64_t schedule_at(Time t, std::function<void()> fn) = 0;
  virtual std::uint64_t schedule_after(Time delay, std::function<void()> fn) = 0;
  // True if the timer was pending and will now never run; false if it already ran, is
  // running, was cancelled before, or never existed.
  virtual bool cancel(std::uint64_t id) = 0;
};

}  // namespace icars
