// The simulation clock: event order, ties, cancellation, events that schedule events, the
// meaning of advance_to, and the real-time driver's pace.
#include "icars/clock/sim_clock.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <string>
#include <thread>
#include <vector>

namespace icars {
namespace {

using namespace std::chrono_literals;

TEST(Time, FormatsDayAndTimeOfDay) {
  EXPECT_EQ(format_time(Time{0}), "d0 00:00:00");
  EXPECT_EQ(format_time(at_time(0, 18, 5)), "d0 18:05:00");
  EXPECT_EQ(format_time(at_time(2, 7, 30, 9)), "d2 07:30:09");
  EXPECT_EQ(format_time(at_time(1, 0, 0) + 250ms), "d1 00:00:00.250");
}

TEST(Time, ParsesTimesOfDayAndRejectsNonsense) {
  EXPECT_EQ(parse_time_of_day("18:00"), Time(18h));
  EXPECT_EQ(parse_time_of_day("07:05:30"), Time(7h + 5min + 30s));
  EXPECT_EQ(parse_time_of_day("7:05"), Time(7h + 5min));
  EXPECT_EQ(parse_time_of_day("23:59:59"), Time(23h + 59min + 59s));
  for (const char* bad : {"25:99", "24:00", "12:60", "12:00:60", "", "7", "07:00pm", "-1:00",
                          "07:5", "a:bc", "07:00:"}) {
    EXPECT_FALSE(parse_time_of_day(bad)) << bad;
  }
}

TEST(SimClock, RunsEventsInTimeOrder) {
  SimClock clock;
  std::vector<int> order;
  clock.schedule_at(30ms, [&] { order.push_back(3); });
  clock.schedule_at(10ms, [&] { order.push_back(1); });
  clock.schedule_at(20ms, [&] { order.push_back(2); });
  EXPECT_EQ(clock.pending(), 3u);
  EXPECT_EQ(clock.next_event_time(), Time(10ms));
  clock.advance_to(100ms);
  EXPECT_EQ(order, (std::vector<int>{1, 2, 3}));
  EXPECT_EQ(clock.pending(), 0u);
  EXPECT_FALSE(clock.next_event_time());
}

TEST(SimClock, EqualTimesRunInSchedulingOrder) {
  SimClock clock;
  std::vector<int> order;
  for (int i = 0; i < 50; ++i) clock.schedule_at(5ms, [&order, i] { order.push_back(i); });
  clock.advance_by(5ms);
  ASSERT_EQ(order.size(), 50u);
  for (int i = 0; i < 50; ++i) EXPECT_EQ(order[static_cast<std::size_t>(i)], i);
}

TEST(SimClock, NowIsTheEventsTimeDuringTheEventAndTheTargetAfterwards) {
  SimClock clock(1000ms);
  std::vector<Time> seen;
  clock.schedule_after(250ms, [&] { seen.push_back(clock.now()); });
  clock.schedule_at(1700ms, [&] { seen.push_back(clock.now()); });
  clock.advance_to(2000ms);
  EXPECT_EQ(seen, (std::vector<Time>{1250ms, 1700ms}));
  EXPECT_EQ(clock.now(), Time(2000ms));
}

TEST(SimClock, AdvanceStopsAtTheTargetAndLeavesLaterEventsPending) {
  SimClock clock;
  int ran = 0;
  clock.schedule_at(10ms, [&] { ++ran; });
  clock.schedule_at(11ms, [&] { ++ran; });
  clock.advance_to(10ms);  // due at exactly t: runs
  EXPECT_EQ(ran, 1);
  EXPECT_EQ(clock.now(), Time(10ms));
  EXPECT_EQ(clock.pending(), 1u);
  clock.advance_to(5ms);  // time never goes back
  EXPECT_EQ(clock.now(), Time(10ms));
  EXPECT_EQ(ran, 1);
}

TEST(SimClock, PastTimesRunAtTheNextAdvance) {
  SimClock clock(100ms);
  Time when{-1};
  clock.schedule_at(10ms, [&] { when = clock.now(); });
  EXPECT_EQ(when, Time(-1));  // never inside the call
  clock.advance_by(0ms);
  EXPECT_EQ(when, Time(100ms));
}

TEST(SimClock, CancelledEventsNeverRun) {
  SimClock clock;
  bool a = false;
  bool b = false;
  const auto ida = clock.schedule_at(10ms, [&] { a = true; });
  clock.schedule_at(10ms, [&] { b = true; });
  EXPECT_TRUE(clock.cancel(ida));
  EXPECT_FALSE(clock.cancel(ida));   // twice
  EXPECT_FALSE(clock.cancel(9999));  // never existed
  clock.advance_to(20ms);
  EXPECT_FALSE(a);
  EXPECT_TRUE(b);
  EXPECT_EQ(clock.pending(), 0u);
}

TEST(SimClock, EventsMayScheduleAndCancelEvents) {
  SimClock clock;
  std::vector<std::string> log;
  std::uint64_t doomed = 0;
  clock.schedule_at(10ms, [&] {
    log.push_back("first@" + std::to_string(clock.now().count()));
    clock.schedule_after(5ms,
                         [&] { log.push_back("child@" + std::to_string(clock.now().count())); });
    clock.schedule_after(0ms, [&] { log.push_back("now@" + std::to_string(clock.now().count())); });
    clock.schedule_after(500ms, [&] { log.push_back("too late"); });
    EXPECT_TRUE(clock.cancel(doomed));
  });
  doomed = clock.schedule_at(12ms, [&] { log.push_back("doomed"); });
  clock.schedule_at(20ms, [&] { log.push_back("last@" + std::to_string(clock.now().count())); });
  clock.advance_to(100ms);
  EXPECT_EQ(log, (std::vector<std::string>{"first@10", "now@10", "child@15", "last@20"}));
  EXPECT_EQ(clock.pending(), 1u);
}

TEST(SimClock, AChainOfEventsRunsWithinOneAdvance) {
  SimClock clock;
  int count = 0;
  std::function<void()> tick = [&] {
    if (++count < 100) clock.schedule_after(1s, tick);
  };
  clock.schedule_after(1s, tick);
  clock.advance_by(1min);
  EXPECT_EQ(count, 60);
  clock.advance_by(1h);
  EXPECT_EQ(count, 100);
}

TEST(SimClock, AdvancingFromInsideAnEventIsRefused) {
  SimClock clock;
  bool threw = false;
  clock.schedule_at(1ms, [&] {
    try {
      clock.advance_by(1ms);
    } catch (const std::logic_error&) {
      threw = true;
    }
  });
  clock.advance_to(10ms);
  EXPECT_TRUE(threw);
  EXPECT_EQ(clock.now(), Time(10ms));
}

TEST(SimClock, AnExceptionStopsTheAdvanceAtThatEvent) {
  SimClock clock;
  bool later = false;
  clock.schedule_at(5ms, [] { throw std::runtime_error("boom"); });
  clock.schedule_at(8ms, [&] { later = true; });
  EXPECT_THROW(clock.advance_to(10ms), std::runtime_error);
  EXPECT_EQ(clock.now(), Time(5ms));
  EXPECT_FALSE(later);
  clock.advance_to(10ms);
  EXPECT_TRUE(later);
}

TEST(SimClock, SchedulingFromManyThreadsKeepsEveryEvent) {
  SimClock clock;
  std::atomic<int> ran{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < 250; ++i) {
        clock.schedule_at(Time(i * 4 + t), [&] { ran.fetch_add(1); });
      }
    });
  }
  for (auto& th : threads) th.join();
  clock.advance_to(1s);
  EXPECT_EQ(ran.load(), 1000);
}

// Waits (in wall time) until `pred` holds or `limit` passes.
template <typename Pred>
bool wait_for(Pred pred, std::chrono::milliseconds limit = 10s) {
  const auto deadline = std::chrono::steady_clock::now() + limit;
  while (!pred()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

TEST(RealTimeDriver, AdvancesAtAboutTheSpeedup) {
  SimClock clock(at_time(0, 18, 0));
  std::atomic<bool> fired{false};
  clock.schedule_at(at_time(0, 18, 0, 30), [&] { fired = true; });
  RealTimeDriver driver(clock, 100.0, 100ms);  // 30 s simulated = 0.3 s wall
  const auto wall_start = std::chrono::steady_clock::now();
  driver.start();
  EXPECT_TRUE(driver.running());
  ASSERT_TRUE(wait_for([&] { return fired.load(); }));
  const auto wall = std::chrono::steady_clock::now() - wall_start;
  // 0.3 s at exactly 100x; generous bounds for a loaded machine.
  EXPECT_GE(wall, 250ms);
  EXPECT_LT(wall, 5s);
  driver.stop();
  EXPECT_FALSE(driver.running());
  const auto stopped_at = clock.now();
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(clock.now(), stopped_at);  // stop() really stops
}

TEST(RealTimeDriver, SimulatedTimeTracksWallTimeTimesSpeedup) {
  SimClock clock;
  RealTimeDriver driver(clock, 1000.0, 50ms);
  const auto wall_start = std::chrono::steady_clock::now();
  driver.start();
  ASSERT_TRUE(wait_for([&] { return clock.now() >= Time(200s); }));
  driver.stop();
  const auto wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start);
  const auto sim = std::chrono::duration<double>(clock.now());
  // The simulation never runs ahead of wall time * speedup (plus one tick)...
  EXPECT_LE(sim.count(), wall.count() * 1000.0 + 0.05);
  // ...and got to 200 s in well under the 200 s a 1x clock would take.
  EXPECT_LT(wall.count(), 20.0);
}

TEST(RealTimeDriver, RestartsFromTheCurrentTimeAndStopsOnDestruction) {
  SimClock clock;
  {
    RealTimeDriver driver(clock, 1000.0);
    driver.start();
    driver.start();  // no-op
    ASSERT_TRUE(wait_for([&] { return clock.now() >= Time(2s); }));
    driver.stop();
    driver.stop();         // no-op
    clock.advance_by(1h);  // the clock is ours again
    const auto resumed_from = clock.now();
    driver.start();
    ASSERT_TRUE(wait_for([&] { return clock.now() >= resumed_from + 2s; }));
  }  // the destructor stops the thread
  const auto t = clock.now();
  std::this_thread::sleep_for(20ms);
  EXPECT_EQ(clock.now(), t);
}

TEST(RealTimeDriver, RejectsNonsenseSettings) {
  SimClock clock;
  EXPECT_THROW(RealTimeDriver(clock, 0.0), std::invalid_argument);
  EXPECT_THROW(RealTimeDriver(clock, -2.0), std::invalid_argument);
  EXPECT_THROW(RealTimeDriver(clock, 10.0, Time{0}), std::invalid_argument);
}

}  // namespace
}  // namespace icars
