// The behavior model: propagation to parent and siblings, event processing nodes, composite
// completion, and teardown of a subtree releasing everything it held. The tree runs on a real
// Runtime thread; time is a SimClock advanced by hand.
#include <gtest/gtest.h>

#include <fmt/format.h>

#include <atomic>
#include <thread>

#include "icars/behavior/behavior.h"
#include "icars/behavior/composite.h"
#include "icars/behavior/registry.h"
#include "icars/clock/sim_clock.h"

namespace b = icars::behavior;
namespace s = icars::service;
using icars::Time;
using namespace std::chrono_literals;

namespace {

// An in-process sensor service: publishes "Ping" typed events to subscribers.
struct Ping {
  std::string from;
  std::int32_t n = 0;
};

}  // namespace

PLANET_EVENT(Ping, from, n);

namespace {

class PingSensor : public s::Service {
 public:
  PingSensor() : Service("pinger", "PingSensor", {}) { set_available(true); }
  std::uint64_t subscribe(std::function<void(const Ping&)> fn) { return listeners_.add(std::move(fn)); }
  void unsubscribe(std::uint64_t id) { listeners_.remove(id); }
  void publish(const Ping& p) { listeners_.notify(p); }
  std::size_t subscribers() const { return listeners_.size(); }

 private:
  s::Listeners<Ping> listeners_;
};

// What every test records.
struct Log {
  std::mutex mutex;
  std::vector<std::string> lines;
  void add(std::string line) {
    std::lock_guard lock(mutex);
    lines.push_back(std::move(line));
  }
  std::vector<std::string> get() {
    std::lock_guard lock(mutex);
    return lines;
  }
  bool has(const std::string& line) {
    auto l = get();
    return std::find(l.begin(), l.end(), line) != l.end();
  }
};

// A leaf that records what it receives and its entry/exit; succeeds or fails on an event
// "Finish"/"Break" addressed to it; propagates an event of type `emit` at entry when given.
class Probe : public b::Behavior {
 public:
  Probe(Log& log, std::string emit = "") : log_(log), emit_(std::move(emit)) {}

 protected:
  void entry() override {
    log_.add(name() + " entry");
    if (!emit_.empty()) propagate(b::Event(emit_));
  }
  void handle_event(const b::Event& e) override {
    log_.add(fmt::format("{} got {}", name(), e.type()));
    if (e.has("to") && e.get<std::string>("to") == name()) {
      if (e.type() == "Finish") succeed();
      if (e.type() == "Break") fail("broken on purpose");
    }
  }
  void exit() override { log_.add(name() + " exit"); }

 private:
  Log& log_;
  std::string emit_;
};

// Listens to the PingSensor and propagates every ping upwards; starts a long timer.
class PingRelay : public b::Behavior {
 protected:
  void entry() override {
    listen(require<PingSensor>(of_type("PingSensor")));
    after(1h, [this] { succeed(); });
  }
  void handle_event(const b::Event& e) override { propagate(e); }
};

std::unique_ptr<b::Behavior> named(std::unique_ptr<b::Behavior> node, std::string name) {
  node->set_identity(name, name);
  return node;
}

template <class T, class... A>
std::unique_ptr<b::Behavior> node(std::string name, A&&... args) {
  return named(std::make_unique<T>(std::forward<A>(args)...), std::move(name));
}

b::Event to(std::string type, std::string target) {
  b::Event e(std::move(type));
  e.set("to", target);
  return e;
}

// Owns a tree the way a task does and records what reaches the top.
class Harness : public b::Owner {
 public:
  Harness() : runtime(clock), env{runtime, services, trace} { trace.add_sink(log.sink()); }
  ~Harness() override {
    runtime.run([&] {
      if (root) root->halt();
      root.reset();
    });
  }

  void start(std::unique_ptr<b::Behavior> tree) {
    runtime.run([&] {
      root = std::move(tree);
      root->attach(env, *this, "T");
      root->start();
    });
    settle();
  }
  void settle() { ASSERT_TRUE(runtime.drain(10s)); }
  // Sends an event to every node of the tree as if a sibling had propagated it.
  void broadcast(const b::Event& e) {
    runtime.run([&] { visit(*root, e); });
    settle();
  }
  b::Behavior& find(const std::string& name) { return *find_in(*root, name); }

  void child_event(b::Behavior&, const b::Event& e) override { top.add(e.type()); }
  void child_done(b::Behavior& child) override {
    done = child.status();
    reason = child.failure_reason();
  }

  icars::SimClock clock{Time{0}};
  b::Runtime runtime;
  s::ServiceContainer services;
  b::Trace trace;
  b::TraceLog log;
  b::Environment env;
  std::unique_ptr<b::Behavior> root;
  Log top;
  std::optional<b::Status> done;
  std::string reason;

 private:
  static void visit(b::Behavior& n, const b::Event& e) {
    n.receive(e);
    for (auto& c : n.children()) visit(*c, e);
  }
  static b::Behavior* find_in(b::Behavior& n, const std::string& name) {
    if (n.name() == name) return &n;
    for (auto& c : n.children()) {
      if (auto* f = find_in(*c, name)) return f;
    }
    return nullptr;
  }
};

}  // namespace

TEST(Propagation, AnEventGoesToTheParentAndAllSiblingsAndClimbsToTheRoot) {
  Log log;
  Harness h;
  auto root = node<b::ConcurrentBehavior>("root");
  auto left = node<b::ConcurrentBehavior>("left");
  left->add_child(node<Probe>("emitter", log, "Alarm"));
  left->add_child(node<Probe>("sibling", log));
  root->add_child(std::move(left));
  root->add_child(node<Probe>("uncle", log));
  h.start(std::move(root));

  EXPECT_TRUE(log.has("sibling got Alarm"));  // sibling of the origin
  EXPECT_TRUE(log.has("uncle got Alarm"));    // sibling of the parent, as the event climbs
  EXPECT_FALSE(log.has("emitter got Alarm")); // never back to its origin
  EXPECT_EQ(h.top.get(), std::vector<std::string>{"Alarm"});  // reaches the task once
}

TEST(Propagation, FilterPassesOnlyMatchingEvents) {
  Harness h;
  auto sensor = std::make_shared<PingSensor>();
  h.services.add(sensor);
  auto filter2 = named(std::make_unique<b::FilterBehavior>(b::Condition::parse("n > 3")), "filter");
  filter2->add_child(node<PingRelay>("relay"));
  h.start(std::move(filter2));
  for (int n : {1, 5, 2, 9}) sensor->publish(Ping{"x", n});
  h.settle();
  EXPECT_EQ(h.top.get(), (std::vector<std::string>{"Ping", "Ping"}));
  EXPECT_EQ(static_cast<b::FilterBehavior&>(*h.root).dropped(), 2u);
}

TEST(Propagation, InterpretTurnsEventsIntoOthersAndSetsProperties) {
  Harness h;
  std::vector<b::InterpretRule> rules(2);
  rules[0].when = b::Condition::parse("event == 'Ping' and n >= 10");
  rules[0].emit = "Loud";
  rules[0].set.emplace_back("double_n", b::Condition::parse("n"));
  rules[1].when = b::Condition::parse("event == 'Ping' and from == 'door'");
  rules[1].emit = "Knock";
  rules[1].copy = false;
  auto interpret = named(std::make_unique<b::InterpretBehavior>(rules), "interpret");
  interpret->add_child(node<PingRelay>("relay"));
  auto sensor = std::make_shared<PingSensor>();
  h.services.add(sensor);

  std::vector<b::Event> seen;
  std::mutex m;
  class Catch : public b::Owner {
   public:
    Catch(std::vector<b::Event>& s, std::mutex& m) : seen(s), mutex(m) {}
    void child_event(b::Behavior&, const b::Event& e) override {
      std::lock_guard lock(mutex);
      seen.push_back(e);
    }
    void child_done(b::Behavior&) override {}
    std::vector<b::Event>& seen;
    std::mutex& mutex;
  } catcher(seen, m);
  h.runtime.run([&] {
    h.root = std::move(interpret);
    h.root->attach(h.env, catcher, "T");
    h.root->start();
  });
  sensor->publish(Ping{"window", 12});
  sensor->publish(Ping{"door", 1});
  sensor->publish(Ping{"window", 1});  // no rule: stops here
  h.settle();
  std::lock_guard lock(m);
  ASSERT_EQ(seen.size(), 2u);
  EXPECT_EQ(seen[0].type(), "Loud");
  EXPECT_EQ(seen[0].get<std::string>("from"), "window");  // copied
  EXPECT_EQ(seen[0].get<double>("double_n"), 12.0);      // set
  EXPECT_EQ(seen[1].type(), "Knock");
  EXPECT_FALSE(seen[1].has("from"));  // copy="false"
}

TEST(Propagation, AggregateEmitsOnceEnoughEventsArriveWithinTheWindow) {
  Harness h;
  b::AggregateSpec spec;
  spec.when = b::Condition::parse("event == 'Ping'");
  spec.emit = "Burst";
  spec.count = 3;
  spec.window = Time(60'000);
  auto aggregate = named(std::make_unique<b::AggregateBehavior>(spec), "aggregate");
  aggregate->add_child(node<PingRelay>("relay"));
  auto sensor = std::make_shared<PingSensor>();
  h.services.add(sensor);
  h.start(std::move(aggregate));

  sensor->publish(Ping{"a", 1});
  sensor->publish(Ping{"a", 2});
  h.settle();
  h.clock.advance_by(2min);  // the first two fall out of the window
  h.settle();
  sensor->publish(Ping{"a", 3});
  sensor->publish(Ping{"a", 4});
  h.settle();
  EXPECT_TRUE(h.top.get().empty());
  sensor->publish(Ping{"a", 5});
  h.settle();
  EXPECT_EQ(h.top.get(), std::vector<std::string>{"Burst"});
}

TEST(Propagation, AggregateAllOfNeedsOneOfEachType) {
  Log log;
  Harness h;
  b::AggregateSpec spec;
  spec.emit = "Both";
  spec.all_of = {"Motion", "Sound"};
  auto aggregate = named(std::make_unique<b::AggregateBehavior>(spec), "aggregate");
  aggregate->add_child(node<Probe>("m1", log, "Motion"));
  aggregate->add_child(node<Probe>("m2", log, "Motion"));
  aggregate->add_child(node<Probe>("s", log, "Sound"));
  h.start(std::move(aggregate));
  EXPECT_EQ(h.top.get(), std::vector<std::string>{"Both"});
}

TEST(Composite, SequentialRunsChildrenInOrderAndSucceeds) {
  Log log;
  Harness h;
  auto seq = node<b::SequentialBehavior>("seq");
  seq->add_child(node<Probe>("first", log));
  seq->add_child(node<Probe>("second", log));
  h.start(std::move(seq));
  EXPECT_EQ(log.get(), std::vector<std::string>{"first entry"});
  h.broadcast(to("Finish", "first"));
  EXPECT_TRUE(log.has("second entry"));
  EXPECT_EQ(h.root->status(), b::Status::running);
  h.broadcast(to("Finish", "second"));
  EXPECT_EQ(h.done, b::Status::succeeded);
}

TEST(Composite, SequentialStopsAtTheFirstFailureUnlessToldToContinue) {
  Log log;
  Harness h;
  auto seq = node<b::SequentialBehavior>("seq");
  seq->add_child(node<Probe>("first", log));
  seq->add_child(node<Probe>("second", log));
  h.start(std::move(seq));
  h.broadcast(to("Break", "first"));
  EXPECT_EQ(h.done, b::Status::failed);
  EXPECT_EQ(h.reason, "first failed: broken on purpose");
  EXPECT_FALSE(log.has("second entry"));

  Log log2;
  Harness h2;
  b::SequentialBehavior::Options options;
  options.continue_on_failure = true;
  options.repeat = 2;
  auto seq2 = named(std::make_unique<b::SequentialBehavior>(options), "seq");
  seq2->add_child(node<Probe>("first", log2));
  seq2->add_child(node<Probe>("second", log2));
  h2.start(std::move(seq2));
  h2.broadcast(to("Break", "first"));
  h2.broadcast(to("Finish", "second"));
  EXPECT_EQ(h2.root->status(), b::Status::running);  // second round
  h2.broadcast(to("Finish", "first"));
  h2.broadcast(to("Finish", "second"));
  EXPECT_EQ(h2.done, b::Status::succeeded);
  const auto lines = log2.get();
  const auto entries = std::count(lines.begin(), lines.end(), std::string("first entry"));
  EXPECT_EQ(entries, 2);
}

TEST(Composite, ConcurrentAllSucceedsWhenEveryChildDidAndFailsAtTheFirstFailure) {
  Log log;
  Harness h;
  auto all = node<b::ConcurrentBehavior>("all");
  all->add_child(node<Probe>("a", log));
  all->add_child(node<Probe>("b", log));
  h.start(std::move(all));
  EXPECT_TRUE(log.has("a entry"));
  EXPECT_TRUE(log.has("b entry"));  // both started at once
  h.broadcast(to("Finish", "a"));
  EXPECT_FALSE(h.done);
  h.broadcast(to("Finish", "b"));
  EXPECT_EQ(h.done, b::Status::succeeded);

  Log log2;
  Harness h2;
  auto all2 = node<b::ConcurrentBehavior>("all");
  all2->add_child(node<Probe>("a", log2));
  all2->add_child(node<Probe>("b", log2));
  h2.start(std::move(all2));
  h2.broadcast(to("Break", "b"));
  EXPECT_EQ(h2.done, b::Status::failed);
  EXPECT_TRUE(log2.has("a exit"));  // the other child was halted
  EXPECT_EQ(h2.find("a").status(), b::Status::halted);
}

TEST(Composite, ConcurrentAnyAndFirst) {
  Log log;
  Harness h;
  auto any = named(std::make_unique<b::ConcurrentBehavior>(b::Completion::any), "any");
  any->add_child(node<Probe>("a", log));
  any->add_child(node<Probe>("b", log));
  h.start(std::move(any));
  h.broadcast(to("Break", "a"));
  EXPECT_FALSE(h.done);  // one failure is not enough
  h.broadcast(to("Finish", "b"));
  EXPECT_EQ(h.done, b::Status::succeeded);

  Log log2;
  Harness h2;
  auto first = named(std::make_unique<b::ConcurrentBehavior>(b::Completion::first), "first");
  first->add_child(node<Probe>("a", log2));
  first->add_child(node<Probe>("b", log2));
  h2.start(std::move(first));
  h2.broadcast(to("Break", "b"));
  EXPECT_EQ(h2.done, b::Status::failed);
  EXPECT_EQ(h2.find("a").status(), b::Status::halted);
}

TEST(Composite, FallbackTriesChildrenInOrderUntilOneSucceeds) {
  Log log;
  Harness h;
  auto fallback = node<b::FallbackBehavior>("fallback");
  fallback->add_child(node<Probe>("a", log));
  fallback->add_child(node<Probe>("b", log));
  fallback->add_child(node<Probe>("c", log));
  h.start(std::move(fallback));
  EXPECT_EQ(log.get(), std::vector<std::string>{"a entry"});
  h.broadcast(to("Break", "a"));
  EXPECT_TRUE(log.has("b entry"));
  h.broadcast(to("Finish", "b"));
  EXPECT_EQ(h.done, b::Status::succeeded);
  EXPECT_FALSE(log.has("c entry"));

  Log log2;
  Harness h2;
  auto all_fail = node<b::FallbackBehavior>("fallback");
  all_fail->add_child(node<Probe>("a", log2));
  all_fail->add_child(node<Probe>("b", log2));
  h2.start(std::move(all_fail));
  h2.broadcast(to("Break", "a"));
  h2.broadcast(to("Break", "b"));
  EXPECT_EQ(h2.done, b::Status::failed);
  EXPECT_EQ(h2.reason, "every child failed; last: b failed: broken on purpose");

  Log log3;
  Harness h3;
  auto halted = node<b::FallbackBehavior>("fallback");
  halted->add_child(node<Probe>("a", log3));
  halted->add_child(node<Probe>("b", log3));
  h3.start(std::move(halted));
  h3.broadcast(to("Break", "a"));
  h3.runtime.run([&] { h3.root->halt(); });
  h3.settle();
  EXPECT_TRUE(log3.has("b exit"));
  EXPECT_EQ(h3.find("b").status(), b::Status::halted);
  EXPECT_FALSE(h3.done);
}

TEST(Teardown, HaltingARootReleasesEverySubscriptionAndTimerOfTheSubtree) {
  Log log;
  Harness h;
  auto sensor = std::make_shared<PingSensor>();
  h.services.add(sensor);
  auto root = node<b::ConcurrentBehavior>("root");
  auto inner = node<b::SequentialBehavior>("inner");
  auto deep = node<b::ConcurrentBehavior>("deep");
  deep->add_child(node<PingRelay>("r1"));
  deep->add_child(node<PingRelay>("r2"));
  deep->add_child(node<Probe>("p", log));
  inner->add_child(std::move(deep));
  root->add_child(std::move(inner));
  root->add_child(node<PingRelay>("r3"));
  const auto clock_events_before = h.clock.pending();
  h.start(std::move(root));
  EXPECT_EQ(sensor->subscribers(), 1u);  // the runtime's relay, for all three (Runtime::Relay)
  EXPECT_EQ(h.clock.pending(), clock_events_before + 3);  // one timer each

  h.runtime.run([&] { h.root->halt(); });
  h.settle();
  EXPECT_EQ(sensor->subscribers(), 0u);
  EXPECT_EQ(h.clock.pending(), clock_events_before);
  EXPECT_TRUE(log.has("p exit"));
  for (const auto* n : {"root", "inner", "deep", "r1", "r2", "r3", "p"}) {
    EXPECT_EQ(h.find(n).status(), b::Status::halted) << n;
  }
  // Nothing reaches the halted tree any more.
  sensor->publish(Ping{"late", 1});
  h.clock.advance_by(2h);
  h.settle();
  EXPECT_TRUE(h.top.get().empty());
  EXPECT_FALSE(h.done);
}

TEST(Teardown, DestroyingAParentDestroysItsSubtreeAndLateRepliesAreDropped) {
  Harness h;
  auto sensor = std::make_shared<PingSensor>();
  h.services.add(sensor);
  std::atomic<int> replies_handled{0};
  std::function<void(std::exception_ptr)> pending_reply;
  std::mutex m;

  class Caller : public b::Behavior {
   public:
    Caller(std::shared_ptr<PingSensor> s, std::function<void(std::exception_ptr)>& slot, std::mutex& m,
           std::atomic<int>& handled)
        : sensor_(std::move(s)), slot_(slot), mutex_(m), handled_(handled) {}

   protected:
    void entry() override {
      listen(sensor_);
      invoke(*sensor_, "slow_op", [this](auto done) {
        std::lock_guard lock(mutex_);
        slot_ = done;
      }, [this](std::exception_ptr) { ++handled_; });
    }

   private:
    std::shared_ptr<PingSensor> sensor_;
    std::function<void(std::exception_ptr)>& slot_;
    std::mutex& mutex_;
    std::atomic<int>& handled_;
  };

  auto root = node<b::ConcurrentBehavior>("root");
  root->add_child(node<Caller>("caller", sensor, pending_reply, m, replies_handled));
  h.start(std::move(root));
  EXPECT_EQ(sensor->subscribers(), 1u);
  h.runtime.run([&] {
    h.root->halt();
    h.root.reset();  // the parent and its child are gone
  });
  EXPECT_EQ(sensor->subscribers(), 0u);
  std::thread([&] {
    std::lock_guard lock(m);
    pending_reply(nullptr);  // the reply arrives after the behavior is gone
  }).join();
  h.settle();
  EXPECT_EQ(replies_handled.load(), 0);
}

TEST(Lifecycle, AMissingServiceFailsTheBehaviorWithAClearReason) {
  Harness h;
  h.start(node<PingRelay>("relay"));
  EXPECT_EQ(h.done, b::Status::failed);
  EXPECT_EQ(h.reason, "no available PingSensor service");
}

TEST(Lifecycle, TimersFollowTheSimulatedClock) {
  b::BehaviorRegistry registry;
  b::register_generic_behaviors(registry);
  Harness h;
  auto seq = node<b::SequentialBehavior>("seq");
  seq->add_child(registry.create("Wait", "nap", {{"duration", "10min"}}));
  seq->add_child(registry.create("Emit", "", {{"event", "Rested"}}));
  h.start(std::move(seq));
  h.clock.advance_by(9min);
  h.settle();
  EXPECT_FALSE(h.done);
  h.clock.advance_by(1min);
  h.settle();
  EXPECT_EQ(h.done, b::Status::succeeded);
  EXPECT_EQ(h.top.get(), std::vector<std::string>{"Rested"});
}

TEST(Registry, ChecksParametersAgainstTheDeclaredOnes) {
  b::BehaviorRegistry registry;
  b::register_generic_behaviors(registry);
  EXPECT_THROW(registry.create("Sleep", "", {}), b::ParamError);
  try {
    registry.create("Wait", "", {{"duration", "ten minutes"}});
    FAIL();
  } catch (const b::ParamError& e) {
    EXPECT_NE(std::string(e.what()).find("'ten minutes' is not a duration"), std::string::npos) << e.what();
  }
  try {
    registry.create("Wait", "", {{"duration", "1s"}, {"speed", "2"}});
    FAIL();
  } catch (const b::ParamError& e) {
    EXPECT_NE(std::string(e.what()).find("Wait has no parameter 'speed'"), std::string::npos) << e.what();
  }
  try {
    registry.create("Wait", "", {});
    FAIL();
  } catch (const b::ParamError& e) {
    EXPECT_NE(std::string(e.what()).find("needs parameter 'duration'"), std::string::npos) << e.what();
  }
  auto emit = registry.create("Emit", "", {{"event", "X"}});
  EXPECT_EQ(emit->params().string("delay"), "0s");  // default filled in
  EXPECT_THROW(registry.add("Wait", "again", {}, [](const b::Params&) { return std::make_unique<b::WaitBehavior>(Time(1)); }),
               std::invalid_argument);
}
