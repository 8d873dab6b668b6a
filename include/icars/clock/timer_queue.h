// The timers of a clock (SimClock, WallClock): functions by the time they are due, timers due at
// the same time in the order they were scheduled, each with an id to cancel it by. Not
// thread-safe: a clock holds its lock around every call.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <unordered_map>
#include <utility>

#include "icars/clock/time.h"

namespace icars::detail {

class TimerQueue {
 public:
  // Adds a timer due at `t`; returns its id (ids start at 1 and grow).
  std::uint64_t add(Time t, std::function<void()> fn) {
    const auto id = next_id_++;
    queue_.emplace(Key{t, id}, std::move(fn));
    times_.emplace(id, t);
    return id;
  }

  // Removes timer `id`: true, with its function moved to `removed` (for the caller to destroy
  // outside its lock: it may own anything), or false when there is no such timer.
  bool remove(std::uint64_t id, std::function<void()>& removed) {
    const auto it = times_.find(id);
    if (it == times_.end()) return false;
    const auto entry = queue_.find(Key{it->second, id});
    removed = std::move(entry->second);
    queue_.erase(entry);
    times_.erase(it);
    return true;
  }

  bool empty() const { return queue_.empty(); }
  std::size_t size() const { return queue_.size(); }
  Time next_due() const { return queue_.begin()->first.first; }  // not empty()

  // Removes the timer due first (not empty()): when it was due, and its function.
  std::pair<Time, std::function<void()>> pop() {
    auto node = queue_.extract(queue_.begin());
    times_.erase(node.key().second);
    return {node.key().first, std::move(node.mapped())};
  }

  // Removes every timer; their functions, for the caller to destroy outside its lock.
  std::map<std::pair<Time, std::uint64_t>, std::function<void()>> take_all() {
    times_.clear();
    return std::exchange(queue_, {});
  }

 private:
  using Key = std::pair<Time, std::uint64_t>;  // (time, id): ids grow, so ties keep their order

  std::uint64_t next_id_ = 1;
  std::map<Key, std::function<void()>> queue_;
  std::unordered_map<std::uint64_t, Time> times_;  // id -> time, for remove()
};

}  // namespace icars::detail
