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
  std::map<Key, std::function<void()>> dropped;  // destroyed outside the lock
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
    dropped.swap(queue_);
    times_.clear();
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
    id = next_id_++;
    queue_.emplace(Key{t, id}, std::move(fn));
    times_.emplace(id, t);
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
  const auto it = times_.find(id);
  if (it == times_.end()) return false;
  const auto entry = queue_.find(Key{it->second, id});
  dropped = std::move(entry->second);
  queue_.erase(entry);
  times_.erase(it);
  return true;
}

std::size_t WallClock::pending() const {
  std::lock_guard lock(mutex_);
  return queue_.size();
}

void WallClock::run() {
  std::unique_lock lock(mutex_);
  for (;;) {
    if (stopping_) return;
    if (queue_.empty()) {
      wake_.wait(lock);
      continue;
    }
    const auto due = wall_for(queue_.begin()->first.first);
    if (std::chrono::steady_clock::now() < due) {
      wake_.wait_until(lock, due);  // woken early by a sooner timer, a cancel or the end
      continue;
    }
    auto node = queue_.extract(queue_.begin());
    times_.erase(node.key().second);
    auto fn = std::move(node.mapped());
    lock.unlock();
    fn();
    fn = nullptr;  // what the timer owned goes before the lock is taken again
    lock.lock();
  }
}

}  // namespace icars
