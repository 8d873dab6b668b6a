// Decorators on the simulated clock: retry, repeat, timeout and invert — how they complete,
// what halting them releases, and that they are transparent to events.
#include "icars/behavior/decorators.h"

#include <gtest/gtest.h>

#include <atomic>
#include <future>

#include "icars/behavior/composite.h"
#include "tree_test_support.h"

namespace b = icars::behavior;
namespace bt = icars::behavior::testing;
using bt::Action;
using bt::Harness;
using bt::Log;
using bt::node;
using icars::Time;
using namespace std::chrono_literals;

namespace {

// Fails its first `failures` runs, then succeeds; each run takes a minute.
class Flaky : public b::Behavior {
 public:
  Flaky(Log& log, int failures) : log_(log), failures_(failures) {}

 protected:
  void entry() override {
    log_.add(name() + " entry");
    after(1min, [this] {
      if (++runs_ <= failures_) {
        fail(fmt::format("run {} broke", runs_));
      } else {
        succeed();
      }
    });
  }

 private:
  Log& log_;
  int failures_;
  int runs_ = 0;
};

// Succeeds as soon as it starts, counting its runs.
class Instant : public b::Behavior {
 public:
  explicit Instant(std::atomic<long>& runs) : runs_(runs) {}

 protected:
  void entry() override {
    ++runs_;
    succeed();
  }

 private:
  std::atomic<long>& runs_;
};

std::unique_ptr<b::Behavior> wrap(std::unique_ptr<b::Behavior> decorator, std::unique_ptr<b::Behavior> child) {
  decorator->add_child(std::move(child));
  return decorator;
}

}  // namespace

TEST(Retry, RunsAFailingChildAgainUntilItSucceeds) {
  Log log;
  Harness h;
  h.start(wrap(node<b::RetryBehavior>("retry", 3), node<Flaky>("flaky", log, 2)));
  h.advance(2min);
  EXPECT_EQ(log.count("flaky entry"), 3);  // two failures, third attempt running
  EXPECT_FALSE(h.done);
  EXPECT_TRUE(h.traced("note", "T/retry: flaky failed: run 1 broke; attempt 2 of 3"));
  h.advance(1min);
  EXPECT_EQ(h.done, b::Status::succeeded);
}

TEST(Retry, FailsWithTheLastFailureAfterItsAttempts) {
  Log log;
  Harness h;
  h.start(wrap(node<b::RetryBehavior>("retry", 2), node<Action>("act", log, 1min, false)));
  h.advance(2min);
  EXPECT_EQ(log.count("act entry"), 2);
  EXPECT_EQ(h.done, b::Status::failed);
  EXPECT_EQ(h.reason, "act failed 2 times; last: told to fail");
}

TEST(Retry, WaitsItsDelayBeforeEachAttemptAndHaltingCancelsIt) {
  Log log;
  Harness h;
  const auto timers_before = h.clock.pending();
  h.start(wrap(node<b::RetryBehavior>("retry", 0, Time(5min)), node<Flaky>("flaky", log, 5)));
  h.advance(1min);  // the first attempt failed: the next one is 5 minutes away
  EXPECT_EQ(log.count("flaky entry"), 1);
  h.advance(4min);
  EXPECT_EQ(log.count("flaky entry"), 1);
  h.advance(1min);
  EXPECT_EQ(log.count("flaky entry"), 2);
  h.advance(1min);  // failed again; halted while waiting
  h.halt();
  EXPECT_EQ(h.status("retry"), b::Status::halted);
  EXPECT_EQ(h.clock.pending(), timers_before);
  h.advance(1h);
  EXPECT_EQ(log.count("flaky entry"), 2);
  EXPECT_FALSE(h.done);
}

TEST(Repeat, RunsASucceedingChildItsNumberOfTimes) {
  Log log;
  Harness h;
  h.start(wrap(node<b::RepeatBehavior>("repeat", 3), node<Action>("act", log, 10s)));
  h.advance(25s);
  EXPECT_EQ(log.count("act entry"), 3);
  EXPECT_FALSE(h.done);
  h.advance(5s);
  EXPECT_EQ(h.done, b::Status::succeeded);
  EXPECT_EQ(log.count("act entry"), 3);
}

TEST(Repeat, ForeverRunsUntilHaltedAndAFailedRunFailsIt) {
  Log log;
  Harness h;
  h.start(wrap(node<b::RepeatBehavior>("repeat", 0), node<Action>("act", log, 10s)));
  h.advance(105s);
  EXPECT_EQ(log.count("act entry"), 11);
  h.halt();
  EXPECT_EQ(h.status("act"), b::Status::halted);
  EXPECT_EQ(log.get().back(), "act exit");
  EXPECT_FALSE(h.done);

  Log log2;
  Harness h2;
  h2.start(wrap(node<b::RepeatBehavior>("repeat", 0), node<Action>("act", log2, 10s, false)));
  h2.advance(10s);
  EXPECT_EQ(h2.done, b::Status::failed);
  EXPECT_EQ(h2.reason, "act failed on run 1: told to fail");
}

// Such a tree never lets time pass by itself; the runtime still lets inputs in (here: the halt).
TEST(Repeat, ForeverAroundAChildThatCompletesAtOnceDoesNotShutOutTheRuntimesInputs) {
  Harness h;
  std::atomic<long> runs{0};
  h.runtime.run([&] {  // returns once the runtime lets inputs in again; never settles
    h.root = wrap(node<b::RepeatBehavior>("repeat", 0), node<Instant>("instant", runs));
    h.root->attach(h.env, h, "T");
    h.root->start();
  });
  auto halted = std::async(std::launch::async, [&] { h.runtime.run([&] { h.root->halt(); }); });
  ASSERT_EQ(halted.wait_for(120s), std::future_status::ready) << "the halt never got in";
  EXPECT_GT(runs.load(), 1000);
  EXPECT_EQ(h.status("repeat"), b::Status::halted);
  h.settle();
}

TEST(Timeout, CompletesAsItsChildWhenInTime) {
  Log log;
  Harness h;
  const auto timers_before = h.clock.pending();
  h.start(wrap(node<b::TimeoutBehavior>("timeout", Time(30s)), node<Action>("act", log, 10s)));
  h.advance(10s);
  EXPECT_EQ(h.done, b::Status::succeeded);
  EXPECT_EQ(h.clock.pending(), timers_before);  // its timer is gone

  Log log2;
  Harness h2;
  h2.start(wrap(node<b::TimeoutBehavior>("timeout", Time(30s)), node<Action>("act", log2, 10s, false)));
  h2.advance(10s);
  EXPECT_EQ(h2.done, b::Status::failed);
  EXPECT_EQ(h2.reason, "act failed: told to fail");
}

TEST(Timeout, FailsAndHaltsAChildStillRunning) {
  Log log;
  Harness h;
  h.start(wrap(node<b::TimeoutBehavior>("timeout", Time(30s)), node<Action>("act", log, 1min)));
  h.advance(29s);
  EXPECT_FALSE(h.done);
  h.advance(1s);
  EXPECT_EQ(h.done, b::Status::failed);
  EXPECT_EQ(h.reason, "act still running after 00:00:30");
  EXPECT_EQ(h.status("act"), b::Status::halted);
  EXPECT_TRUE(log.has("act exit"));
  EXPECT_TRUE(h.traced("behavior", "T/timeout/act halted"));
}

TEST(Timeout, HaltedMidWayItStopsItsChildAndItsTimer) {
  Log log;
  Harness h;
  const auto timers_before = h.clock.pending();
  h.start(wrap(node<b::TimeoutBehavior>("timeout", Time(30s)), node<Action>("act", log, 1min)));
  h.advance(10s);
  h.halt();
  EXPECT_EQ(h.status("act"), b::Status::halted);
  EXPECT_EQ(h.clock.pending(), timers_before);
  h.advance(1h);
  EXPECT_FALSE(h.done);
}

TEST(Invert, SwapsSuccessAndFailure) {
  Log log;
  Harness h;
  h.start(wrap(node<b::InvertBehavior>("invert"), node<Action>("act", log, 1s)));
  h.advance(1s);
  EXPECT_EQ(h.done, b::Status::failed);
  EXPECT_EQ(h.reason, "act succeeded");

  Log log2;
  Harness h2;
  h2.start(wrap(node<b::InvertBehavior>("invert"), node<Action>("act", log2, 1s, false)));
  h2.advance(1s);
  EXPECT_EQ(h2.done, b::Status::succeeded);
}

TEST(Decorator, IsTransparentToEvents) {
  Log log;
  Harness h;
  auto root = node<b::ConcurrentBehavior>("root");
  root->add_child(node<bt::Source>("outside"));
  root->add_child(wrap(node<b::InvertBehavior>("invert"), node<Action>("inner", log)));
  auto repeat = wrap(node<b::RepeatBehavior>("repeat", 0), node<bt::Source>("wrapped"));
  root->add_child(std::move(repeat));
  h.start(std::move(root));
  h.send("outside", bt::event("Ping"));
  EXPECT_TRUE(log.has("inner got Ping"));  // reached the decorator, so its child
  h.send("wrapped", bt::event("Pong"));
  EXPECT_TRUE(log.has("inner got Pong"));  // propagated as if "wrapped" stood in its place
  EXPECT_EQ(h.top.get(), (std::vector<std::string>{"Ping", "Pong"}));
}

TEST(Decorator, NeedsExactlyOneChild) {
  Log log;
  Harness h;
  auto retry = node<b::RetryBehavior>("retry", 2);
  retry->add_child(node<Action>("a", log));
  retry->add_child(node<Action>("b", log));
  h.start(std::move(retry));
  EXPECT_EQ(h.done, b::Status::failed);
  EXPECT_EQ(h.reason, "a retry wraps exactly one node, it has 2");
  EXPECT_TRUE(log.get().empty());
}
