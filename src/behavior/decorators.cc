#include "icars/behavior/decorators.h"

#include <fmt/format.h>

#include "icars/clock/time.h"

namespace icars::behavior {

namespace {

// "00:00:30": a duration as the trace prints times of day (as a task's timeout does).
std::string hh_mm_ss(Time t) { return format_time(t).substr(3); }

std::string failure_of(const Behavior& child) {
  return fmt::format("{} failed: {}", child.name(), child.failure_reason());
}

}  // namespace

// --- DecoratorBehavior --------------------------------------------------------------------------

void DecoratorBehavior::entry() {
  awaiting_ = false;
  if (children().size() != 1) {
    fail(fmt::format("a {} wraps exactly one node, it has {}", type(), children().size()));
    return;
  }
  begin();
}

void DecoratorBehavior::start_child() {
  awaiting_ = true;
  child().start();
}

void DecoratorBehavior::halt_child() {
  awaiting_ = false;
  child().halt();
}

bool DecoratorBehavior::settle_child() {
  if (!awaiting_ || child().running()) return false;
  awaiting_ = false;
  child_completed(child());
  return true;
}

void DecoratorBehavior::handle_event(const Event& event) {
  if (!children().empty() && child().running()) child().receive(event);
}

void DecoratorBehavior::child_done(Behavior& done) {
  // A notice is stale when the child runs again (restarted since) or its run was settled.
  if (!running() || done.running() || !awaiting_) return;
  awaiting_ = false;
  child_completed(done);
}

// --- Retry --------------------------------------------------------------------------------------

void RetryBehavior::begin() {
  attempt_ = 1;
  start_child();
}

void RetryBehavior::child_completed(Behavior& done) {
  if (done.status() == Status::succeeded) {
    succeed();
    return;
  }
  if (attempts_ != 0 && attempt_ >= attempts_) {
    fail(fmt::format("{} failed {} time{}; last: {}", done.name(), attempt_, attempt_ == 1 ? "" : "s",
                     done.failure_reason()));
    return;
  }
  ++attempt_;
  note(fmt::format("{}; attempt {}{}", failure_of(done), attempt_,
                   attempts_ == 0 ? std::string() : fmt::format(" of {}", attempts_)));
  if (delay_.count() > 0) {
    after(delay_, [this] { start_child(); });
  } else {
    start_child();
  }
}

// --- Repeat -------------------------------------------------------------------------------------

void RepeatBehavior::begin() {
  run_ = 1;
  start_child();
}

void RepeatBehavior::child_completed(Behavior& done) {
  if (done.status() == Status::failed) {
    fail(fmt::format("{} failed on run {}: {}", done.name(), run_, done.failure_reason()));
    return;
  }
  if (times_ != 0 && run_ >= times_) {
    succeed();
    return;
  }
  ++run_;
  start_child();
}

// --- Timeout ------------------------------------------------------------------------------------

void TimeoutBehavior::begin() {
  start_child();
  if (!running()) return;
  after(after_, [this] {
    halt_child();
    fail(fmt::format("{} still running after {}", child().name(), hh_mm_ss(after_)));
  });
}

void TimeoutBehavior::child_completed(Behavior& done) {
  if (done.status() == Status::succeeded) {
    succeed();
  } else {
    fail(failure_of(done));
  }
}

// --- Invert -------------------------------------------------------------------------------------

void InvertBehavior::begin() { start_child(); }

void InvertBehavior::child_completed(Behavior& done) {
  if (done.status() == Status::succeeded) {
    fail(fmt::format("{} succeeded", done.name()));
  } else {
    succeed();
  }
}

}  // namespace icars::behavior
