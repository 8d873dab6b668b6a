#include "icars/clock/sim_clock.h"

#include <cmath>
#include <stdexcept>

namespace icars {

SimClock::SimClock(Time start) : now_(start) {}

Time SimClock::now() const {
  std::lock_guard lock(mutex_);
  return now_;
}

std::uint64_t SimClock::schedule_at(Time t, std::function<void()> fn) {
  std::lock_guard lock(mutex_);
  if (t < now_) t = now_;
  const auto id = next_id_++;
  queue_.emplace(Key{t, id}, std::move(fn));
  times_.emplace(id, t);
  return id;
}

std::uint64_t SimClock::schedule_after(Time delay, std::function<void()> fn) {
  std::lock_guard lock(mutex_);
  const auto t = now_ + (delay < Time{0} ? Time{0} : delay);
  const auto id = next_id_++;
  queue_.emplace(Key{t, id}, std::move(fn));
  times_.emplace(id, t);
  return id;
}

bool SimClock::cancel(std::uint64_t id) {
  std::function<void()> dropped;  // destroyed outside the lock: it may own anything
  std::lock_guard lock(mutex_);
  const auto it = times_.find(id);
  if (it == times_.end()) return false;
  const auto entry = queue_.find(Key{it->second, id});
  dropped = std::move(entry->second);
  queue_.erase(entry);
  times_.erase(it);
  return true;
}

void SimClock::advance_to(Time t) {
  {
    std::lock_guard lock(mutex_);
    if (advancing_thread_ == std::this_thread::get_id()) {
      throw std::logic_error("SimClock::advance_to called from inside one of its own events");
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

  for (;;) {
    std::function<void()> fn;
    {
      std::lock_guard lock(mutex_);
      if (queue_.empty() || queue_.begin()->first.first > t) {
        if (t > now_) now_ = t;
        return;
      }
      auto node = queue_.extract(queue_.begin());
      now_ = node.key().first;
      times_.erase(node.key().second);
      fn = std::move(node.mapped());
    }
    fn();
  }
}

void SimClock::advance_by(Time d) { advance_to(now() + d); }

std::size_t SimClock::pending() const {
  std::lock_guard lock(mutex_);
  return queue_.size();
}

std::optional<Time> SimClock::next_event_time() const {
  std::lock_guard lock(mutex_);
  if (queue_.empty()) return std::nullopt;
  return queue_.begin()->first.first;
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
  std::lock_guard lock(mutex_);
  if (thread_.joinable()) return;
  stopping_ = false;
  thread_ = std::thread(
      [this, wall = std::chrono::steady_clock::now(), sim = clock_.now()] { run(wall, sim); });
}

void RealTimeDriver::stop() {
  std::thread thread;
  {
    std::lock_guard lock(mutex_);
    if (!thread_.joinable()) return;
    stopping_ = true;
    thread = std::move(thread_);
  }
  wake_.notify_all();
  thread.join();
}

bool RealTimeDriver::running() const {
  std::lock_guard lock(mutex_);
  return thread_.joinable();
}

void RealTimeDriver::run(std::chrono::steady_clock::time_point wall_start, Time sim_start) {
  using namespace std::chrono;
  const auto wall_for = [&](Time sim) {
    return wall_start + duration_cast<steady_clock::duration>(duration<double, std::milli>(
                            static_cast<double>((sim - sim_start).count()) / speedup_));
  };
  Time next = sim_start + tick_;
  for (;;) {
    {
      std::unique_lock lock(mutex_);
      if (wake_.wait_until(lock, wall_for(next), [this] { return stopping_; })) return;
    }
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
