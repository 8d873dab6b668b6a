// Lock-step: a SimClock that moves only when what its last event started has finished.
//
// A RealTimeDriver (sim_clock.h) moves the clock with the wall clock, whatever the threads
// reacting to it are doing: at 20000x a reaction that takes 3 ms of wall time comes a simulated
// minute late, and two runs differ. A LockStepDriver runs the clock's events one at a time and,
// after each, waits until the Activity (activity.h) has settled — the messages the event caused
// handled, the behaviors' handlers run, the replies back — before it runs the next. A reaction
// then happens at the simulated instant of its cause, and a run gives the same trace at any
// speed. `speedup` paces it against the wall clock (never ahead of it; behind it when the
// machine is slower); 0 runs as fast as the work allows.
//
//   LockStepDriver driver(clock, *activity, {.speedup = 0, .until = at_time(1, 7, 0)});
//   driver.start();
//   driver.wait_finished();   // the clock is at 07:00 of day 1
#pragma once

#include <chrono>
#include <condition_variable>
#include <functional>
#include <limits>
#include <mutex>
#include <string>
#include <thread>

#include "icars/clock/activity.h"
#include "icars/clock/driver_thread.h"
#include "icars/clock/sim_clock.h"

namespace icars {

struct LockStepOptions {
  double speedup = 0;  // simulated seconds per wall second; 0: as fast as the work allows
  Time until = Time::max();  // the driver stops with the clock here (events due then have run)
  // How long to wait for the work of one event before advancing anyway (and warning): work
  // that never finishes (a thread blocked, a peer that never answers) must not stop the house.
  std::chrono::milliseconds settle_timeout{10000};
  // While it paces a gap between events, now() moves in steps of at most this much (for
  // whoever watches the clock); no events run then.
  Time tick{100};
  // Told when an event's work did not settle in time, with the simulated time.
  std::function<void(Time, const std::string&)> warn;
};

class LockStepDriver {
 public:
  LockStepDriver(SimClock& clock, Activity& activity, LockStepOptions options = {});
  ~LockStepDriver();  // stops
  LockStepDriver(const LockStepDriver&) = delete;
  LockStepDriver& operator=(const LockStepDriver&) = delete;

  // Settles what is already under way, then runs the clock on the driver's thread. No-op when
  // running; after stop(), resumes from the clock's time (pacing from then).
  void start();
  // Returns once the current event's work has settled (or timed out); no-op when stopped.
  void stop();
  // Asks the driver to stop after the current event's work, without waiting (from any thread,
  // an event included); stop() then joins it.
  void request_stop();
  bool running() const;
  // True once the clock has reached `until`.
  bool finished() const;
  // Waits until finished(), stop() or `timeout`; true when finished.
  bool wait_finished(std::chrono::milliseconds timeout = std::chrono::milliseconds::max());

  // Paces from now on at `speedup` (0: as fast as the work allows): stops, and starts again if
  // it was running. Throws std::invalid_argument for a negative or non-finite speedup.
  void set_speedup(double speedup);
  double speedup() const;

  std::uint64_t events_run() const;
  std::uint64_t settle_timeouts() const;

 private:
  void run(std::chrono::steady_clock::time_point wall_start, Time sim_start);
  void settle();

  SimClock& clock_;
  Activity& activity_;
  LockStepOptions options_;  // speedup changes under mutex_ (set_speedup), the rest is fixed
  mutable std::mutex mutex_;      // guards what follows
  std::condition_variable done_;  // finished, or a stop asked for
  bool finished_ = false;
  std::uint64_t events_run_ = 0;
  std::uint64_t settle_timeouts_ = 0;
  detail::DriverThread thread_;
};

}  // namespace icars
