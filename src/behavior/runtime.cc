#include "icars/behavior/runtime.h"

#include <asio/post.hpp>

#include <cstdio>
#include <exception>
#include <mutex>
#include <unordered_map>

namespace icars::behavior {

// Timers live here so a clock event that fires after the Runtime is gone finds nothing.
struct Runtime::TimerTable {
  std::mutex mutex;
  std::uint64_t next = 1;
  std::unordered_map<std::uint64_t, std::uint64_t> clock_ids;  // timer id -> clock event id
};

Runtime::Runtime(Clock& clock, std::shared_ptr<Activity> activity)
    : clock_(clock), activity_(std::move(activity)), work_(io_.get_executor()), timers_(std::make_shared<TimerTable>()) {
  thread_ = std::thread([this] { io_.run(); });
}

Runtime::~Runtime() {
  {
    std::lock_guard lock(timers_->mutex);
    for (const auto& [id, clock_id] : timers_->clock_ids) clock_.cancel(clock_id);
    timers_->clock_ids.clear();
  }
  work_.reset();
  io_.stop();
  if (thread_.joinable()) thread_.join();
}

void Runtime::post(std::function<void()> fn) {
  ++outstanding_;
  asio::post(io_, [this, fn = std::move(fn), hold = Activity::Hold(activity_.get())]() mutable {
    try {
      fn();
    } catch (const std::exception& e) {
      std::fprintf(stderr, "icars: behavior runtime: a handler threw: %s\n", e.what());
    } catch (...) {
      std::fprintf(stderr, "icars: behavior runtime: a handler threw\n");
    }
    ++handlers_run_;
    --outstanding_;
    hold.release();
  });
}

bool Runtime::drain(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  int quiet = 0;
  while (std::chrono::steady_clock::now() < deadline) {
    if (in_runtime_thread()) return outstanding_.load() <= 1;
    if (outstanding_.load() == 0) {
      // Quiet twice in a row, with a round trip through the queue between: nothing was
      // posted from a handler that had just finished.
      if (++quiet == 2) return true;
      std::promise<void> marker;
      post([&marker] { marker.set_value(); });
      marker.get_future().wait();
      continue;
    }
    quiet = 0;
    std::this_thread::sleep_for(std::chrono::microseconds(200));
  }
  return false;
}

std::uint64_t Runtime::start_timer(Time delay, std::function<void()> fn) {
  std::lock_guard lock(timers_->mutex);
  const auto id = timers_->next++;
  std::weak_ptr<TimerTable> table = timers_;
  // The clock event runs on the clock's thread: it only hands the timer to the runtime.
  const auto clock_id = clock_.schedule_after(delay, [this, table, id, fn = std::move(fn)]() mutable {
    auto fired = table.lock();
    if (!fired) return;
    {
      std::lock_guard guard(fired->mutex);
      if (!fired->clock_ids.contains(id)) return;
    }
    post([table, id, fn = std::move(fn)] {
      auto current = table.lock();
      if (!current) return;
      {
        std::lock_guard guard(current->mutex);
        if (current->clock_ids.erase(id) == 0) return;  // cancelled after it fired
      }
      fn();
    });
  });
  timers_->clock_ids.emplace(id, clock_id);
  return id;
}

void Runtime::cancel_timer(std::uint64_t id) {
  std::lock_guard lock(timers_->mutex);
  auto it = timers_->clock_ids.find(id);
  if (it == timers_->clock_ids.end()) return;
  clock_.cancel(it->second);
  timers_->clock_ids.erase(it);
}

}  // namespace icars::behavior
