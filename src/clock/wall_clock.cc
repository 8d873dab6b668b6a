#include "icars/clock/wall_clock.h"

#include <ctime>

namespace icars {
namespace {

Time local_time_of_day() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm local{};
  localtime_r(&t, &local);
  return std::chrono::hours(local.tm_hour) + std::chrono::minutes(local.tm_min) +
         std::chrono::seconds(local.tm_sec);
}

}  // namespace

WallClock::WallClock() : WallClock(local_time_of_day()) {}

WallClock::WallClock(Time start)
    : origin_(std::chrono::steady_clock::now()), start_(start), thread_([this] { run(); }) {}

WallClock::~WallClock() {
  decltype(timers_.take_all()) dropped;  // destroyed outside the lock
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
    dropped = timers_.take_all();
  }
  wake_.notify_all();
  thread_.join();
}

Time WallClock::now() const {
  return start_ + std::chrono::duration_cast<Time>(std::chrono::steady_clock::now() - origin_);
}

std::chrono::steady_clock::time_point WallClock::wall_for(Time t) const {
  return origin_ + (t - start_);
}

std::uint64_t WallClock::schedule_at(Time t, std::function<void()> fn) {
  std::uint64_t id = 0;
  {
    std::lock_guard lock(mutex_);
    id = timers_.add(t, std::move(fn));
  }
  wake_.notify_all();
  return id;
}

std::uint64_t WallClock::schedule_after(Time delay, std::function<void()> fn) {
  return schedule_at(now() + (delay < Time{0} ? Time{0} : delay), std::move(fn));
}

bool WallClock::cancel(std::uint64_t id) {
  std::function<void()> dropped;  // destroyed outside the lock: it may own anything
  std::lock_guard lock(mutex_);
  return timers_.remove(id, dropped);
}

std::size_t WallClock::pending() const {
  std::lock_guard lock(mutex_);
  return timers_.size();
}

void WallClock::run() {
  std::unique_lock lock(mutex_);
  for (;;) {
    if (stopping_) return;
    if (timers_.empty()) {
      wake_.wait(lock);
      continue;
    }
    const auto due = wall_for(timers_.next_due());
    if (std::chrono::steady_clock::now() < due) {
      wake_.wait_until(lock, due);  // woken early by a sooner timer, a cancel or the end
      continue;
    }
    auto fn = timers_.pop().second;
    lock.unlock();
    fn();
    fn = nullptr;  // what the timer owned goes before the lock is taken again
    lock.lock();
  }
}

}  // namespace icars
