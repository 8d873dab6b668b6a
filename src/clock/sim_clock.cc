#include "icars/clock/sim_clock.h"

#include <cmath>
#include <stdexcept>
#include <tuple>

namespace icars {

SimClock::SimClock(Time start) : now_(start) {}

Time SimClock::now() const {
  std::lock_guard lock(mutex_);
  return now_;
}

std::uint64_t SimClock::schedule_at(Time t, std::function<void()> fn) {
  std::lock_guard lock(mutex_);
  return timers_.add(t < now_ ? now_ : t, std::move(fn));
}

std::uint64_t SimClock::schedule_after(Time delay, std::function<void()> fn) {
  std::lock_guard lock(mutex_);
  return timers_.add(now_ + (delay < Time{0} ? Time{0} : delay), std::move(fn));
}

bool SimClock::cancel(std::uint64_t id) {
  std::function<void()> dropped;  // destroyed outside the lock: it may own anything
  std::lock_guard lock(mutex_);
  return timers_.remove(id, dropped);
}

void SimClock::advance_to(Time t) { advance(t, false); }

bool SimClock::step(Time limit) { return advance(limit, true); }

bool SimClock::advance(Time t, bool one_event) {
  {
    std::lock_guard lock(mutex_);
    if (advancing_thread_ == std::this_thread::get_id()) {
      throw std::logic_error("SimClock advanced from inside one of its own events");
    }
  }
  std::lock_guard advancing(advance_mutex_);
  {
    std::lock_guard lock(mutex_);
    advancing_thread_ = std::this_thread::get_id();
  }
  struct Reset {
    SimClock& clock;
    ~Reset() {
      std::lock_guard lock(clock.mutex_);
      clock.advancing_thread_ = {};
    }
  } reset{*this};

  for (bool ran = false;;) {
    std::function<void()> fn;
    {
      std::lock_guard lock(mutex_);
      if (one_event && ran) return true;
      if (timers_.empty() || timers_.next_due() > t) {
        if (!one_event && t > now_) now_ = t;
        return ran;
      }
      std::tie(now_, fn) = timers_.pop();
    }
    ran = true;
    fn();
  }
}

void SimClock::advance_by(Time d) { advance_to(now() + d); }

std::size_t SimClock::pending() const {
  std::lock_guard lock(mutex_);
  return timers_.size();
}

std::optional<Time> SimClock::next_event_time() const {
  std::lock_guard lock(mutex_);
  if (timers_.empty()) return std::nullopt;
  return timers_.next_due();
}

// --- RealTimeDriver ------------------------------------------------------------------------

RealTimeDriver::RealTimeDriver(SimClock& clock, double speedup, Time tick)
    : clock_(clock), speedup_(speedup), tick_(tick) {
  if (!(speedup > 0) || !std::isfinite(speedup)) {
    throw std::invalid_argument("RealTimeDriver: speedup must be a positive number");
  }
  if (tick <= Time{0}) throw std::invalid_argument("RealTimeDriver: tick must be positive");
}

RealTimeDriver::~RealTimeDriver() { stop(); }

void RealTimeDriver::start() {
  thread_.start([this, wall = std::chrono::steady_clock::now(), sim = clock_.now()] { run(wall, sim); });
}

void RealTimeDriver::stop() { thread_.stop(); }

bool RealTimeDriver::running() const { return thread_.running(); }

void RealTimeDriver::run(std::chrono::steady_clock::time_point wall_start, Time sim_start) {
  using namespace std::chrono;
  const auto wall_for = [&](Time sim) {
    return wall_start + duration_cast<steady_clock::duration>(duration<double, std::milli>(
                            static_cast<double>((sim - sim_start).count()) / speedup_));
  };
  Time next = sim_start + tick_;
  for (;;) {
    if (!thread_.wait_until(wall_for(next))) return;
    // Catch up in one advance if events ran slower than real time.
    const auto elapsed = duration<double, std::milli>(steady_clock::now() - wall_start).count();
    const auto ticks =
        static_cast<std::int64_t>(elapsed * speedup_ / static_cast<double>(tick_.count()));
    const Time target = std::max(next, sim_start + tick_ * ticks);
    clock_.advance_to(target);
    next = target + tick_;
  }
}

}  // namespace icars
