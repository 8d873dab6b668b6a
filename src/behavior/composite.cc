#include "icars/behavior/composite.h"

#include <fmt/format.h>

#include <algorithm>

namespace icars::behavior {

namespace {

ConditionScope scope_for(Time now, const Behavior& from) {
  ConditionScope scope;
  scope.now = now;
  scope.variables.emplace("child", from.name());
  return scope;
}

planet::Value to_value(const ConditionValue& v) {
  if (const auto* b = std::get_if<bool>(&v)) return planet::Value::of(*b);
  if (const auto* d = std::get_if<double>(&v)) return planet::Value::of(*d);
  if (const auto* s = std::get_if<std::string>(&v)) return planet::Value::of(*s);
  return {};
}

}  // namespace

// --- Sequential -------------------------------------------------------------------------------

void SequentialBehavior::entry() {
  index_ = 0;
  round_ = 0;
  if (children().empty()) {
    succeed();
    return;
  }
  start_child();
}

void SequentialBehavior::start_child() { children()[index_]->start(); }

void SequentialBehavior::child_done(Behavior& child) {
  if (!running() || index_ >= children().size() || children()[index_].get() != &child) return;
  if (child.status() == Status::failed) {
    if (!options_.continue_on_failure) {
      fail(fmt::format("{} failed: {}", child.name(), child.failure_reason()));
      return;
    }
  }
  if (++index_ < children().size()) {
    start_child();
    return;
  }
  ++round_;
  if (options_.repeat == 0 || round_ < options_.repeat) {
    index_ = 0;
    start_child();
    return;
  }
  succeed();
}

// --- Fallback ---------------------------------------------------------------------------------

void FallbackBehavior::entry() {
  index_ = 0;
  if (children().empty()) {
    fail("no child to try");
    return;
  }
  children()[index_]->start();
}

void FallbackBehavior::child_done(Behavior& child) {
  if (!running() || index_ >= children().size() || children()[index_].get() != &child) return;
  if (child.status() == Status::succeeded) {
    succeed();
    return;
  }
  if (++index_ < children().size()) {
    children()[index_]->start();
    return;
  }
  fail(fmt::format("every child failed; last: {} failed: {}", child.name(), child.failure_reason()));
}

// --- Concurrent -------------------------------------------------------------------------------

std::string_view to_string(Completion completion) {
  switch (completion) {
    case Completion::all: return "all";
    case Completion::any: return "any";
    case Completion::first: return "first";
  }
  return "?";
}

std::optional<Completion> completion_from_string(std::string_view text) {
  if (text == "all") return Completion::all;
  if (text == "any") return Completion::any;
  if (text == "first") return Completion::first;
  return std::nullopt;
}

void ConcurrentBehavior::entry() {
  succeeded_ = 0;
  failed_ = 0;
  if (children().empty()) {
    succeed();
    return;
  }
  for (const auto& child : children()) {
    if (!running()) return;  // a child's entry cannot complete its parent, but be safe
    child->start();
  }
}

void ConcurrentBehavior::child_done(Behavior& child) {
  if (!running()) return;
  const bool ok = child.status() == Status::succeeded;
  ok ? ++succeeded_ : ++failed_;
  const auto n = children().size();
  const auto failure = [&] { return fmt::format("{} failed: {}", child.name(), child.failure_reason()); };
  switch (completion_) {
    case Completion::all:
      if (!ok) fail(failure());
      else if (succeeded_ == n) succeed();
      return;
    case Completion::any:
      if (ok) succeed();
      else if (failed_ == n) fail("every child failed; last: " + failure());
      return;
    case Completion::first:
      ok ? succeed() : fail(failure());
      return;
  }
}

// --- Event processing -------------------------------------------------------------------------

void FilterBehavior::child_event(Behavior& child, const Event& event) {
  if (!running()) return;
  if (pass_.evaluate(event, scope_for(now(), child))) {
    propagate(event);
  } else {
    ++dropped_;
  }
}

void InterpretBehavior::child_event(Behavior& child, const Event& event) {
  if (!running()) return;
  const auto scope = scope_for(now(), child);
  for (const auto& rule : rules_) {
    if (!rule.when.evaluate(event, scope)) continue;
    Event out(rule.emit);
    if (rule.copy) {
      for (const auto& [name, value] : event.items()) out.put(name, value);
    }
    for (const auto& [name, expression] : rule.set) {
      auto value = to_value(expression.value(event, scope));
      if (!value.empty()) out.put(name, std::move(value));
    }
    propagate(std::move(out));
    return;
  }
  if (pass_unmatched_) propagate(event);
}

void AggregateBehavior::entry() {
  collected_.clear();
  ConcurrentBehavior::entry();
}

void AggregateBehavior::child_event(Behavior& child, const Event& event) {
  if (!running()) return;
  const auto t = now();
  if (!spec_.when.evaluate(event, scope_for(t, child))) {
    if (spec_.pass_unmatched) propagate(event);
    return;
  }
  collected_.emplace_back(t, event);
  if (spec_.window.count() > 0) {
    while (!collected_.empty() && t - collected_.front().first > spec_.window) collected_.pop_front();
  }
  bool complete = false;
  if (!spec_.all_of.empty()) {
    complete = std::all_of(spec_.all_of.begin(), spec_.all_of.end(), [&](const std::string& type) {
      return std::any_of(collected_.begin(), collected_.end(),
                         [&](const auto& c) { return c.second.type() == type; });
    });
  } else {
    complete = collected_.size() >= static_cast<std::size_t>(std::max(spec_.count, 1));
  }
  if (!complete) return;
  Event out(spec_.emit);
  for (const auto& [name, value] : collected_.back().second.items()) out.put(name, value);
  out.set("count", static_cast<std::int32_t>(collected_.size()));
  out.set("first_ms", static_cast<std::int64_t>(collected_.front().first.count()));
  out.set("last_ms", static_cast<std::int64_t>(collected_.back().first.count()));
  collected_.clear();
  propagate(std::move(out));
}

// --- Leaves -----------------------------------------------------------------------------------

void WaitBehavior::entry() {
  after(duration_, [this] { succeed(); });
}

void EmitBehavior::entry() {
  if (delay_.count() == 0) {
    propagate(event_);
    succeed();
    return;
  }
  after(delay_, [this] {
    propagate(event_);
    succeed();
  });
}

}  // namespace icars::behavior
