#include "test_interfaces.h"

#include <chrono>
#include <stdexcept>
#include <thread>

#include <asio/use_awaitable.hpp>

#include "icars/planet/proxy.h"

namespace planet_test {

namespace {
template <class T>
void echo(p::Servant& s, const p::Operation<T(T)>& op) {
  s.implement(op, [](T v) { return v; });
}
}  // namespace

std::shared_ptr<p::Servant> make_echo_servant(p::Communicator& communicator) {
  auto s = std::make_shared<p::Servant>(std::string(Echo::type_id));
  auto counter = std::make_shared<std::atomic<std::int64_t>>(0);
  s->implement(Echo::ping, [] {});
  echo(*s, Echo::echo_bool);
  echo(*s, Echo::echo_byte);
  echo(*s, Echo::echo_short);
  echo(*s, Echo::echo_int);
  echo(*s, Echo::echo_long);
  echo(*s, Echo::echo_float);
  echo(*s, Echo::echo_double);
  echo(*s, Echo::echo_string);
  echo(*s, Echo::echo_binary);
  echo(*s, Echo::echo_stream);
  echo(*s, Echo::echo_enum);
  echo(*s, Echo::echo_pose);
  echo(*s, Echo::echo_reading);
  echo(*s, Echo::echo_event);
  echo(*s, Echo::echo_remote);
  echo(*s, Echo::echo_bools);
  echo(*s, Echo::echo_bytes);
  echo(*s, Echo::echo_shorts);
  echo(*s, Echo::echo_ints);
  echo(*s, Echo::echo_longs);
  echo(*s, Echo::echo_floats);
  echo(*s, Echo::echo_doubles);
  echo(*s, Echo::echo_strings);
  echo(*s, Echo::echo_binaries);
  echo(*s, Echo::echo_enums);
  echo(*s, Echo::echo_poses);
  echo(*s, Echo::echo_events);
  echo(*s, Echo::echo_remotes);
  echo(*s, Echo::echo_nested);
  s->implement(Echo::echo_exception, [](p::RemoteException e) { return e; });
  s->implement(Echo::mix, [](std::int32_t a, const std::string& b, double c) {
    return a + static_cast<std::int32_t>(b.size()) + static_cast<std::int32_t>(c);
  });
  s->implement(Echo::size_of,
               [](const p::Binary& b) { return static_cast<std::int64_t>(b.bytes.size()); });
  s->implement(Echo::make_binary, [](std::int32_t n) {
    p::Binary b;
    b.bytes.resize(static_cast<std::size_t>(n));
    for (std::size_t i = 0; i < b.bytes.size(); ++i) b.bytes[i] = std::byte(i * 7);
    return b;
  });
  s->implement(Echo::refuse, [](const std::string& why) {
    throw p::RemoteException("test::Refused", why, p::Properties().set("code", std::int32_t{42}));
  });
  s->implement(Echo::crash, [] { throw std::runtime_error("servant crashed on purpose"); });
  s->implement(Echo::count, [counter](std::int32_t n) { *counter += n; });
  s->implement(Echo::counted, [counter] { return counter->load(); });
  auto absorbed = std::make_shared<std::vector<std::int64_t>>(2, 0);  // io thread only
  s->implement(Echo::absorb, [absorbed](const p::Binary& b) {
    (*absorbed)[0] += static_cast<std::int64_t>(b.bytes.size());
    (*absorbed)[1] += 1;
  });
  s->implement(Echo::absorbed, [absorbed] { return *absorbed; });
  s->implement(Echo::block_ms, [](std::int32_t ms) {
    std::this_thread::sleep_for(std::chrono::milliseconds(ms));
  });
  s->implement(Echo::caller_pun,
               [](const p::Current& current) { return current.connection->peer_pun(); });
  s->implement(Echo::call_back, [&communicator](p::ObjectRef ref, std::string text,
                                                const p::Current& current)
                                     -> asio::awaitable<std::string> {
    // Calls the object the caller passed by reference, over the caller's own connection.
    p::Proxy back(communicator, current.connection, ref);
    co_return co_await back.async_call(Callback::notify_me, {text}, asio::use_awaitable);
  });
  return s;
}

}  // namespace planet_test
