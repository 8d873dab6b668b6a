// Decorators (BehaviorTree.CPP's decorator nodes in the ICARS behavior model): nodes with exactly
// one child that change how it runs or how its completion counts.
//
// - RetryBehavior runs a failing child again, up to a number of attempts.
// - RepeatBehavior runs a succeeding child again, a number of times or until halted.
// - TimeoutBehavior fails, halting its child, when the child has not completed in time.
// - InvertBehavior turns the child's success into failure and its failure into success.
//
// A decorator is transparent to events: what its child propagates goes on to the decorator's
// parent and siblings as if the child stood in its place, and every event that reaches the
// decorator (from its siblings, or from a decorator around it) reaches its running child.
// Halting a decorator halts its child and cancels its timers. Built with no child or several,
// it fails at entry.
#pragma once

#include "icars/behavior/behavior.h"

namespace icars::behavior {

// The base of nodes with one child: starts, halts and hears from it exactly once per run.
class DecoratorBehavior : public Behavior {
 protected:
  Behavior& child() const { return *children().front(); }
  // The decorator's entry, once its one child is checked.
  virtual void begin() = 0;
  // The child's current run completed (its status is succeeded or failed). Runs once per run,
  // never for a run this decorator halted.
  virtual void child_completed(Behavior& child) = 0;

  void start_child();
  void halt_child();
  // When the child has completed but the notice is still queued (the runtime posts it), hands
  // that completion to child_completed now; false when there was none.
  bool settle_child();

  void entry() final;
  void handle_event(const Event& event) override;  // to the running child
  void child_done(Behavior& child) final;

 private:
  bool awaiting_ = false;  // a run started whose completion child_completed has not had
};

// Runs its child until it succeeds, at most `attempts` times in all (0: until it succeeds),
// waiting `delay` before each new attempt. Succeeds when the child does; fails with the last
// failure when the child failed `attempts` times.
class RetryBehavior : public DecoratorBehavior {
 public:
  explicit RetryBehavior(int attempts, Time delay = Time{0}) : attempts_(attempts), delay_(delay) {}

 protected:
  void begin() override;
  void child_completed(Behavior& child) override;

 private:
  int attempts_;
  Time delay_;
  int attempt_ = 0;
};

// Runs its child `times` times in a row (0: until halted) while it succeeds. Succeeds after
// the last run; fails as soon as a run fails. (`<sequential repeat="N">` repeats a sequence.)
class RepeatBehavior : public DecoratorBehavior {
 public:
  explicit RepeatBehavior(int times) : times_(times) {}
  int runs() const { return run_; }

 protected:
  void begin() override;
  void child_completed(Behavior& child) override;

 private:
  int times_;
  int run_ = 0;
};

// Completes as its child does, unless the child is still running `after` its start: then the
// child is halted and the timeout fails ("<child> still running after HH:MM:SS").
class TimeoutBehavior : public DecoratorBehavior {
 public:
  explicit TimeoutBehavior(Time after) : after_(after) {}

 protected:
  void begin() override;
  void child_completed(Behavior& child) override;

 private:
  Time after_;
};

// Succeeds when its child fails, fails ("<child> succeeded") when it succeeds.
class InvertBehavior : public DecoratorBehavior {
 protected:
  void begin() override;
  void child_completed(Behavior& child) override;
};

}  // namespace icars::behavior
