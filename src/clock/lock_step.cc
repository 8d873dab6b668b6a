#include "icars/clock/lock_step.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace icars {

LockStepDriver::LockStepDriver(SimClock& clock, Activity& activity, LockStepOptions options)
    : clock_(clock), activity_(activity), options_(std::move(options)) {
  if (!(options_.speedup >= 0) || !std::isfinite(options_.speedup)) {
    throw std::invalid_argument("LockStepDriver: speedup must be 0 (as fast as possible) or positive");
  }
  if (options_.tick <= Time{0}) throw std::invalid_argument("LockStepDriver: tick must be positive");
  if (options_.settle_timeout <= std::chrono::milliseconds{0}) {
    throw std::invalid_argument("LockStepDriver: settle_timeout must be positive");
  }
}

LockStepDriver::~LockStepDriver() { stop(); }

void LockStepDriver::start() {
  {
    std::lock_guard lock(mutex_);
    if (finished_) return;
  }
  thread_.start([this] { run(std::chrono::steady_clock::now(), clock_.now()); });
}

void LockStepDriver::stop() {
  thread_.stop();
  done_.notify_all();
}

void LockStepDriver::request_stop() {
  thread_.request_stop();
  done_.notify_all();
}

bool LockStepDriver::running() const { return thread_.running() && !finished(); }

bool LockStepDriver::finished() const {
  std::lock_guard lock(mutex_);
  return finished_;
}

bool LockStepDriver::wait_finished(std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  if (timeout == std::chrono::milliseconds::max()) {
    done_.wait(lock, [this] { return finished_ || thread_.stopping(); });
  } else {
    done_.wait_for(lock, timeout, [this] { return finished_ || thread_.stopping(); });
  }
  return finished_;
}

void LockStepDriver::set_speedup(double speedup) {
  if (!(speedup >= 0) || !std::isfinite(speedup)) {
    throw std::invalid_argument("LockStepDriver: speedup must be 0 (as fast as possible) or positive");
  }
  const bool was_running = running();
  stop();
  {
    std::lock_guard lock(mutex_);
    options_.speedup = speedup;  // run() reads it when it starts
  }
  if (was_running) start();
}

double LockStepDriver::speedup() const {
  std::lock_guard lock(mutex_);
  return options_.speedup;
}

std::uint64_t LockStepDriver::events_run() const {
  std::lock_guard lock(mutex_);
  return events_run_;
}

std::uint64_t LockStepDriver::settle_timeouts() const {
  std::lock_guard lock(mutex_);
  return settle_timeouts_;
}

void LockStepDriver::settle() {
  if (activity_.settle(options_.settle_timeout)) return;
  {
    std::lock_guard lock(mutex_);
    ++settle_timeouts_;
  }
  if (options_.warn) {
    options_.warn(clock_.now(), fmt::format("lock-step: work started at this time was still under way after {} ms "
                                            "({} pieces); the clock goes on",
                                            options_.settle_timeout.count(), activity_.busy()));
  }
}

void LockStepDriver::run(std::chrono::steady_clock::time_point wall_start, Time sim_start) {
  using namespace std::chrono;
  const double speedup = this->speedup();
  const auto wall_for = [&](Time sim) {
    return wall_start + duration_cast<steady_clock::duration>(
                            duration<double, std::milli>(static_cast<double>((sim - sim_start).count()) / speedup));
  };
  const auto sim_for = [&](steady_clock::time_point wall) {
    return sim_start + duration_cast<Time>(duration<double, std::milli>(
                           duration<double, std::milli>(wall - wall_start).count() * speedup));
  };
  const auto wait_until = [&](steady_clock::time_point wall) { return thread_.wait_until(wall); };

  settle();  // what is already under way finishes at the clock's present time
  for (;;) {
    if (thread_.stopping()) return;
    const auto next = clock_.next_event_time();
    const bool due = next && *next <= options_.until;
    if (!due && options_.until == Time::max()) {
      // Nothing will ever happen unless something from outside schedules it.
      if (!wait_until(steady_clock::now() + milliseconds(10))) return;
      continue;
    }
    const Time target = due ? std::max(*next, clock_.now()) : options_.until;
    if (speedup > 0) {
      const Time allowed = sim_for(steady_clock::now());
      if (allowed < target) {
        // Not yet: move now() towards the next event in ticks, running nothing.
        const Time to = std::min(target, std::max(clock_.now(), allowed) + options_.tick);
        if (!wait_until(wall_for(to))) return;
        if (to < target) {
          clock_.advance_to(to);  // runs only what something outside scheduled meanwhile
          settle();
        }
        continue;
      }
    }
    if (due) {
      clock_.step(options_.until);
      {
        std::lock_guard lock(mutex_);
        ++events_run_;
      }
      settle();
      continue;
    }
    clock_.advance_to(options_.until);
    settle();
    if (clock_.next_event_time().value_or(Time::max()) <= options_.until) continue;  // scheduled meanwhile
    {
      std::lock_guard lock(mutex_);
      finished_ = true;
    }
    done_.notify_all();
    return;
  }
}

}  // namespace icars
