// Follows the simulated time of a house whose device managers run in other processes: polls
// the Simulation service's clock and advances a clock of the mediating server's own to it, so
// behaviors' timers count in the house's time.
#pragma once

#include <atomic>
#include <chrono>
#include <thread>

#include "icars/clock/sim_clock.h"
#include "icars/service/service_container.h"

namespace icars::home {

class ClockFollower {
 public:
  // Starts polling every `every` (a call is tens of microseconds; at 1500x, 5 ms of wall time
  // are 7.5 s simulated). `clock` and `services` must outlive the follower.
  ClockFollower(SimClock& clock, service::ServiceContainer& services,
                std::chrono::milliseconds every = std::chrono::milliseconds(5));
  ~ClockFollower();  // stops polling
  ClockFollower(const ClockFollower&) = delete;
  ClockFollower& operator=(const ClockFollower&) = delete;

  // True once the house's time was read at least once.
  bool following() const { return following_; }

 private:
  void run();

  SimClock& clock_;
  service::ServiceContainer& services_;
  const std::chrono::milliseconds every_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> following_{false};
  std::thread thread_;
};

}  // namespace icars::home
