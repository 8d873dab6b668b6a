// Reactive nodes: behavior-tree control that follows the events reaching a node, as
// BehaviorTree.CPP's reactive nodes follow their ticks. An event reaches a node when one of its
// siblings propagates it (behavior.h), or when a decorator around the node passes it on
// (decorators.h); these nodes read those events, never their own children's.
//
// - WhenBehavior runs its child each time an event of a type, satisfying a condition, reaches
//   it; an event arriving while the child runs restarts the child or is ignored.
// - ConditionBehavior is a condition over events: it holds or not according to the latest
//   matching event, and is unknown before the first.
// - ReactiveSequenceBehavior and ReactiveFallbackBehavior run their children in order like a
//   sequence and a fallback, and keep re-checking the ConditionBehavior children they passed
//   against every event that reaches them: a passed condition that changes its mind halts the
//   running child and completes the node.
#pragma once

#include <optional>
#include <string>

#include "icars/behavior/condition.h"
#include "icars/behavior/decorators.h"

namespace icars::behavior {

// The events a reactive node looks at: those of type `event` for which `condition` holds
// (evaluated on the event, with the time of day; an empty condition always holds).
struct EventTrigger {
  std::string event;
  Condition condition;
};

// What an event that sets off a WhenBehavior does while its child is still running.
enum class WhileRunning { restart, ignore };
std::string_view to_string(WhileRunning mode);
std::optional<WhileRunning> while_running_from_string(std::string_view text);

// Starts its child whenever an event of `trigger.event` satisfying `trigger.condition` reaches
// it, then passes that event to the child. While the child runs, such an event halts and
// restarts it (restart) or changes nothing (ignore). A child's failure fails the node unless
// `continue_on_failure`. With `times` = 0 it never completes by itself (its task or parent
// halts it); with `times` = N it succeeds when the child has completed N times. Being a
// decorator, it passes every event reaching it to its running child.
class WhenBehavior : public DecoratorBehavior {
 public:
  struct Options {
    EventTrigger trigger;
    WhileRunning while_running = WhileRunning::ignore;
    int times = 0;  // runs to complete before succeeding; 0: never completes by itself
    bool continue_on_failure = false;
  };
  explicit WhenBehavior(Options options) : options_(std::move(options)) {}
  int runs() const { return runs_; }  // completed runs of the child, this activation

 protected:
  void begin() override;
  void child_completed(Behavior& child) override;
  void handle_event(const Event& event) override;

 private:
  Options options_;
  int runs_ = 0;
};

// A condition over events, as a child of a reactive composite (below), which feeds it every
// event reaching the composite (observe). It holds or not according to `trigger.condition` on
// the latest event of type `trigger.event`, and is unknown before the first one. Started, it
// succeeds at once if it holds, fails at once if not, and when unknown waits for the first
// such event. A composite forgets its conditions' state when it starts.
class ConditionBehavior : public Behavior {
 public:
  explicit ConditionBehavior(EventTrigger trigger) : trigger_(std::move(trigger)) {}
  const EventTrigger& trigger() const { return trigger_; }
  std::optional<bool> holds() const { return holds_; }
  // "occupied holds for OccupancyEvent room=bedroom occupied=true"
  std::string describe_state() const;

  void observe(const Event& event);  // an event of the type decides holds()
  void forget();                     // unknown again

 protected:
  void entry() override;

 private:
  void complete_run();
  EventTrigger trigger_;
  std::optional<bool> holds_;
  std::string decided_by_;  // the event that decided it, described
};

// Shared by the two reactive composites (`fallback` selects which).
class ReactiveCompositeBehavior : public Behavior {
 protected:
  explicit ReactiveCompositeBehavior(bool fallback) : fallback_(fallback) {}
  void entry() override;
  void child_done(Behavior& child) override;
  void handle_event(const Event& event) override;  // feeds the conditions, re-checks passed ones

 private:
  void start_current();
  bool fallback_;
  std::size_t index_ = 0;  // the child running or about to run
};

// BehaviorTree.CPP's ReactiveSequence, event-driven: runs its children in order while they
// succeed and succeeds after the last; a failing child (a condition that does not hold) fails
// it. While a later child runs, a ConditionBehavior child it already passed that no longer holds
// (an event decided so) halts the running child and fails the sequence ("<condition> no longer
// holds: <event>"). Other children already passed are not run again. No children: succeeds.
class ReactiveSequenceBehavior final : public ReactiveCompositeBehavior {
 public:
  ReactiveSequenceBehavior() : ReactiveCompositeBehavior(false) {}
};

// BehaviorTree.CPP's ReactiveFallback, event-driven: runs its children in order while they
// fail and fails after the last ("every child failed"); a succeeding child (a condition that
// holds) succeeds it. While a later child runs, a ConditionBehavior child it already passed
// (that did not hold) that now holds halts the running child and succeeds the fallback.
// No children: fails.
class ReactiveFallbackBehavior final : public ReactiveCompositeBehavior {
 public:
  ReactiveFallbackBehavior() : ReactiveCompositeBehavior(true) {}
};

}  // namespace icars::behavior
