#include "icars/behavior/runtime.h"

#include <asio/post.hpp>

#include <cstdio>
#include <exception>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace icars::behavior {

// Timers live here so a clock event that fires after the Runtime is gone finds nothing.
struct Runtime::TimerTable {
  std::mutex mutex;
  std::uint64_t next = 1;
  std::unordered_map<std::uint64_t, std::uint64_t> clock_ids;  // timer id -> clock event id
};

// A relay's emit posts through this, so an event a source publishes after the Runtime is gone
// finds nothing to post to.
struct Runtime::Inputs {
  std::mutex mutex;
  Runtime* runtime = nullptr;
};

Runtime::Runtime(Clock& clock, std::shared_ptr<Activity> activity)
    : clock_(clock), activity_(std::move(activity)), work_(io_.get_executor()), timers_(std::make_shared<TimerTable>()),
      inputs_(std::make_shared<Inputs>()) {
  inputs_->runtime = this;
  thread_ = std::thread([this] { io_.run(); });
}

Runtime::~Runtime() {
  {
    std::lock_guard lock(inputs_->mutex);
    inputs_->runtime = nullptr;
  }
  {
    std::lock_guard lock(timers_->mutex);
    for (const auto& [id, clock_id] : timers_->clock_ids) clock_.cancel(clock_id);
    timers_->clock_ids.clear();
  }
  work_.reset();
  io_.stop();
  if (thread_.joinable()) thread_.join();
  for (auto& [key, entry] : relays_) {
    if (!entry.source.expired() && entry.unsubscribe) entry.unsubscribe();
  }
}

void Runtime::post(std::function<void()> fn) {
  if (in_runtime_thread()) {
    // A consequence of the handler running now (every handler runs inside an input's wrapper,
    // which runs the consequences when the input's own handler is done).
    ++outstanding_;
    consequences_.push_back({std::move(fn), Activity::Hold(activity_.get())});
    return;
  }
  post_input(std::move(fn), {});
}

void Runtime::post_input(std::function<void()> fn, std::function<void()> then) {
  ++outstanding_;
  asio::post(io_, [this, fn = std::move(fn), then = std::move(then), hold = Activity::Hold(activity_.get())]() mutable {
    execute(fn);
    hold.release();
    if (run_consequences()) release_idle_relays();
    if (then) then();
  });
}

void Runtime::execute(std::function<void()>& fn) {
  try {
    fn();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "icars: behavior runtime: a handler threw: %s\n", e.what());
  } catch (...) {
    std::fprintf(stderr, "icars: behavior runtime: a handler threw\n");
  }
  ++handlers_run_;
  --outstanding_;
}

bool Runtime::run_consequences() {
  // A tree that keeps itself busy without time passing (a Repeat around a child that completes
  // at once) would never let an input in; past this many, the rest wait behind the inputs
  // queued meanwhile, as it would have without run to completion.
  constexpr int kMaxInARow = 100'000;
  for (int n = 0; !consequences_.empty(); ++n) {
    if (n == kMaxInARow) {
      if (!warned_busy_) {
        warned_busy_ = true;
        std::fprintf(stderr, "icars: behavior runtime: %d handlers in a row without an input (a tree busy at one "
                             "instant?); letting inputs in between\n", n);
      }
      asio::post(io_, [this] {
        if (run_consequences()) release_idle_relays();
      });
      return false;
    }
    auto next = std::move(consequences_.front());
    consequences_.pop_front();
    execute(next.fn);
    next.hold.release();
  }
  return true;
}

// Between inputs, a relay nobody listens to is not a step of a transition (a task left, the
// next one about to listen) but the end of listening: it stops listening to its source.
void Runtime::release_idle_relays() {
  if (!relays_idle_) return;
  relays_idle_ = false;
  for (auto it = relays_.begin(); it != relays_.end();) {
    auto& entry = it->second;
    if (entry.source.expired()) {
      it = relays_.erase(it);
    } else if (entry.relay->listeners_.empty()) {
      if (entry.unsubscribe) entry.unsubscribe();
      it = relays_.erase(it);
    } else {
      ++it;
    }
  }
}

std::uint64_t Runtime::Relay::add(std::function<void(const planet::Event&)> fn) {
  const auto id = next_++;
  listeners_.emplace(id, std::move(fn));
  return id;
}

void Runtime::Relay::remove(std::uint64_t id) {
  listeners_.erase(id);
  if (listeners_.empty()) runtime_.relays_idle_ = true;
}

void Runtime::Relay::dispatch(const planet::Event& e) {
  // A listener may remove itself or others (its behavior completing): each is looked up again.
  std::vector<std::uint64_t> ids;
  ids.reserve(listeners_.size());
  for (const auto& [id, fn] : listeners_) ids.push_back(id);
  for (const auto id : ids) {
    const auto it = listeners_.find(id);
    if (it == listeners_.end()) continue;
    auto fn = it->second;  // the listener may remove itself while it runs
    fn(e);
  }
}

std::shared_ptr<Runtime::Relay> Runtime::relay(
    const std::shared_ptr<const void>& source,
    const std::function<std::function<void()>(std::function<void(planet::Event)> emit)>& subscribe) {
  for (auto it = relays_.begin(); it != relays_.end();) {
    it = it->second.source.expired() ? relays_.erase(it) : std::next(it);
  }
  auto& entry = relays_[source.get()];
  if (!entry.relay) {
    entry.source = source;
    entry.relay = std::make_shared<Relay>(*this);
    entry.unsubscribe = subscribe([inputs = inputs_, weak = std::weak_ptr<Relay>(entry.relay)](planet::Event e) {
      std::lock_guard lock(inputs->mutex);
      if (!inputs->runtime) return;
      inputs->runtime->post([weak, e = std::move(e)] {
        if (auto relay = weak.lock()) relay->dispatch(e);  // gone with its source: dropped
      });
    });
  }
  return entry.relay;
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
