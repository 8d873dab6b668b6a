// The wall clock: real time from a chosen start, timers in time order on the clock's thread,
// cancellation, timers that set timers, and pending timers dropped at the end.
#include "icars/clock/wall_clock.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace icars {
namespace {

using namespace std::chrono_literals;

// What timers did, waited for with a generous bound.
class Log {
 public:
  void add(const std::string& entry) {
    {
      std::lock_guard lock(mutex_);
      entries_.push_back(entry);
    }
    changed_.notify_all();
  }
  bool wait_for(std::size_t n) {
    std::unique_lock lock(mutex_);
    return changed_.wait_for(lock, 20s, [&] { return entries_.size() >= n; });
  }
  std::vector<std::string> entries() {
    std::lock_guard lock(mutex_);
    return entries_;
  }

 private:
  std::mutex mutex_;
  std::condition_variable changed_;
  std::vector<std::string> entries_;
};

TEST(WallClock, CountsRealTimeFromItsStart) {
  const auto start = at_time(0, 22, 0);
  WallClock clock(start);
  const auto first = clock.now();
  EXPECT_GE(first, start);
  std::this_thread::sleep_for(20ms);  // real time must pass for a wall clock to move
  EXPECT_GE(clock.now() - first, 20ms);
  WallClock local;  // day 0 is today: the time of day, less than a day
  EXPECT_LT(local.now(), kDay + 1min);
}

TEST(WallClock, RunsTimersInTimeOrderOnItsOwnThread) {
  WallClock clock(Time{0});
  Log log;
  std::atomic<bool> on_clock_thread{true};
  const auto test_thread = std::this_thread::get_id();
  const auto note = [&](std::string name) {
    return [&, name] {
      if (std::this_thread::get_id() == test_thread) on_clock_thread = false;
      log.add(name);
    };
  };
  const auto base = clock.now();
  clock.schedule_at(base + 60ms, note("c"));
  clock.schedule_at(base + 20ms, note("a"));
  clock.schedule_at(base + 20ms, note("b"));  // same time: after "a", set earlier
  clock.schedule_after(-5s, note("now"));     // in the past: at once
  ASSERT_TRUE(log.wait_for(4));
  EXPECT_EQ(log.entries(), (std::vector<std::string>{"now", "a", "b", "c"}));
  EXPECT_TRUE(on_clock_thread);
  EXPECT_GE(clock.now() - base, 60ms);
}

TEST(WallClock, ACancelledTimerNeverRunsAndATimerMaySetAnother) {
  WallClock clock(Time{0});
  Log log;
  const auto dropped = clock.schedule_after(30ms, [&] { log.add("cancelled"); });
  clock.schedule_after(10ms, [&] {
    log.add("first");
    clock.schedule_after(40ms, [&] { log.add("second"); });
  });
  EXPECT_TRUE(clock.cancel(dropped));
  EXPECT_FALSE(clock.cancel(dropped));
  EXPECT_FALSE(clock.cancel(12345));
  ASSERT_TRUE(log.wait_for(2));
  EXPECT_EQ(log.entries(), (std::vector<std::string>{"first", "second"}));
  EXPECT_EQ(clock.pending(), 0u);
}

TEST(WallClock, PendingTimersAreDroppedWhenTheClockEnds) {
  auto owned = std::make_shared<int>(1);
  std::atomic<bool> ran{false};
  {
    WallClock clock(Time{0});
    clock.schedule_after(1h, [&ran, owned] { ran = true; });
    EXPECT_EQ(owned.use_count(), 2);
  }
  EXPECT_FALSE(ran);
  EXPECT_EQ(owned.use_count(), 1);  // the dropped timer let go of what it held
}

}  // namespace
}  // namespace icars
