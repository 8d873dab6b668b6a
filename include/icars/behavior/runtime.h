// The behavior runtime: the one thread on which every behavior, task and coordinator of a
// mediating server runs, and the clock their timers follow.
//
// Behaviors are active objects (ICARS paper 4.3.2): everything that reaches them — a sensor
// event from a communicator thread, a timer from the clock's thread, the reply of a remote
// call, an event propagated by a sibling — is posted to the runtime and runs there, one
// handler at a time, in the order posted. So a behavior's state needs no lock, and a handler
// may destroy any part of the tree: nothing else is running.
#pragma once

#include <asio/executor_work_guard.hpp>
#include <asio/io_context.hpp>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <future>
#include <memory>
#include <thread>

#include "icars/clock/activity.h"
#include "icars/clock/clock.h"

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

  // Runs `fn` on the runtime thread after everything posted before it. Thread-safe. An
  // exception escaping `fn` is a bug in the handler: it is logged to stderr and dropped.
  void post(std::function<void()> fn);
  bool in_runtime_thread() const { return std::this_thread::get_id() == thread_.get_id(); }

  // Runs `fn` on the runtime thread and returns its result (rethrowing its exception); from the
  // runtime thread itself it runs `fn` directly. For applications and tests that set up or
  // inspect behaviors from outside.
  template <class F>
  auto run(F fn) -> decltype(fn()) {
    if (in_runtime_thread()) return fn();
    std::packaged_task<decltype(fn())()> task(std::move(fn));
    auto result = task.get_future();
    post([&task] { task(); });
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

 private:
  struct TimerTable;

  Clock& clock_;
  std::shared_ptr<Activity> activity_;
  asio::io_context io_;
  asio::executor_work_guard<asio::io_context::executor_type> work_;
  std::atomic<std::int64_t> outstanding_{0};
  std::atomic<std::uint64_t> handlers_run_{0};
  std::shared_ptr<TimerTable> timers_;
  std::thread thread_;
};

}  // namespace icars::behavior
