// The behavior runtime: the one thread on which every behavior, task and coordinator of a
// mediating server runs, and the clock their timers follow.
//
// Behaviors are active objects (ICARS paper 4.3.2): everything that reaches them — a sensor
// event from a communicator thread, a timer from the clock's thread, the reply of a remote
// call, an event propagated by a sibling — is posted to the runtime and runs there, one
// handler at a time. So a behavior's state needs no lock, and a handler may destroy any part of
// the tree: nothing else is running.
//
// Run to completion (as SCXML processes its external events): an input from outside the
// runtime (a sensor event, a timer, a reply) is processed with everything it causes — events
// propagated through the tree, a task's event, the transition it takes, the new task's entry —
// before the next input is. So an event that arrives right behind the one that changed the
// statechart's state reaches the new state's behaviors, never the old ones'.
#pragma once

#include <asio/executor_work_guard.hpp>
#include <asio/io_context.hpp>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <thread>

#include "icars/clock/activity.h"
#include "icars/clock/clock.h"
#include "icars/planet/event.h"

namespace icars::behavior {

class Runtime {
 public:
  // Starts the runtime thread. Timers follow `clock` (a simulated clock driven by hand in
  // tests, by a RealTimeDriver or a LockStepDriver in a house, the wall clock in production).
  // With an `activity` (lock-step, icars/clock/activity.h) every handler posted is work until
  // it has run.
  explicit Runtime(Clock& clock, std::shared_ptr<Activity> activity = nullptr);
  ~Runtime();  // stops the thread; handlers still queued are dropped
  Runtime(const Runtime&) = delete;
  Runtime& operator=(const Runtime&) = delete;

  Clock& clock() { return clock_; }
  Time now() const { return clock_.now(); }

  // Runs `fn` on the runtime thread. Thread-safe. Posted from another thread it is an input,
  // run after the inputs posted before it; posted from the runtime thread it is a consequence
  // of the handler running, and runs after that handler and the consequences posted before it,
  // but before any input not yet started. An exception escaping `fn` is a bug in the handler:
  // it is logged to stderr and dropped.
  void post(std::function<void()> fn);
  bool in_runtime_thread() const { return std::this_thread::get_id() == thread_.get_id(); }

  // Runs `fn` on the runtime thread and returns its result (rethrowing its exception); from the
  // runtime thread itself it runs `fn` directly. For applications and tests that set up or
  // inspect behaviors from outside.
  // From another thread it is an input, and returns once `fn` has run to completion (with the
  // consequences of what it did: a tree halted from here has released everything).
  template <class F>
  auto run(F fn) -> decltype(fn()) {
    if (in_runtime_thread()) return fn();
    std::packaged_task<decltype(fn())()> task(std::move(fn));
    auto result = task.get_future();
    std::promise<void> completed;
    post_input([&task] { task(); }, [&completed] { completed.set_value(); });
    completed.get_future().wait();
    return result.get();
  }

  // Waits until nothing posted is waiting or running (handlers that post more are waited for
  // too); false if that takes longer than `timeout`. Remote calls in flight do not count.
  bool drain(std::chrono::milliseconds timeout = std::chrono::seconds(30));

  // Posts `fn` when the clock reaches now + delay. Returns an id for cancel_timer. Cancelling
  // from the runtime thread guarantees `fn` does not run, even if the clock already fired it.
  std::uint64_t start_timer(Time delay, std::function<void()> fn);
  void cancel_timer(std::uint64_t id);

  std::uint64_t handlers_run() const { return handlers_run_.load(); }

  // The fan-out of one event source (a sensor service) to the behaviors listening to it. The
  // source's events are posted as inputs, and each is handed to the listeners present when it
  // is processed: a behavior that starts listening while an event is queued (the state the
  // event before it led to) hears it. Runtime thread only.
  class Relay {
   public:
    explicit Relay(Runtime& runtime) : runtime_(runtime) {}
    std::uint64_t add(std::function<void(const planet::Event&)> fn);
    void remove(std::uint64_t id);

   private:
    friend class Runtime;
    void dispatch(const planet::Event& e);
    Runtime& runtime_;
    std::uint64_t next_ = 1;
    std::map<std::uint64_t, std::function<void(const planet::Event&)>> listeners_;
  };
  // The relay of `source`, made the first time: `subscribe(emit)` subscribes to the source so
  // that it calls `emit` (from any thread) with each event, and returns what unsubscribes it
  // (run when the Runtime is destroyed, if the source is still there). A source's relay lives
  // as long as the source (or a holder of the pointer returned).
  std::shared_ptr<Relay> relay(const std::shared_ptr<const void>& source,
               const std::function<std::function<void()>(std::function<void(planet::Event)> emit)>& subscribe);

 private:
  struct TimerTable;
  struct Inputs;  // what a source's emit posts to: gone with the Runtime
  struct Consequence {
    std::function<void()> fn;
    Activity::Hold hold;
  };
  void post_input(std::function<void()> fn, std::function<void()> then);  // `then` after its consequences
  void execute(std::function<void()>& fn);
  bool run_consequences();  // false: some were left for later (too many in a row)
  void release_idle_relays();

  Clock& clock_;
  std::shared_ptr<Activity> activity_;
  asio::io_context io_;
  asio::executor_work_guard<asio::io_context::executor_type> work_;
  std::atomic<std::int64_t> outstanding_{0};
  std::atomic<std::uint64_t> handlers_run_{0};
  std::shared_ptr<TimerTable> timers_;
  std::deque<Consequence> consequences_;  // runtime thread only
  std::shared_ptr<Inputs> inputs_;
  struct RelayEntry {
    std::weak_ptr<const void> source;
    std::shared_ptr<Relay> relay;
    std::function<void()> unsubscribe;
  };
  std::map<const void*, RelayEntry> relays_;  // runtime thread only
  bool relays_idle_ = false;                  // a relay lost its last listener
  bool warned_busy_ = false;
  std::thread thread_;
};

}  // namespace icars::behavior
