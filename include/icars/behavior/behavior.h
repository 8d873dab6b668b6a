// ICARS behavior model (paper 4.3.2, Figs. 11 and 12): a Behavior is an active object that
// starts with an entry function (discover and bind services, subscribe to sensors), reacts to
// events with ECA rules in handle_event (condition over the event's properties → service calls
// and event propagation), and ends with an exit function (unsubscribe, release). It completes
// with success or failure, or is halted by its parent.
//
// Behaviors form trees: composites (composite.h) own their children, and destroying or halting
// a node halts its whole subtree first. "Every event that a node propagates is sent to its
// parent and all its siblings": a parent by default passes a child's event on upwards the same
// way, so events climb to the root, where the task turns them into task events.
//
// Everything here runs on the behavior Runtime's thread. A behavior writes no plumbing: what it
// subscribes to, the timers it starts and the replies it waits for are tied to its activation
// and released at exit; a callback that arrives after that is dropped.
//
//   class LookAtSound : public Behavior {            // Fig. 11b
//     void entry() override {
//       wheels_ = require<home::NavigationService>(of_type("Navigation"));
//       listen(require<home::SoundSensor>(of_type("SoundSensor")));
//     }
//     void handle_event(const Event& e) override {
//       if (e.type() == "SoundEvent")
//         invoke(*wheels_, "turn_to", [&](auto done) {
//           wheels_->proxy().turn_to_async(e.get<double>("direction"), done); });
//     }
//     std::shared_ptr<home::NavigationService> wheels_;
//   };
#pragma once

#include <exception>
#include <functional>
#include <memory>
#include <set>
#include <stdexcept>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include "icars/behavior/params.h"
#include "icars/behavior/runtime.h"
#include "icars/behavior/trace.h"
#include "icars/planet/event.h"
#include "icars/service/service_container.h"

namespace icars::behavior {

using planet::Event;

enum class Status { idle, running, succeeded, failed, halted };
std::string_view to_string(Status status);

// "WaypointReached waypoint=door index=3": an event's type and its scalar properties.
std::string describe_event(const Event& e);

// What every behavior of an application sees.
struct Environment {
  Runtime& runtime;
  service::ServiceContainer& services;
  Trace& trace;
};

// A behavior's failure with a reason; thrown from entry or handle_event it fails the behavior.
class BehaviorError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class Behavior;

// Where a behavior's propagated events and its completion go: its parent composite, or, for
// the root of a task, the task. Calls arrive posted through the runtime, never inside the
// child's own call, and only while the owner exists.
class Owner {
 public:
  virtual ~Owner() = default;
  virtual void child_event(Behavior& child, const Event& event) = 0;
  virtual void child_done(Behavior& child) = 0;
  std::weak_ptr<const char> life() const { return life_; }

 private:
  std::shared_ptr<const char> life_ = std::make_shared<const char>('\0');
};

class Behavior : public Owner {
 public:
  Behavior() = default;
  ~Behavior() override;  // halts first if running
  Behavior(const Behavior&) = delete;
  Behavior& operator=(const Behavior&) = delete;

  // Identity, set by whoever builds the tree (a factory, the policy).
  void set_identity(std::string type, std::string name);
  const std::string& type() const { return type_; }
  const std::string& name() const { return name_; }
  std::string path() const;  // "RestMode/VoiceControl/GoToUser"
  void set_params(Params params) { params_ = std::move(params); }
  const Params& params() const { return params_; }

  Status status() const { return status_; }
  bool running() const { return status_ == Status::running; }
  const std::string& failure_reason() const { return reason_; }
  Behavior* parent() const { return parent_; }
  const std::vector<std::unique_ptr<Behavior>>& children() const { return children_; }
  // Adds a child (before the tree is attached); a parent owns its children.
  Behavior& add_child(std::unique_ptr<Behavior> child);

  // Lifecycle, driven by the owner on the runtime thread.
  void attach(Environment& env, Owner& owner, std::string path_prefix);  // for a tree's root
  void start();                  // → running; entry(); a failure in entry fails it
  void halt();                   // running → halted: children first, then exit(), then release
  void receive(const Event& e);  // an event from a sibling → handle_event while running

  std::uint64_t events_handled() const { return events_handled_; }

 protected:
  // A behavior is started again after it completed (a retry's next attempt, a repeat's next
  // run, a state entered again): entry() sets up everything one activation uses, and nothing
  // of the last activation (a failure seen, a listener, a cached service) carries over.
  virtual void entry() {}
  virtual void handle_event(const Event&) {}
  virtual void exit() {}
  // A child propagated an event: by default pass it on to this node's parent and siblings.
  void child_event(Behavior& child, const Event& event) override;
  // A child completed (status succeeded or failed). Leaves have no children.
  void child_done(Behavior&) override {}

  // Sends `e` to the parent and every sibling.
  void propagate(Event e);
  void succeed();
  void fail(std::string reason);

  Environment& env() { return *env_; }
  Runtime& runtime() { return env_->runtime; }
  service::ServiceContainer& services() { return env_->services; }
  Time now() const { return env_->runtime.now(); }
  void note(std::string text);  // a line in the trace, from this behavior
  // A trace record of `kind` from this behavior, with details for machines (docs/trace.md).
  void record(std::string kind, std::string text, std::vector<std::pair<std::string, TraceValue>> fields = {});

  static service::ServiceQuery of_type(std::string type) { return service::ServiceQuery::of_type(std::move(type)); }
  // The first available service matching `query` that is an S, or null.
  template <class S>
  std::shared_ptr<S> discover(service::ServiceQuery query) const {
    return env_->services.find_first<S>(query.available());
  }
  // Like discover, but a missing service is a failure of the behavior (BehaviorError).
  template <class S>
  std::shared_ptr<S> require(service::ServiceQuery query) const {
    if (auto s = discover<S>(query)) return s;
    throw BehaviorError("no available " + query.type + " service" +
                        (query.room.empty() ? "" : " in the " + query.room));
  }
  // Every event `sensor` publishes reaches handle_event as an Event named after its type
  // without namespace ("OccupancyEvent", "SpeechEvent"), until exit.
  template <class S>
  void listen(const std::shared_ptr<S>& sensor) {
    listen(sensor, [this](const Event& e) { receive(e); });
  }
  // Every event `sensor` publishes goes to `on_event` (on the runtime, while this activation
  // lasts) instead of handle_event, which then sees only its siblings' and children's events.
  // Events reach it through the runtime's relay of the sensor (Runtime::Relay): one queued when
  // this behavior starts listening is heard.
  template <class S, class F>
  void listen(const std::shared_ptr<S>& sensor, F on_event) {
    const auto relay = runtime().relay(sensor, [sensor = std::weak_ptr<S>(sensor)](std::function<void(Event)> emit) {
      auto source = sensor.lock();
      const auto id = source->subscribe([emit = std::move(emit)](const auto& typed) { emit(rename(planet::to_event(typed))); });
      return std::function<void()>([sensor, id] {
        if (auto s = sensor.lock()) s->unsubscribe(id);
      });
    });
    const auto id = relay->add([this, activation = std::weak_ptr<const char>(activation_),
                               on_event = std::move(on_event)](const Event& e) mutable {
      if (activation.lock() && running()) on_event(e);
    });
    on_release([relay = std::weak_ptr<Runtime::Relay>(relay), id] {
      if (auto r = relay.lock()) r->remove(id);
    });
  }

  // The Service Framework's events about devices (DeviceLost, DeviceBack, DeviceRestored,
  // DeviceForgotten; see service::DeviceRegistry) reach handle_event until exit.
  void listen_devices();

  // Runs `fn` on the runtime after `delay` of (simulated) time, unless this activation ended.
  std::uint64_t after(Time delay, std::function<void()> fn);
  void cancel(std::uint64_t timer);
  // Runs at exit (after exit()), in reverse order of registration.
  void on_release(std::function<void()> fn) { releases_.push_back(std::move(fn)); }

  // Wraps a callback so that, called from any thread, it runs on the runtime while this
  // activation lasts and is dropped otherwise.
  template <class F>
  auto guard(F fn) {
    return [rt = &runtime(), activation = std::weak_ptr<const char>(activation_),
            fn = std::make_shared<F>(std::move(fn))](auto&&... args) {
      // A completion that arrives after the activation ended (its policy stopped, its runtime
      // perhaps gone with it) has nothing to run on: it is dropped before touching the runtime.
      if (activation.expired()) return;
      rt->post([activation, fn, ... a = std::decay_t<decltype(args)>(std::forward<decltype(args)>(args))]() mutable {
        if (activation.lock()) (*fn)(std::move(a)...);
      });
    };
  }

  // An asynchronous call on a service, traced as "<service>.<op>": `start(handler)` initiates
  // it (e.g. `svc->proxy().set_power_async(true, handler)`); `done(error, results...)` runs on
  // the runtime while this activation lasts. Without `done`, a failed call fails the behavior.
  // A call that cannot even be sent (the service is unbound) completes with the error alone:
  // give result parameters defaults (`[](std::exception_ptr e, double length = 0)`) so `done`
  // hears about it; a `done` that cannot take the error alone leaves it to fail the behavior.
  template <class Start, class Done>
  void invoke(const service::Service& service, std::string op, Start start, Done done) {
    const std::string full = service.id() + "." + op;
    trace_call(full);
    auto finish = guard([done](std::exception_ptr e, auto... results) mutable {
      done(e, std::move(results)...);
    });
    try {
      // The failure is traced where the call completes, so a command that fails after this
      // activation ended (a behavior that succeeded without waiting for it) is still reported.
      start([finish, failed = failure_recorder(full)](std::exception_ptr e, auto&&... results) mutable {
        if (e) failed(e);
        finish(e, std::forward<decltype(results)>(results)...);
      });
    } catch (...) {  // not even sent (the service is unbound)
      runtime().post(guard_call([this, full, e = std::current_exception(), done]() mutable {
        trace_call_failure(full, e);
        if constexpr (std::is_invocable_v<Done&, std::exception_ptr>) {
          done(e);
        } else {
          fail(call_error(full, e));
        }
      }));
    }
  }
  template <class Start>
  void invoke(const service::Service& service, std::string op, Start start) {
    invoke(service, op, std::move(start), [this, full = service.id() + "." + op](std::exception_ptr e, auto&&...) {
      if (e) fail(call_error(full, e));
    });
  }

  // `e` renamed to its type without namespace ("icars::home::OccupancyEvent" → "OccupancyEvent").
  static Event rename(Event e);

  // "a call failed: <what the exception says>"
  static std::string describe(std::exception_ptr e);
  static std::string call_error(const std::string& op, std::exception_ptr e) {
    return op + " failed: " + describe(e);
  }

 private:
  template <class F>
  std::function<void()> guard_call(F fn) {
    return [activation = std::weak_ptr<const char>(activation_), fn = std::move(fn)]() mutable {
      if (activation.lock()) fn();
    };
  }

  friend class Composite;
  void handle(const Event& e);
  void complete(Status status, std::string reason);
  void release();
  void notify_owner_done();
  void trace_call(const std::string& op);
  void trace_call_failure(const std::string& op, std::exception_ptr e);
  // Traces the failure of call `op` from any thread, even after this activation (or this
  // behavior) ended: it holds only the trace and the runtime, which outlive every behavior.
  std::function<void(std::exception_ptr)> failure_recorder(const std::string& op) const;

  std::string type_;
  std::string name_;
  std::string path_prefix_;
  Params params_;
  Status status_ = Status::idle;
  std::string reason_;
  Environment* env_ = nullptr;
  Owner* owner_ = nullptr;
  Behavior* parent_ = nullptr;
  std::vector<std::unique_ptr<Behavior>> children_;
  std::shared_ptr<const char> activation_;  // lives from start to completion or halt
  std::set<std::uint64_t> timers_;
  std::vector<std::function<void()>> releases_;
  std::uint64_t events_handled_ = 0;
};

}  // namespace icars::behavior
