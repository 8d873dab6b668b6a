// PLANET servants: typed operations, servant objects and the object adapter.
//
// An interface is described once by typed `Operation` constants that both sides share:
//
//   struct Calculator {
//     static constexpr std::string_view type_id = "demo::Calculator";
//     static constexpr planet::Operation<std::int32_t(std::int32_t, std::int32_t)> add{"add"};
//     static constexpr planet::OneWay<std::string> log{"log"};
//   };
//
// A servant implements operations with ordinary C++ callables (`implement(Calculator::add,
// [](std::int32_t a, std::int32_t b) { return a + b; })`); the adapter decodes and type-checks the
// arguments, calls the servant and encodes the result or the exception. A callable may take a
// trailing `const Current&` to learn which connection called it (to call the caller back).
// A callable that returns `asio::awaitable<R>` is run as a coroutine on the io thread, so an
// implementation can itself `co_await` other remote calls before it answers.
// The ObjectAdapter maps servant paths ("/home/tv") to servants.
#pragma once

#include <asio/awaitable.hpp>
#include <cstdint>
#include <functional>
#include <optional>
#include <memory>
#include <shared_mutex>
#include <string>
#include <string_view>
#include <tuple>
#include <type_traits>
#include <unordered_map>
#include <utility>
#include <vector>

#include "icars/planet/connection.h"
#include "icars/planet/event.h"
#include "icars/planet/serializer.h"

namespace icars::planet {

// A two-way operation with a typed signature, e.g. Operation<std::int32_t(std::int32_t)>.
template <class Signature>
class Operation;

template <class R, class... A>
class Operation<R(A...)> {
  static_assert((std::is_same_v<A, std::decay_t<A>> && ...),
                "operation parameters are value types (std::string, not const std::string&)");

 public:
  using Result = R;
  constexpr explicit Operation(std::string_view name) : name_(name) {}
  constexpr std::string_view name() const { return name_; }

 private:
  std::string_view name_;
};

// A one-way operation: sent as NOTIFY, no reply, no result, errors only logged by the callee.
template <class... A>
class OneWay {
 public:
  constexpr explicit OneWay(std::string_view name) : name_(name) {}
  constexpr std::string_view name() const { return name_; }

 private:
  std::string_view name_;
};

// What a servant may learn about the request it is serving.
struct Current {
  std::shared_ptr<Connection> connection;  // the link the request came over
  std::string_view path;
  std::string_view method;
  std::uint32_t request_id = 0;  // 0 for NOTIFY
};

namespace detail {

struct StringHash {
  using is_transparent = void;
  std::size_t operator()(std::string_view s) const noexcept {
    return std::hash<std::string_view>{}(s);
  }
};

[[noreturn]] void fail_argument(Reader& r, std::string_view method, std::size_t index,
                                std::span<const std::byte> expected,
                                std::span<const std::byte> actual);
[[noreturn]] void fail_arity(Reader& r, std::string_view method, std::size_t expected,
                             std::size_t actual);

template <class T>
T decode_argument(Reader& r, std::string_view method, std::size_t index) {
  const auto actual = read_descriptor(r);
  const auto expected = descriptor_of<T>();
  if (actual.size() != expected.size() ||
      std::memcmp(actual.data(), expected.data(), actual.size()) != 0) {
    fail_argument(r, method, index, expected, actual);
  }
  return Codec<T>::decode(r);
}

template <class... A, std::size_t... I>
std::tuple<A...> decode_arguments(Reader& r, std::string_view method, std::index_sequence<I...>) {
  const std::uint8_t argc = r.u8();
  if (argc != sizeof...(A)) fail_arity(r, method, sizeof...(A), argc);
  // Braced initialisation evaluates left to right, so arguments are read in order.
  std::tuple<A...> args{decode_argument<A>(r, method, I + 1)...};
  if (r.remaining() != 0) r.fail("trailing bytes after the arguments of '" + std::string(method) + "'");
  return args;
}

template <class T>
struct IsAwaitable : std::false_type {};
template <class T, class E>
struct IsAwaitable<asio::awaitable<T, E>> : std::true_type {};

template <class F, class... A>
decltype(auto) invoke_with_current(F& fn, std::tuple<A...>& args, const Current& current) {
  return std::apply(
      [&](A&... a) -> decltype(auto) {
        if constexpr (std::is_invocable_v<F&, A&&..., const Current&>) {
          return std::invoke(fn, std::move(a)..., current);
        } else {
          static_assert(std::is_invocable_v<F&, A&&...>,
                        "the implementation does not accept the operation's parameters");
          return std::invoke(fn, std::move(a)...);
        }
      },
      args);
}

}  // namespace detail

class Servant {
 public:
  explicit Servant(std::string type_id) : type_id_(std::move(type_id)) {}
  virtual ~Servant() = default;
  Servant(const Servant&) = delete;
  Servant& operator=(const Servant&) = delete;

  const std::string& type_id() const { return type_id_; }
  bool has_method(std::string_view name) const { return methods_.find(name) != methods_.end(); }

  // The tagged result of an asynchronous implementation.
  using AsyncResult = asio::awaitable<std::vector<std::byte>>;

  // Implements a two-way operation. `fn` returns R, void or asio::awaitable<R> and may throw
  // RemoteException.
  template <class R, class... A, class F>
  void implement(const Operation<R(A...)>& op, F fn) {
    const std::string_view name = op.name();
    using Returned = std::remove_cvref_t<decltype(detail::invoke_with_current(
        fn, std::declval<std::tuple<A...>&>(), std::declval<const Current&>()))>;
    if constexpr (detail::IsAwaitable<Returned>::value) {
      methods_[std::string(name)] = [fn = std::move(fn), name](
                                        Reader& in, Writer*,
                                        const Current& current) -> std::optional<AsyncResult> {
        auto args = detail::decode_arguments<A...>(in, name, std::index_sequence_for<A...>{});
        return run_async<R>(fn, std::move(args), current.connection, std::string(current.path),
                            std::string(current.method), current.request_id);
      };
    } else {
      implement_sync<R, A...>(name, std::move(fn));
    }
  }

  // Implements a one-way operation.
  template <class... A, class F>
  void implement(const OneWay<A...>& op, F fn) {
    const std::string_view name = op.name();
    methods_[std::string(name)] = [fn = std::move(fn), name](
                                      Reader& in, Writer* out,
                                      const Current& current) mutable -> std::optional<AsyncResult> {
      auto args = detail::decode_arguments<A...>(in, name, std::index_sequence_for<A...>{});
      detail::invoke_with_current(fn, args, current);
      if (out) out->u8(static_cast<std::uint8_t>(TypeCode::void_type));
      return std::nullopt;
    };
  }

  // Decodes the arguments in `args`, runs the method and, for a CALL, writes the tagged result
  // into `result`; an asynchronous implementation instead returns the coroutine that produces
  // the tagged result. Throws Error(unimplemented) for an unknown method, Error(bad_data) for
  // arguments of the wrong number or types, and whatever the implementation throws.
  std::optional<AsyncResult> dispatch(std::string_view method, Reader& args, Writer* result,
                                      const Current& current);

 private:
  template <class R, class... A, class F>
  void implement_sync(std::string_view name, F fn) {
    methods_[std::string(name)] = [fn = std::move(fn), name](
                                      Reader& in, Writer* out,
                                      const Current& current) mutable -> std::optional<AsyncResult> {
      auto args = detail::decode_arguments<A...>(in, name, std::index_sequence_for<A...>{});
      if constexpr (std::is_void_v<R>) {
        detail::invoke_with_current(fn, args, current);
        if (out) out->u8(static_cast<std::uint8_t>(TypeCode::void_type));
      } else {
        R result = detail::invoke_with_current(fn, args, current);
        if (out) encode_tagged(*out, result);
      }
      return std::nullopt;
    };
  }

  template <class R, class F, class... A>
  static AsyncResult run_async(F fn, std::tuple<A...> args, std::shared_ptr<Connection> connection,
                               std::string path, std::string method, std::uint32_t request_id) {
    const Current current{std::move(connection), path, method, request_id};
    std::vector<std::byte> out;
    Writer w(out);
    if constexpr (std::is_void_v<R>) {
      co_await detail::invoke_with_current(fn, args, current);
      w.u8(static_cast<std::uint8_t>(TypeCode::void_type));
    } else {
      R result = co_await detail::invoke_with_current(fn, args, current);
      encode_tagged(w, result);
    }
    co_return out;
  }

  using Method = std::function<std::optional<AsyncResult>(Reader&, Writer*, const Current&)>;
  std::string type_id_;
  std::unordered_map<std::string, Method, detail::StringHash, std::equal_to<>> methods_;
};

// Maps servant paths to servants. Thread-safe.
class ObjectAdapter {
 public:
  // Registers a servant; throws std::invalid_argument if the path is taken or malformed.
  void add(const std::string& path, std::shared_ptr<Servant> servant);
  bool remove(std::string_view path);
  std::shared_ptr<Servant> find(std::string_view path) const;
  std::vector<std::string> paths() const;

 private:
  mutable std::shared_mutex mutex_;
  std::unordered_map<std::string, std::shared_ptr<Servant>, detail::StringHash, std::equal_to<>>
      servants_;
};

}  // namespace icars::planet
