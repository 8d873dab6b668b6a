// Test support for behavior trees driven on the simulated clock: a Harness that owns a tree as
// a task does, a Source leaf that propagates events on demand (so its siblings receive them as
// from any sibling), and an Action leaf that logs its entry and exit and completes after a
// simulated duration or when told. Private to the tests of src/behavior.
#pragma once

#include <gtest/gtest.h>

#include <fmt/format.h>

#include <algorithm>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "icars/behavior/behavior.h"
#include "icars/clock/sim_clock.h"

namespace icars::behavior::testing {

using namespace std::chrono_literals;

// What the leaves of a test did, in order.
class Log {
 public:
  void add(std::string line) {
    std::lock_guard lock(mutex_);
    lines_.push_back(std::move(line));
  }
  std::vector<std::string> get() const {
    std::lock_guard lock(mutex_);
    return lines_;
  }
  bool has(const std::string& line) const { return count(line) > 0; }
  long count(const std::string& line) const {
    const auto lines = get();
    return std::count(lines.begin(), lines.end(), line);
  }

 private:
  mutable std::mutex mutex_;
  std::vector<std::string> lines_;
};

// Never completes; send() propagates an event to its parent and siblings.
class Source : public Behavior {
 public:
  void send(Event e) { propagate(std::move(e)); }
};

// Logs "<name> entry", "<name> got <type>" and "<name> exit". Completes `after` its start
// (succeeding, or failing when `ok` is false) unless `after` is 0; finish() completes it now.
class Action : public Behavior {
 public:
  Action(Log& log, Time after = Time{0}, bool ok = true) : log_(log), after_(after), ok_(ok) {}
  void finish(bool ok) { ok ? succeed() : fail("told to fail"); }

 protected:
  void entry() override {
    log_.add(name() + " entry");
    if (after_.count() > 0) after(after_, [this] { finish(ok_); });
  }
  void handle_event(const Event& e) override { log_.add(fmt::format("{} got {}", name(), e.type())); }
  void exit() override { log_.add(name() + " exit"); }

 private:
  Log& log_;
  Time after_;
  bool ok_;
};

template <class T, class... A>
std::unique_ptr<Behavior> node(std::string name, A&&... args) {
  auto n = std::make_unique<T>(std::forward<A>(args)...);
  n->set_identity(name, name);
  return n;
}

inline Event event(std::string type, std::vector<std::pair<std::string, planet::Value>> properties = {}) {
  Event e(std::move(type));
  for (auto& [name, value] : properties) e.put(name, std::move(value));
  return e;
}

// Owns a tree the way a task does (path prefix "T") and records what reaches the top.
class Harness : public Owner {
 public:
  Harness() : runtime(clock), env{runtime, services, trace} { trace.add_sink(log.sink()); }
  ~Harness() override {
    runtime.run([&] {
      if (root) root->halt();
      root.reset();
    });
  }

  void start(std::unique_ptr<Behavior> tree) {
    runtime.run([&] {
      root = std::move(tree);
      root->attach(env, *this, "T");
      root->start();
    });
    settle();
  }
  void settle() { ASSERT_TRUE(runtime.drain(10s)); }
  // Moves the clock on by `d` one timer at a time, letting the tree react to each (a timer the
  // reaction starts runs too if it is due within `d`).
  void advance(Time d) {
    const auto until = clock.now() + d;
    settle();
    for (auto next = clock.next_event_time(); next && *next <= until; next = clock.next_event_time()) {
      clock.advance_to(*next);
      settle();
    }
    clock.advance_to(until);
    settle();
  }
  // The Source named `source` propagates `e`.
  void send(const std::string& source, Event e) {
    runtime.run([&] { static_cast<Source&>(find(source)).send(std::move(e)); });
    settle();
  }
  void finish(const std::string& action, bool ok = true) {
    runtime.run([&] { static_cast<Action&>(find(action)).finish(ok); });
    settle();
  }
  void halt() {
    runtime.run([&] { root->halt(); });
    settle();
  }
  Behavior& find(const std::string& name) {
    auto* found = find_in(*root, name);
    EXPECT_NE(found, nullptr) << name;
    return *found;
  }
  Status status(const std::string& name) { return runtime.run([&] { return find(name).status(); }); }
  // The texts of the trace's records of `kind` ("behavior", "note").
  std::vector<std::string> texts(std::string_view kind) const {
    std::vector<std::string> out;
    for (const auto& r : log.of_kind(kind)) out.push_back(r.text);
    return out;
  }
  bool traced(std::string_view kind, const std::string& text) const {
    const auto all = texts(kind);
    return std::find(all.begin(), all.end(), text) != all.end();
  }

  void child_event(Behavior&, const Event& e) override { top.add(e.type()); }
  void child_done(Behavior& child) override {
    done = child.status();
    reason = child.failure_reason();
  }

  SimClock clock{Time{0}};
  Runtime runtime;
  service::ServiceContainer services;
  Trace trace;
  TraceLog log;
  Environment env;
  std::unique_ptr<Behavior> root;
  Log top;
  std::optional<Status> done;
  std::string reason;

 private:
  static Behavior* find_in(Behavior& n, const std::string& name) {
    if (n.name() == name) return &n;
    for (const auto& c : n.children()) {
      if (auto* f = find_in(*c, name)) return f;
    }
    return nullptr;
  }
};

}  // namespace icars::behavior::testing
