// PLANET proxies (stubs): typed calls on a remote object.
//
// A Proxy names a remote object by link and servant path and invokes its operations:
//
//   planet::Proxy calc(communicator, peer, "/calc");
//   std::int32_t sum = calc.call(Calculator::add, 2, 3);                   // synchronous
//   calc.async_call(Calculator::add, {2, 3}, [](std::exception_ptr e, std::int32_t sum) {...});
//   std::future<std::int32_t> f = calc.async_call(Calculator::add, {2, 3}, asio::use_future);
//   std::int32_t s = co_await calc.async_call(Calculator::add, {2, 3}, asio::use_awaitable);
//   calc.notify(Calculator::log, "hello");                                  // one-way
//
// Failures arrive as Error (disconnected, overloaded, timeout, unimplemented, bad_data) or as
// RemoteException for exceptions the servant raised. An operation declared idempotent
// (CallMode::idempotent, IDL `idempotent`) is not failed with `disconnected` over a reconnecting
// link (Peer): it is sent again once the link is back, until its deadline (see
// Communicator::start_call); other calls are sent at most once. Asynchronous calls follow asio's
// completion-token model: completion signature void(std::exception_ptr, R) (void(exception_ptr)
// when R is void); the handler runs exactly once, on its associated executor (the
// communicator's io thread by default), never inside async_call itself.
#pragma once

#include <asio/async_result.hpp>
#include <asio/associated_executor.hpp>
#include <asio/executor_work_guard.hpp>
#include <asio/post.hpp>
#include <atomic>
#include <chrono>
#include <exception>
#include <memory>
#include <mutex>
#include <semaphore>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

#include "icars/planet/communicator.h"
#include "icars/planet/serializer.h"
#include "icars/planet/servant.h"

namespace icars::planet {

template <class R>
struct CompletionSignature {
  using type = void(std::exception_ptr, R);
};
template <>
struct CompletionSignature<void> {
  using type = void(std::exception_ptr);
};

// Hears of the two-way calls sent through a proxy that carries it (Proxy::set_observer), so a
// caller can keep a record of what it asked and how each request ended, to be matched with the
// callee's record by request id. Called on the calling thread and on the thread that completes
// the call: it must be thread-safe and must not block.
class CallObserver {
 public:
  virtual ~CallObserver() = default;
  // The request left as request `request_id` of this communicator (an idempotent call waiting
  // for its link is reported once, when it is registered; a resend keeps the id).
  virtual void sent(std::uint32_t request_id, const std::string& path, std::string_view method) = 0;
  // Exactly once per call, after `sent`: `error` is null when a well-formed reply arrived. A
  // call that could not be sent at all (the link is down) ends with request id 0 and no `sent`.
  virtual void ended(std::uint32_t request_id, const std::string& path, std::string_view method,
                     const std::exception_ptr& error) = 0;
};

namespace detail {
// Orders an observed call's `sent` before its `ended`: the reply may complete the call on the
// io thread before start_call has returned the request id to the calling thread.
class ObservedCall {
 public:
  ObservedCall(std::shared_ptr<CallObserver> observer, std::string path, std::string_view method)
      : observer_(std::move(observer)), path_(std::move(path)), method_(method) {}
  void started(std::uint32_t request_id) {
    std::lock_guard lock(mutex_);
    id_ = request_id;
    started_ = true;
    if (request_id != 0) observer_->sent(request_id, path_, method_);
    if (ended_) observer_->ended(id_, path_, method_, error_);
  }
  void finished(const std::exception_ptr& error) {
    std::lock_guard lock(mutex_);
    ended_ = true;
    error_ = error;
    if (started_) observer_->ended(id_, path_, method_, error_);
  }

 private:
  std::shared_ptr<CallObserver> observer_;
  std::string path_;
  std::string method_;  // its own copy: a relay's method name lives only as long as its call
  std::mutex mutex_;
  std::uint32_t id_ = 0;
  bool started_ = false;
  bool ended_ = false;
  std::exception_ptr error_;
};
}  // namespace detail

class Proxy {
 public:
  Proxy() = default;  // unbound: every call fails with Error(failed)
  Proxy(Communicator& communicator, std::shared_ptr<Link> link, std::string path)
      : communicator_(&communicator),
        link_(std::move(link)),
        path_(std::move(path)),
        timeout_(communicator.options().call_timeout) {}

  // A proxy for an object passed by reference that arrived over `via` (for a servant, the
  // connection of the request: `current.connection`); the link is chosen by
  // Communicator::resolve, so a reference to an object of the caller calls back over the
  // caller's own connection.
  Proxy(Communicator& communicator, const std::shared_ptr<Link>& via, const ObjectRef& ref)
      : Proxy(communicator, communicator.resolve(ref, via), ref.path) {}

  bool bound() const { return communicator_ != nullptr && link_ != nullptr; }
  Communicator& communicator() const {
    if (!communicator_) throw Error(ErrorKind::failed, "unbound proxy");
    return *communicator_;
  }
  // A reference to this proxy's object, to pass on to another peer. The PUN names the peer at
  // the other end of the link (empty if the link is down), so the receiver can reach it.
  ObjectRef object(std::string_view type_id) const {
    std::string pun;
    if (link_) {
      if (auto c = link_->connection()) pun = c->peer_pun();
    }
    return ObjectRef{std::move(pun), path_, std::string(type_id)};
  }
  const std::string& path() const { return path_; }
  const std::shared_ptr<Link>& link() const { return link_; }
  std::chrono::milliseconds timeout() const { return timeout_; }
  Proxy with_timeout(std::chrono::milliseconds timeout) const {
    Proxy copy = *this;
    copy.timeout_ = timeout;
    return copy;
  }
  // Sets the deadline of later calls through this proxy (typed stubs keep their type).
  void set_timeout(std::chrono::milliseconds timeout) { timeout_ = timeout; }
  // Reports later two-way calls through this proxy and its copies to `observer` (null: none).
  void set_observer(std::shared_ptr<CallObserver> observer) { observer_ = std::move(observer); }

  // Synchronous call: blocks the calling thread until the reply, an error or the timeout.
  // Calling it on the communicator's io thread throws (it would deadlock); use async_call.
  template <class R, class... A>
  R call(const Operation<R(A...)>& op, const std::type_identity_t<A>&... args) const {
    check_bound(op.name());
    if (communicator_->in_io_thread()) {
      throw Error(ErrorKind::failed,
                  "synchronous call of '" + std::string(op.name()) +
                      "' on the PLANET io thread would deadlock; use async_call");
    }
    struct State {
      std::binary_semaphore done{0};
      std::atomic<bool> answered{false};
      std::exception_ptr error;
      std::conditional_t<std::is_void_v<R>, char, R> value{};
    } state;
    auto request = encode_request(RmiCode::call, op.name(), args...);
    auto observed = observe(op.name());
    const std::uint32_t id = communicator_->start_call(
        link_, std::move(request), timeout_, op.mode(),
        [&state, observed](std::exception_ptr e, Reader* r) {
          if (!e) {
            try {
              if constexpr (std::is_void_v<R>) {
                expect_void(*r);
              } else {
                state.value = decode_result<R>(*r);
              }
            } catch (...) {
              e = std::current_exception();
            }
          }
          if (observed) observed->finished(e);
          state.error = e;
          state.answered.store(true);
          state.done.release();
        });
    if (observed) observed->started(id);
    // The reply is read on this thread when nothing else is arriving (one thread hop less).
    if (id != 0) {
      communicator_->read_reply(*link_, id, std::chrono::steady_clock::now() + timeout_,
                                [&state] { return state.answered.load(); });
    }
    // The deadline sweep fails the call at its deadline; the extra second only guards
    // against a stalled io thread.
    if (!state.done.try_acquire_for(timeout_ + std::chrono::seconds(1))) {
      communicator_->cancel_call(id, timeout_error(op.name()));
      state.done.acquire();
    }
    if (state.error) std::rethrow_exception(translate(op.translator(), state.error));
    if constexpr (!std::is_void_v<R>) return std::move(state.value);
  }

  // Asynchronous call (AMI) with any asio completion token: a callback, asio::use_future,
  // asio::use_awaitable, asio::deferred...
  template <class R, class... A, class Token>
  auto async_call(const Operation<R(A...)>& op, std::type_identity_t<std::tuple<A...>> args,
                  Token&& token) const {
    using Signature = typename CompletionSignature<R>::type;
    return asio::async_initiate<Token, Signature>(
        [this, name = op.name(), translator = op.translator(), mode = op.mode()](
            auto handler, std::tuple<A...> call_args) {
          check_bound(name);
          auto request = std::apply(
              [&](const A&... a) { return encode_request(RmiCode::call, name, a...); }, call_args);
          auto work = asio::make_work_guard(
              asio::get_associated_executor(handler, communicator_->executor()));
          auto observed = observe(name);
          const std::uint32_t id = communicator_->start_call(
              link_, std::move(request), timeout_, mode,
              [handler = std::move(handler), work = std::move(work), translator, observed,
               activity = communicator_->activity()](std::exception_ptr e, Reader* r) mutable {
                std::conditional_t<std::is_void_v<R>, char, R> value{};
                if (e) e = translate(translator, e);
                if (!e) {
                  try {
                    if constexpr (std::is_void_v<R>) {
                      expect_void(*r);
                    } else {
                      value = decode_result<R>(*r);
                    }
                  } catch (...) {
                    e = std::current_exception();
                  }
                }
                if (observed) observed->finished(e);
                auto ex = work.get_executor();
                // Lock-step: the completion is work until the handler has run.
                asio::post(ex, [handler = std::move(handler), e, value = std::move(value),
                                work = std::move(work), hold = Activity::Hold(activity.get())]() mutable {
                  if constexpr (std::is_void_v<R>) {
                    (void)value;
                    std::move(handler)(e);
                  } else {
                    std::move(handler)(e, std::move(value));
                  }
                  hold.release();
                });
              });
          if (observed) observed->started(id);
        },
        token, std::move(args));
  }

  // A relay's call (Servant::forward_others): `method` with arguments already encoded (`args`:
  // the count and the tagged values, as ForwardedCall carries them), sent at most once or, with
  // CallMode::idempotent over a Peer, again after a reconnection. The handler gets (error, the
  // tagged result's bytes); a RemoteException from the servant comes back as it was thrown.
  template <class Token>
  auto async_call_raw(std::string method, std::vector<std::byte> args, CallMode mode, Token&& token) const {
    using Signature = void(std::exception_ptr, std::vector<std::byte>);
    return asio::async_initiate<Token, Signature>(
        [this, mode](auto handler, std::string name, std::vector<std::byte> raw_args) {
          check_bound(name);
          auto request = encode_raw_request(RmiCode::call, name, raw_args);
          auto work = asio::make_work_guard(asio::get_associated_executor(handler, communicator_->executor()));
          auto observed = observe(name);
          const std::uint32_t id = communicator_->start_call(
              link_, std::move(request), timeout_, mode,
              [handler = std::move(handler), work = std::move(work), observed,
               activity = communicator_->activity()](std::exception_ptr e, Reader* r) mutable {
                std::vector<std::byte> result;
                if (!e && r) {
                  const auto rest = r->rest();
                  result.assign(rest.begin(), rest.end());
                }
                if (observed) observed->finished(e);
                auto ex = work.get_executor();
                asio::post(ex, [handler = std::move(handler), e, result = std::move(result),
                                work = std::move(work), hold = Activity::Hold(activity.get())]() mutable {
                  std::move(handler)(e, std::move(result));
                  hold.release();
                });
              });
          if (observed) observed->started(id);
        },
        token, std::move(method), std::move(args));
  }
  // A relay's NOTIFY, arguments already encoded; as notify().
  void notify_raw(std::string_view method, std::span<const std::byte> args) const {
    check_bound(method);
    communicator_->send_oneway(*link_, encode_raw_request(RmiCode::notify, method, args));
  }

  // One-way call (NOTIFY): returns once queued. Throws Error(disconnected) when the link is down
  // and Error(overloaded) when the send queue is full. Delivery is at most once: a NOTIFY still
  // queued when the link drops is discarded, never replayed after reconnection.
  template <class... A>
  void notify(const OneWay<A...>& op, const std::type_identity_t<A>&... args) const {
    check_bound(op.name());
    communicator_->send_oneway(*link_, encode_request(RmiCode::notify, op.name(), args...));
  }

 private:
  void check_bound(std::string_view method) const {
    if (!bound()) {
      throw Error(ErrorKind::failed, "call of '" + std::string(method) + "' on an unbound proxy");
    }
  }
  // Replaces a RemoteException by the typed exception the operation declares, if any.
  static std::exception_ptr translate(ExceptionTranslator translator, std::exception_ptr e) {
    if (!translator) return e;
    try {
      std::rethrow_exception(e);
    } catch (const RemoteException& remote) {
      return translator(remote);
    } catch (...) {
      return e;
    }
  }

  std::shared_ptr<detail::ObservedCall> observe(std::string_view method) const {
    if (!observer_) return nullptr;
    return std::make_shared<detail::ObservedCall>(observer_, path_, method);
  }

  template <class... A>
  std::vector<std::byte> encode_request(RmiCode code, std::string_view method,
                                        const A&... args) const {
    std::vector<std::byte> out;
    out.reserve(64 + path_.size() + method.size());
    Writer w(out);
    w.u8(static_cast<std::uint8_t>(code));
    w.u32(0);  // request id, assigned by the communicator
    w.str(path_);
    w.str(method);
    w.u8(static_cast<std::uint8_t>(sizeof...(A)));
    (encode_tagged(w, args), ...);
    return out;
  }

  std::vector<std::byte> encode_raw_request(RmiCode code, std::string_view method,
                                            std::span<const std::byte> args) const {
    if (args.empty()) throw Error(ErrorKind::bad_data, "forwarded '" + std::string(method) + "' has no argument count");
    std::vector<std::byte> out;
    out.reserve(16 + path_.size() + method.size() + args.size());
    Writer w(out);
    w.u8(static_cast<std::uint8_t>(code));
    w.u32(0);  // request id, assigned by the communicator
    w.str(path_);
    w.str(method);
    w.raw(args);
    return out;
  }

  template <class R>
  static R decode_result(Reader& r) {
    R value = decode_tagged<R>(r, "result");
    if (r.remaining() != 0) r.fail("trailing bytes after the result");
    return value;
  }
  static void expect_void(Reader& r) {
    if (r.u8() != static_cast<std::uint8_t>(TypeCode::void_type) || r.remaining() != 0) {
      r.fail("result: expected void");
    }
  }
  Error timeout_error(std::string_view method) const {
    return Error(ErrorKind::timeout, "no reply to '" + std::string(method) + "' on " + path_ +
                                         " within " + std::to_string(timeout_.count()) + " ms");
  }

  Communicator* communicator_ = nullptr;
  std::shared_ptr<Link> link_;
  std::string path_;
  std::chrono::milliseconds timeout_{0};
  std::shared_ptr<CallObserver> observer_;
};

}  // namespace icars::planet
