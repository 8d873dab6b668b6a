#include "icars/behavior/reactive.h"

#include <fmt/format.h>

namespace icars::behavior {

namespace {

std::string failure_of(const Behavior& child) {
  return fmt::format("{} failed: {}", child.name(), child.failure_reason());
}

}  // namespace

std::string_view to_string(WhileRunning mode) {
  switch (mode) {
    case WhileRunning::restart: return "restart";
    case WhileRunning::ignore: return "ignore";
  }
  return "?";
}

std::optional<WhileRunning> while_running_from_string(std::string_view text) {
  if (text == "restart") return WhileRunning::restart;
  if (text == "ignore") return WhileRunning::ignore;
  return std::nullopt;
}

// --- When ---------------------------------------------------------------------------------------

void WhenBehavior::begin() { runs_ = 0; }

void WhenBehavior::handle_event(const Event& event) {
  const auto& trigger = options_.trigger;
  if (event.type() == trigger.event && trigger.condition.evaluate(event, ConditionScope{now(), {}})) {
    if (!child().running()) {
      settle_child();  // a completion whose notice is still queued counts before the new run
      if (!running()) return;
      start_child();
    } else if (options_.while_running == WhileRunning::restart) {
      note(fmt::format("restarting {} on {}", child().name(), describe_event(event)));
      halt_child();
      start_child();
    }
  }
  DecoratorBehavior::handle_event(event);
}

void WhenBehavior::child_completed(Behavior& done) {
  if (done.status() == Status::failed) {
    if (!options_.continue_on_failure) {
      fail(failure_of(done));
      return;
    }
    note(failure_of(done));
  }
  ++runs_;
  if (options_.times != 0 && runs_ >= options_.times) succeed();
}

// --- Condition ----------------------------------------------------------------------------------

std::string ConditionBehavior::describe_state() const {
  if (!holds_) return fmt::format("no {} yet", trigger_.event);
  const auto& text = trigger_.condition.text();
  return fmt::format("'{}' is {} for {}", text.empty() ? std::string("true") : text, *holds_ ? "true" : "false",
                     decided_by_);
}

void ConditionBehavior::observe(const Event& event) {
  if (event.type() != trigger_.event) return;
  holds_ = trigger_.condition.evaluate(event, ConditionScope{now(), {}});
  decided_by_ = describe_event(event);
  if (running()) complete_run();
}

void ConditionBehavior::forget() {
  holds_.reset();
  decided_by_.clear();
}

void ConditionBehavior::entry() {
  if (holds_) complete_run();  // else wait for the first event of the type
}

void ConditionBehavior::complete_run() {
  if (*holds_) {
    succeed();
  } else {
    fail(describe_state());
  }
}

// --- Reactive sequence and fallback -------------------------------------------------------------

void ReactiveCompositeBehavior::entry() {
  index_ = 0;
  for (const auto& child : children()) {
    if (auto* condition = dynamic_cast<ConditionBehavior*>(child.get())) condition->forget();
  }
  if (children().empty()) {
    if (fallback_) {
      fail("no child to try");
    } else {
      succeed();
    }
    return;
  }
  start_current();
}

void ReactiveCompositeBehavior::start_current() { children()[index_]->start(); }

void ReactiveCompositeBehavior::child_done(Behavior& child) {
  if (!running() || child.running() || index_ >= children().size() || children()[index_].get() != &child) return;
  const bool succeeded = child.status() == Status::succeeded;
  if (succeeded == fallback_) {  // a sequence's failure, a fallback's success: done
    if (fallback_) {
      succeed();
    } else {
      fail(failure_of(child));
    }
    return;
  }
  if (++index_ < children().size()) {
    start_current();
  } else if (fallback_) {
    fail("every child failed; last: " + failure_of(child));
  } else {
    succeed();
  }
}

void ReactiveCompositeBehavior::handle_event(const Event& event) {
  for (const auto& child : children()) {
    if (auto* condition = dynamic_cast<ConditionBehavior*>(child.get())) condition->observe(event);
  }
  // Only conditions already passed are re-checked: the current child completes by itself.
  for (std::size_t i = 0; i < index_ && i < children().size(); ++i) {
    const auto* condition = dynamic_cast<const ConditionBehavior*>(children()[i].get());
    if (condition == nullptr || !condition->holds()) continue;
    if (!fallback_ && !*condition->holds()) {
      fail(fmt::format("{} no longer holds: {}", condition->name(), condition->describe_state()));
      return;
    }
    if (fallback_ && *condition->holds()) {
      note(fmt::format("{} holds now: {}", condition->name(), condition->describe_state()));
      succeed();
      return;
    }
  }
}

}  // namespace icars::behavior
