// Composite behaviors (ICARS paper 4.3.2, Fig. 12): the inner nodes of a behavior tree.
//
// - SequentialBehavior runs its children one after another, in order.
// - FallbackBehavior tries its children one after another until one succeeds.
// - ConcurrentBehavior starts all its children at once; its Completion says when it is done.
// - FilterBehavior, InterpretBehavior and AggregateBehavior are concurrent composites that
//   process the events their children propagate on the way up (paper: filtering,
//   interpretation, aggregation), configured with conditions (condition.h) instead of code.
//
// A composite owns its children: halting it halts them (deepest first), and it completes only
// after halting the children still running, so a finished subtree holds no service,
// subscription or timer.
#pragma once

#include <deque>
#include <string>
#include <vector>

#include "icars/behavior/behavior.h"
#include "icars/behavior/condition.h"

namespace icars::behavior {

class SequentialBehavior : public Behavior {
 public:
  struct Options {
    bool continue_on_failure = false;  // false: the first failing child fails the sequence
    int repeat = 1;                    // rounds through the children; 0: until halted
  };
  SequentialBehavior() = default;
  explicit SequentialBehavior(Options options) : options_(options) {}

 protected:
  void entry() override;
  void child_done(Behavior& child) override;

 private:
  void start_child();
  Options options_;
  std::size_t index_ = 0;
  int round_ = 0;
};

// Runs its children one after another until one succeeds (BehaviorTree.CPP's Fallback, or
// Selector): succeeds with the first child that succeeds, tries the next when one fails, and
// fails when every child failed ("every child failed; last: ..."). With no children it fails.
class FallbackBehavior : public Behavior {
 protected:
  void entry() override;
  void child_done(Behavior& child) override;

 private:
  std::size_t index_ = 0;
};

// When a concurrent composite completes:
//   all   - succeeds when every child succeeded; fails as soon as one fails (the default);
//   any   - succeeds as soon as one child succeeds; fails when every child failed;
//   first - completes as soon as one child completes, as that child did.
// Children still running at completion are halted. With no children it succeeds at once.
enum class Completion { all, any, first };
std::string_view to_string(Completion completion);
std::optional<Completion> completion_from_string(std::string_view text);

class ConcurrentBehavior : public Behavior {
 public:
  explicit ConcurrentBehavior(Completion completion = Completion::all) : completion_(completion) {}
  Completion completion() const { return completion_; }

 protected:
  void entry() override;
  void child_done(Behavior& child) override;

 private:
  Completion completion_;
  std::size_t succeeded_ = 0;
  std::size_t failed_ = 0;
};

// Passes on upwards only the children's events that satisfy `pass`; the others stop here.
class FilterBehavior : public ConcurrentBehavior {
 public:
  FilterBehavior(Condition pass, Completion completion = Completion::all)
      : ConcurrentBehavior(completion), pass_(std::move(pass)) {}
  std::uint64_t dropped() const { return dropped_; }

 protected:
  void child_event(Behavior& child, const Event& event) override;

 private:
  Condition pass_;
  std::uint64_t dropped_ = 0;
};

// One interpretation rule: an event that satisfies `when` becomes an event of type `emit`,
// carrying the original's properties (unless copy is false) and the `set` values computed from
// the original (expressions evaluated by Condition::value).
struct InterpretRule {
  Condition when;
  std::string emit;
  bool copy = true;
  std::vector<std::pair<std::string, Condition>> set;
};

// Interprets children's events into other events by the first matching rule; events no rule
// matches stop here, or pass on unchanged when `pass_unmatched`.
class InterpretBehavior : public ConcurrentBehavior {
 public:
  InterpretBehavior(std::vector<InterpretRule> rules, bool pass_unmatched = false,
                    Completion completion = Completion::all)
      : ConcurrentBehavior(completion), rules_(std::move(rules)), pass_unmatched_(pass_unmatched) {}

 protected:
  void child_event(Behavior& child, const Event& event) override;

 private:
  std::vector<InterpretRule> rules_;
  bool pass_unmatched_;
};

// Aggregates several children's events into one. Events that satisfy `when` are collected;
// the aggregate event `emit` is propagated (and the collection restarts) as soon as
//   - `count` of them arrived within `window` (count mode), or
//   - one of each type in `all_of` arrived within `window` (all-of mode).
// A window of 0 means no time limit. The aggregate carries the last collected event's
// properties plus `count`, `first_ms` and `last_ms`. Events that do not satisfy `when` stop
// here, or pass on unchanged when `pass_unmatched`.
struct AggregateSpec {
  Condition when;
  std::string emit;
  int count = 2;
  std::vector<std::string> all_of;
  Time window{0};
  bool pass_unmatched = false;
};

class AggregateBehavior : public ConcurrentBehavior {
 public:
  explicit AggregateBehavior(AggregateSpec spec, Completion completion = Completion::all)
      : ConcurrentBehavior(completion), spec_(std::move(spec)) {}

 protected:
  void entry() override;
  void child_event(Behavior& child, const Event& event) override;

 private:
  AggregateSpec spec_;
  std::deque<std::pair<Time, Event>> collected_;
};

// Leaves every application needs.
// Waits for a duration of (simulated) time, then succeeds.
class WaitBehavior : public Behavior {
 public:
  explicit WaitBehavior(Time duration) : duration_(duration) {}

 protected:
  void entry() override;

 private:
  Time duration_;
};

// Propagates one event, then succeeds (after `delay`, if given).
class EmitBehavior : public Behavior {
 public:
  explicit EmitBehavior(Event event, Time delay = Time{0})
      : event_(std::move(event)), delay_(delay) {}

 protected:
  void entry() override;

 private:
  Event event_;
  Time delay_;
};

}  // namespace icars::behavior
