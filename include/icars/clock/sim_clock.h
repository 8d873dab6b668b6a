// The simulated clock: deterministic discrete-event time, optionally driven at a multiple of
// wall-clock speed. The simulated house runs on it, and so do the tests of every layer above.
//
// Everything in the simulated house happens as events on one SimClock: a user's scheduled
// activity, a step of a robot's motion, the delivery of an utterance. Events run in time
// order, and in the order they were scheduled when their times are equal, on the thread that
// advances the clock — so a run is a pure function of its inputs, and a test advances time
// by hand (`advance_by(10min)`) while a demo lets a RealTimeDriver advance it at, say, 60x.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_map>
#include <utility>

#include "icars/clock/clock.h"
#include "icars/clock/driver_thread.h"
#include "icars/clock/timer_queue.h"

namespace icars {

// A discrete-event clock. All methods are thread-safe; events run on the thread that calls
// advance_to/advance_by, never under the clock's lock, so an event may schedule, cancel or
// query freely (but not advance the clock: that throws std::logic_error).
class SimClock final : public Clock {
 public:
  explicit SimClock(Time start = Time{0});
  SimClock(const SimClock&) = delete;
  SimClock& operator=(const SimClock&) = delete;

  Time now() const override;

  // Runs `fn` once the clock reaches `t`; a time in the past means "at the next advance".
  // Events with equal times run in the order they were scheduled. Returns an id for cancel().
  std::uint64_t schedule_at(Time t, std::function<void()> fn) override;
  std::uint64_t schedule_after(Time delay, std::function<void()> fn) override;

  // True if the event was pending and will now never run; false if it already ran, is
  // running, was cancelled before, or never existed.
  bool cancel(std::uint64_t id) override;

  // Runs every event due at or before `t`, in order, including events those events schedule
  // for times <= t; during each event now() is that event's time. Afterwards now() == t
  // (time never goes back: a `t` before now() only runs the events already due). Calls from
  // two threads are serialized. If an event throws, the exception propagates with now() at
  // that event's time and later events still pending.
  void advance_to(Time t);
  void advance_by(Time d);
  // Runs only the next event, if it is due at or before `limit`, with now() at its time
  // (LockStepDriver's step); true when one ran. Like advance_to otherwise.
  bool step(Time limit = Time::max());

  std::size_t pending() const;
  std::optional<Time> next_event_time() const;

 private:
  bool advance(Time t, bool one_event);

  mutable std::mutex mutex_;
  Time now_;
  detail::TimerQueue timers_;

  std::mutex advance_mutex_;          // one advancing thread at a time
  std::thread::id advancing_thread_;  // guarded by mutex_
};

// Advances a SimClock at `speedup` times wall-clock speed on its own thread: every `tick` of
// simulated time (wall time tick / speedup) it advances the clock to the simulated time that
// corresponds to the wall time elapsed since start(). If events run slower than real time the
// driver catches up in one advance instead of drifting. Nothing else should advance the clock
// while the driver runs.
class RealTimeDriver {
 public:
  RealTimeDriver(SimClock& clock, double speedup, Time tick = Time{100});
  ~RealTimeDriver();  // stops
  RealTimeDriver(const RealTimeDriver&) = delete;
  RealTimeDriver& operator=(const RealTimeDriver&) = delete;

  void start();  // no-op when running; after stop(), resumes from the clock's current time
  void stop();   // returns after the current advance (if any) has finished; no-op when stopped
  bool running() const;
  double speedup() const { return speedup_; }

 private:
  void run(std::chrono::steady_clock::time_point wall_start, Time sim_start);

  SimClock& clock_;
  const double speedup_;
  const Time tick_;
  detail::DriverThread thread_;
};

}  // namespace icars
