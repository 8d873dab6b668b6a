#include "icars/planet/servant.h"

#include "icars/clock/activity.h"
#include "icars/planet/communicator.h"

#include <fmt/format.h>

#include <asio/co_spawn.hpp>
#include <asio/use_awaitable.hpp>

#include <mutex>
#include <stdexcept>

namespace icars::planet {

namespace detail {

void fail_argument(Reader& r, std::string_view method, std::size_t index,
                   std::span<const std::byte> expected, std::span<const std::byte> actual) {
  r.fail(fmt::format("argument {} of '{}': expected {}, got {}", index, method,
                     describe(expected), describe(actual)));
}

void fail_arity(Reader& r, std::string_view method, std::size_t expected, std::size_t actual) {
  r.fail(fmt::format("'{}' takes {} argument{}, got {}", method, expected,
                     expected == 1 ? "" : "s", actual));
}

// Servant calls running on this thread (synchronous dispatches, nested ones included): remove()
// called from inside one must not wait, it might wait for itself.
thread_local int t_running_calls = 0;

// Counts a servant call in t_running_calls while it runs on this thread.
struct RunningCall {
  RunningCall() { ++t_running_calls; }
  ~RunningCall() { --t_running_calls; }
  RunningCall(const RunningCall&) = delete;
  RunningCall& operator=(const RunningCall&) = delete;
};

}  // namespace detail

std::optional<Servant::AsyncResult> Servant::dispatch(std::string_view method, Reader& args,
                                                      Writer* result, const Current& current) {
  auto it = methods_.find(method);
  if (it == methods_.end() && forward_) {
    const auto rest = args.rest();
    return forward_(ForwardedCall{current.connection, std::string(current.path), std::string(method),
                                  std::vector<std::byte>(rest.begin(), rest.end()), result == nullptr,
                                  current.communicator});
  }
  if (it == methods_.end()) {
    throw Error(ErrorKind::unimplemented,
                fmt::format("servant at '{}' ({}) has no method '{}'", current.path, type_id_,
                            method));
  }
  if (executor_ && !coroutines_.contains(method)) {
    const auto rest = args.rest();
    return run_elsewhere(it->second, std::vector<std::byte>(rest.begin(), rest.end()), result != nullptr, current,
                         std::string(current.path), std::string(current.method));
  }
  return it->second(args, result, current);
}

Servant::AsyncResult Servant::run_elsewhere(const Method& method, std::vector<std::byte> args, bool two_way,
                                            Current current, std::string path, std::string name) {
  // Work in progress of this process while it runs elsewhere (a lock-step clock waits for it).
  Activity::Hold busy(current.communicator ? current.communicator->activity().get() : nullptr);
  current.path = path;
  current.method = name;
  // A capture-less coroutine: what it uses lives in its own frame, on the executor.
  const auto on_executor = [](const Method* fn, std::vector<std::byte> bytes, bool reply,
                              Current call) -> asio::awaitable<std::vector<std::byte>> {
    Reader in(bytes);
    std::vector<std::byte> out;
    Writer w(out);
    std::optional<AsyncResult> pending;
    {
      const detail::RunningCall running;  // counted while it runs on this thread
      pending = (*fn)(in, reply ? &w : nullptr, call);
    }
    if (pending) co_return co_await std::move(*pending);
    co_return out;
  };
  co_return co_await asio::co_spawn(executor_, on_executor(&method, std::move(args), two_way, current),
                                    asio::use_awaitable);
}

// --- ObjectAdapter::Dispatch ----------------------------------------------------------------

ObjectAdapter::Dispatch& ObjectAdapter::Dispatch::operator=(Dispatch&& other) noexcept {
  if (this != &other) {
    release();
    servant_ = std::move(other.servant_);
    calls_ = std::move(other.calls_);
  }
  return *this;
}

ObjectAdapter::Dispatch::~Dispatch() { release(); }

// Drops the servant before counting the call out, so that when this held the last reference the
// servant is destroyed before a waiting remove() returns.
void ObjectAdapter::Dispatch::release() {
  servant_.reset();
  if (!calls_) return;
  auto calls = std::move(calls_);
  std::lock_guard lock(calls->mutex);
  if (--calls->count == 0) calls->idle.notify_all();
}

std::optional<Servant::AsyncResult> ObjectAdapter::Dispatch::run(std::string_view method,
                                                                 Reader& args, Writer* result,
                                                                 const Current& current) {
  const detail::RunningCall running;
  return servant_->dispatch(method, args, result, current);
}

// --- ObjectAdapter -------------------------------------------------------------------------

void ObjectAdapter::add(const std::string& path, std::shared_ptr<Servant> servant) {
  if (path.empty() || path.front() != '/') {
    throw std::invalid_argument(fmt::format("servant path '{}' must start with '/'", path));
  }
  if (!servant) throw std::invalid_argument("null servant for path " + path);
  std::unique_lock lock(mutex_);
  if (!servants_.emplace(path, Entry{std::move(servant), std::make_shared<detail::ActiveCalls>()})
           .second) {
    throw std::invalid_argument(fmt::format("a servant is already registered at '{}'", path));
  }
}

bool ObjectAdapter::remove(std::string_view path) { return remove(path, nullptr); }

bool ObjectAdapter::remove(std::string_view path, const Servant* only) {
  Entry removed;
  {
    std::unique_lock lock(mutex_);
    auto it = servants_.find(path);
    if (it == servants_.end()) return false;
    if (only && it->second.servant.get() != only) return false;
    removed = std::move(it->second);
    servants_.erase(it);
  }
  // Every call that found the servant counted itself in under the adapter's lock, so none can
  // start after this point.
  removed.servant.reset();
  const bool may_wait =
      detail::t_running_calls == 0 && !(on_io_thread_ && on_io_thread_());
  if (may_wait) {
    std::unique_lock lock(removed.calls->mutex);
    removed.calls->idle.wait(lock, [&] { return removed.calls->count == 0; });
  }
  return true;
}

std::shared_ptr<Servant> ObjectAdapter::find(std::string_view path) const {
  std::shared_lock lock(mutex_);
  auto it = servants_.find(path);
  return it == servants_.end() ? nullptr : it->second.servant;
}

ObjectAdapter::Dispatch ObjectAdapter::begin_call(std::string_view path) const {
  Dispatch call;
  std::shared_lock lock(mutex_);
  auto it = servants_.find(path);
  if (it == servants_.end()) return call;
  {
    std::lock_guard count_lock(it->second.calls->mutex);
    ++it->second.calls->count;
  }
  call.servant_ = it->second.servant;
  call.calls_ = it->second.calls;
  return call;
}

std::vector<std::string> ObjectAdapter::paths() const {
  std::shared_lock lock(mutex_);
  std::vector<std::string> out;
  for (const auto& [path, s] : servants_) out.push_back(path);
  return out;
}

}  // namespace icars::planet
