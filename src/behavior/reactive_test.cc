// Reactive nodes on the simulated clock, fed by a sibling's events as in a task: `when` (restart
// or ignore while running, times, failures, halting), conditions, and the reactive sequence and
// fallback halting their running child when a condition they passed changes its mind.
#include "icars/behavior/reactive.h"

#include <gtest/gtest.h>

#include "icars/behavior/composite.h"
#include "tree_test_support.h"

namespace b = icars::behavior;
namespace bt = icars::behavior::testing;
using bt::Action;
using bt::Harness;
using bt::Log;
using bt::node;
using icars::Time;
using icars::planet::Value;
using namespace std::chrono_literals;

namespace {

b::Event speech(const std::string& text) { return bt::event("SpeechEvent", {{"text", Value::of(text)}}); }
b::Event occupancy(bool occupied) { return bt::event("OccupancyEvent", {{"occupied", Value::of(occupied)}}); }

b::WhenBehavior::Options lights(b::WhileRunning mode, int times = 0, bool continue_on_failure = false) {
  b::WhenBehavior::Options o;
  o.trigger = {"SpeechEvent", b::Condition::parse("contains(text, 'lights')")};
  o.while_running = mode;
  o.times = times;
  o.continue_on_failure = continue_on_failure;
  return o;
}

// concurrent(Source "sense", `reactive`): the Source's events reach `reactive` as a sibling's.
std::unique_ptr<b::Behavior> beside_a_sensor(std::unique_ptr<b::Behavior> reactive) {
  auto root = node<b::ConcurrentBehavior>("root");
  root->add_child(node<bt::Source>("sense"));
  root->add_child(std::move(reactive));
  return root;
}

std::unique_ptr<b::Behavior> when(b::WhenBehavior::Options options, std::unique_ptr<b::Behavior> child) {
  auto w = node<b::WhenBehavior>("when", std::move(options));
  w->add_child(std::move(child));
  return w;
}

std::unique_ptr<b::Behavior> condition(std::string name, std::string event, std::string condition) {
  return node<b::ConditionBehavior>(std::move(name), b::EventTrigger{std::move(event), b::Condition::parse(condition)});
}

}  // namespace

TEST(When, RunsItsChildOnAMatchingEventAndPassesTheEventOn) {
  Log log;
  Harness h;
  h.start(beside_a_sensor(when(lights(b::WhileRunning::ignore), node<Action>("act", log, 1min))));
  EXPECT_FALSE(log.has("act entry"));
  h.send("sense", speech("hello"));
  EXPECT_FALSE(log.has("act entry"));
  h.send("sense", speech("turn on the LIGHTS please"));
  EXPECT_EQ(log.get(), (std::vector<std::string>{"act entry", "act got SpeechEvent"}));
  h.advance(1min);
  EXPECT_EQ(static_cast<b::WhenBehavior&>(h.find("when")).runs(), 1);
  EXPECT_EQ(h.status("when"), b::Status::running);  // never completes by itself
  h.send("sense", speech("lights off"));
  EXPECT_EQ(log.count("act entry"), 2);
}

TEST(When, IgnoreLetsTheRunningChildGoOn) {
  Log log;
  Harness h;
  h.start(beside_a_sensor(when(lights(b::WhileRunning::ignore), node<Action>("act", log, 1min))));
  h.send("sense", speech("lights"));
  h.advance(30s);
  h.send("sense", speech("lights again"));
  EXPECT_EQ(log.count("act entry"), 1);
  EXPECT_EQ(log.count("act got SpeechEvent"), 2);  // a running child still hears it
  h.advance(30s);
  EXPECT_EQ(h.status("act"), b::Status::succeeded);
  EXPECT_EQ(static_cast<b::WhenBehavior&>(h.find("when")).runs(), 1);
}

TEST(When, RestartHaltsAndStartsTheRunningChildAgain) {
  Log log;
  Harness h;
  h.start(beside_a_sensor(when(lights(b::WhileRunning::restart, 2), node<Action>("act", log, 1min))));
  h.send("sense", speech("lights"));
  h.advance(30s);
  h.send("sense", speech("lights again"));
  EXPECT_EQ(log.count("act entry"), 2);
  EXPECT_EQ(log.count("act exit"), 1);  // the first run was halted
  EXPECT_TRUE(h.traced("behavior", "T/root/when/act halted"));
  h.advance(59s);
  EXPECT_EQ(h.status("act"), b::Status::running);  // a full minute from the restart
  h.advance(1s);
  EXPECT_EQ(static_cast<b::WhenBehavior&>(h.find("when")).runs(), 1);
  h.send("sense", speech("lights"));
  h.advance(1min);
  EXPECT_EQ(h.status("when"), b::Status::succeeded);  // times="2"
}

TEST(When, AFailingChildFailsItUnlessToldToContinue) {
  Log log;
  Harness h;
  h.start(beside_a_sensor(when(lights(b::WhileRunning::ignore), node<Action>("act", log, 1min, false))));
  h.send("sense", speech("lights"));
  h.advance(1min);
  EXPECT_EQ(h.done, b::Status::failed);
  EXPECT_EQ(h.reason, "when failed: act failed: told to fail");

  Log log2;
  Harness h2;
  h2.start(beside_a_sensor(when(lights(b::WhileRunning::ignore, 0, true), node<Action>("act", log2, 1min, false))));
  h2.send("sense", speech("lights"));
  h2.advance(1min);
  EXPECT_EQ(h2.status("when"), b::Status::running);
  EXPECT_TRUE(h2.traced("note", "T/root/when: act failed: told to fail"));
}

TEST(When, HaltingItHaltsTheRunningChildAndItsTimers) {
  Log log;
  Harness h;
  const auto timers_before = h.clock.pending();
  h.start(beside_a_sensor(when(lights(b::WhileRunning::ignore), node<Action>("act", log, 1min))));
  h.send("sense", speech("lights"));
  h.halt();
  EXPECT_EQ(h.status("act"), b::Status::halted);
  EXPECT_EQ(h.clock.pending(), timers_before);
  h.advance(1h);
  EXPECT_FALSE(h.done);
}

TEST(ReactiveSequence, WaitsForItsConditionThenRunsTheAction) {
  Log log;
  Harness h;
  auto seq = node<b::ReactiveSequenceBehavior>("seq");
  seq->add_child(condition("home", "OccupancyEvent", "occupied"));
  seq->add_child(node<Action>("act", log, 10min));
  h.start(beside_a_sensor(std::move(seq)));
  EXPECT_EQ(h.status("home"), b::Status::running);  // unknown: no OccupancyEvent yet
  h.send("sense", speech("lights"));                // another type decides nothing
  EXPECT_EQ(h.status("home"), b::Status::running);
  h.send("sense", occupancy(true));
  EXPECT_TRUE(log.has("act entry"));
  h.send("sense", occupancy(true));
  h.advance(10min);
  EXPECT_EQ(h.status("seq"), b::Status::succeeded);
}

TEST(ReactiveSequence, APassedConditionThatNoLongerHoldsHaltsTheActionAndFails) {
  Log log;
  Harness h;
  auto seq = node<b::ReactiveSequenceBehavior>("seq");
  seq->add_child(condition("home", "OccupancyEvent", "occupied"));
  seq->add_child(node<Action>("act", log, 10min));
  h.start(beside_a_sensor(std::move(seq)));
  h.send("sense", occupancy(true));
  h.advance(5min);
  h.send("sense", occupancy(false));
  EXPECT_EQ(h.status("act"), b::Status::halted);
  EXPECT_TRUE(log.has("act exit"));
  EXPECT_EQ(h.done, b::Status::failed);
  EXPECT_EQ(h.reason, "seq failed: home no longer holds: 'occupied' is false for OccupancyEvent occupied=false");
}

TEST(ReactiveSequence, AConditionKnownFalseAtItsTurnFailsAtOnce) {
  Log log;
  Harness h;
  auto seq = node<b::ReactiveSequenceBehavior>("seq");
  seq->add_child(node<Action>("first", log, 1min));
  seq->add_child(condition("home", "OccupancyEvent", "occupied"));
  seq->add_child(node<Action>("then", log, 1min));
  h.start(beside_a_sensor(std::move(seq)));
  h.send("sense", occupancy(false));  // decided while "first" runs
  h.advance(1min);
  EXPECT_EQ(h.status("seq"), b::Status::failed);
  EXPECT_FALSE(log.has("then entry"));
  EXPECT_EQ(h.reason, "seq failed: home failed: 'occupied' is false for OccupancyEvent occupied=false");
}

TEST(ReactiveFallback, AConditionThatComesToHoldHaltsTheRunningChildAndSucceeds) {
  Log log;
  Harness h;
  auto fallback = node<b::ReactiveFallbackBehavior>("fallback");
  fallback->add_child(condition("gone", "OccupancyEvent", "not occupied"));
  fallback->add_child(node<Action>("chase", log, 10min));
  h.start(beside_a_sensor(std::move(fallback)));
  h.send("sense", occupancy(true));  // not gone: try the next child
  EXPECT_TRUE(log.has("chase entry"));
  h.advance(2min);
  h.send("sense", occupancy(false));
  EXPECT_EQ(h.status("chase"), b::Status::halted);
  EXPECT_EQ(h.status("fallback"), b::Status::succeeded);
  EXPECT_TRUE(h.traced("note", "T/root/fallback: gone holds now: 'not occupied' is true for OccupancyEvent occupied=false"));
}

TEST(ReactiveFallback, FailsWhenEveryChildFailed) {
  Log log;
  Harness h;
  auto fallback = node<b::ReactiveFallbackBehavior>("fallback");
  fallback->add_child(condition("gone", "OccupancyEvent", "not occupied"));
  fallback->add_child(node<Action>("chase", log, 1min, false));
  h.start(beside_a_sensor(std::move(fallback)));
  h.send("sense", occupancy(true));
  h.advance(1min);
  EXPECT_EQ(h.status("fallback"), b::Status::failed);
  EXPECT_EQ(h.reason, "fallback failed: every child failed; last: chase failed: told to fail");
}

TEST(Reactive, WhenStartsAReactiveSequenceWithTheEventThatSetItOff) {
  Log log;
  Harness h;
  auto seq = node<b::ReactiveSequenceBehavior>("seq");
  seq->add_child(condition("home", "OccupancyEvent", "occupied"));
  seq->add_child(node<Action>("act", log, 10min));
  b::WhenBehavior::Options o;
  o.trigger = {"OccupancyEvent", b::Condition::parse("occupied")};
  o.continue_on_failure = true;
  h.start(beside_a_sensor(when(o, std::move(seq))));
  h.send("sense", occupancy(true));  // starts seq, whose condition hears the same event
  EXPECT_TRUE(log.has("act entry"));
  h.advance(1min);
  h.send("sense", occupancy(false));  // passed on by `when`: the sequence gives up
  EXPECT_EQ(h.status("act"), b::Status::halted);
  EXPECT_EQ(h.status("seq"), b::Status::failed);
  EXPECT_EQ(h.status("when"), b::Status::running);
  h.send("sense", occupancy(true));  // and starts again on the next one
  EXPECT_EQ(log.count("act entry"), 2);
}
