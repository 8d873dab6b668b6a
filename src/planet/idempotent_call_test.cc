// Idempotent operations (IDL `idempotent`, CallMode::idempotent) over a reconnecting link: a
// call that finds the link down, or loses its connection before the reply, is sent again once
// the Peer is back, until its deadline; its completion runs exactly once. At-most-once calls
// fail with `disconnected` in the same situations. Real sockets, a real server process, and a
// fault proxy that cuts or refuses connections.
#include <gtest/gtest.h>
#include <signal.h>

#include <asio/use_future.hpp>
#include <atomic>
#include <future>
#include <mutex>
#include <optional>
#include <thread>

#include "child_process.h"
#include "fault_proxy.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "test_interfaces.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;
using planet_test::Echo;

ErrorKind kind_of(const std::exception_ptr& e) {
  try {
    std::rethrow_exception(e);
  } catch (const Error& error) {
    return error.kind();
  } catch (...) {
    ADD_FAILURE() << "not a planet::Error";
    return ErrorKind::failed;
  }
}

template <class T>
ErrorKind error_of(std::future<T>& f) {
  try {
    f.get();
  } catch (const Error& e) {
    return e.kind();
  }
  ADD_FAILURE() << "the call succeeded";
  return ErrorKind::failed;
}

// Counts the completions of calls made with a callback: each must run exactly once.
struct Completions {
  std::mutex mutex;
  int count = 0;
  std::exception_ptr error;
  std::int64_t value = 0;
  auto handler() {
    return [this](std::exception_ptr e, std::int64_t v) {
      std::lock_guard lock(mutex);
      ++count;
      error = e;
      value = v;
    };
  }
  int seen() {
    std::lock_guard lock(mutex);
    return count;
  }
};

// A server in this process behind a fault proxy, and a client whose Peer goes through the proxy.
struct ProxiedServer {
  ProxiedServer()
      : server([] {
          CommunicatorOptions o;
          o.name = "server";
          return o;
        }()) {
    server.adapter().add("/echo", planet_test::make_echo_servant(server));
    port = server.listen("127.0.0.1", 0);
    faults = std::make_unique<planet_test::FaultProxy>("127.0.0.1", port);
  }
  // How many lingers the server started, asked over a direct connection (not the proxy).
  std::int64_t lingers_started(Communicator& client) {
    if (!direct) {
      direct = client.connect("127.0.0.1", port);
      EXPECT_TRUE(direct->wait_connected(20s));
    }
    return Proxy(client, direct, "/echo").call(Echo::lingers_started);
  }

  Communicator server;
  std::uint16_t port = 0;
  std::unique_ptr<planet_test::FaultProxy> faults;
  std::shared_ptr<Peer> direct;
};

TEST(IdempotentCall, StartedWhileTheServerIsDownCompletesOnceItIsBack) {
  auto server = planet_test::start_test_server();
  const std::uint16_t port = server.port;
  Communicator client;
  auto peer = client.connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy echo = Proxy(client, peer, "/echo").with_timeout(60s);
  EXPECT_EQ(echo.call(Echo::echo_int, 1), 1);

  server.process->signal(SIGKILL);
  server.process->wait();
  ASSERT_TRUE(planet_test::wait_until([&] { return !peer->is_connected(); }));

  // At most once: fails at once, as before.
  auto once = echo.async_call(Echo::linger_once, {0}, asio::use_future);
  ASSERT_EQ(once.wait_for(5s), std::future_status::ready);
  EXPECT_EQ(error_of(once), ErrorKind::disconnected);

  // Idempotent: waits for the link, asynchronously and synchronously.
  Completions completions;
  echo.async_call(Echo::linger, {0}, completions.handler());
  auto future = echo.async_call(Echo::linger, {0}, asio::use_future);
  auto blocking = std::async(std::launch::async, [&] { return echo.call(Echo::linger, 0); });
  ASSERT_TRUE(planet_test::wait_until([&] { return client.pending_calls() == 3; }));
  EXPECT_EQ(future.wait_for(300ms), std::future_status::timeout);
  EXPECT_EQ(completions.seen(), 0);

  auto restarted = planet_test::start_test_server({"--port", std::to_string(port)});
  ASSERT_EQ(future.wait_for(30s), std::future_status::ready) << peer->last_error();
  const std::int64_t runs = future.get();
  EXPECT_GE(runs, 1);
  EXPECT_LE(runs, 3);
  ASSERT_EQ(blocking.wait_for(10s), std::future_status::ready);
  EXPECT_GE(blocking.get(), 1);
  ASSERT_TRUE(planet_test::wait_until([&] { return completions.seen() == 1; }));
  EXPECT_EQ(completions.error, nullptr);
  // The restarted server ran each call once: nothing was sent to it twice.
  EXPECT_EQ(echo.call(Echo::lingers_started), 3);
  EXPECT_EQ(client.pending_calls(), 0u);
  std::this_thread::sleep_for(100ms);
  EXPECT_EQ(completions.seen(), 1);
}

TEST(IdempotentCall, ConnectionCutMidCallIsSentAgainAndCompletesOnce) {
  ProxiedServer setup;
  Communicator client;
  auto peer = client.connect("127.0.0.1", setup.faults->port());
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy echo = Proxy(client, peer, "/echo").with_timeout(30s);

  Completions completions;
  echo.async_call(Echo::linger, {400}, completions.handler());
  ASSERT_TRUE(planet_test::wait_until([&] { return setup.lingers_started(client) == 1; }));
  setup.faults->cut();

  ASSERT_TRUE(planet_test::wait_until([&] { return completions.seen() == 1; }))
      << peer->last_error();
  EXPECT_EQ(completions.error, nullptr);
  EXPECT_GE(peer->connect_count(), 2u);
  // The servant ran it once over the cut connection and once more over the new one; the caller
  // heard only the answer over the new connection (the first run or both had finished by then).
  EXPECT_EQ(setup.lingers_started(client), 2);
  EXPECT_GE(completions.value, 1);
  EXPECT_LE(completions.value, 2);
  std::this_thread::sleep_for(600ms);  // the first run's reply, if any, has nowhere to go
  EXPECT_EQ(completions.seen(), 1);
  EXPECT_EQ(client.pending_calls(), 0u);
}

TEST(IdempotentCall, AtMostOnceCallFailsWhenItsConnectionIsCut) {
  ProxiedServer setup;
  Communicator client;
  auto peer = client.connect("127.0.0.1", setup.faults->port());
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy echo = Proxy(client, peer, "/echo").with_timeout(30s);

  auto once = echo.async_call(Echo::linger_once, {400}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return setup.lingers_started(client) == 1; }));
  setup.faults->cut();
  ASSERT_EQ(once.wait_for(10s), std::future_status::ready);
  EXPECT_EQ(error_of(once), ErrorKind::disconnected);

  // The link comes back, but the call is not sent again.
  ASSERT_TRUE(planet_test::wait_until([&] { return peer->connect_count() >= 2; }));
  std::this_thread::sleep_for(200ms);
  EXPECT_EQ(setup.lingers_started(client), 1);
  EXPECT_EQ(client.pending_calls(), 0u);
}

TEST(IdempotentCall, DeadlinePassingWhileTheLinkIsDownEndsTheCallWithTimeout) {
  ProxiedServer setup;
  Communicator client;
  auto peer = client.connect("127.0.0.1", setup.faults->port());
  ASSERT_TRUE(peer->wait_connected(20s));
  setup.faults->refuse(true);
  setup.faults->cut();
  ASSERT_TRUE(planet_test::wait_until([&] { return !peer->is_connected(); }));

  Proxy echo = Proxy(client, peer, "/echo").with_timeout(500ms);
  const auto start = std::chrono::steady_clock::now();
  auto call = echo.async_call(Echo::linger, {0}, asio::use_future);
  ASSERT_EQ(call.wait_for(10s), std::future_status::ready);
  EXPECT_EQ(error_of(call), ErrorKind::timeout);
  const auto waited = std::chrono::steady_clock::now() - start;
  EXPECT_GE(waited, 450ms);
  EXPECT_LT(waited, 5s);
  // Synchronously too.
  try {
    echo.call(Echo::linger, 0);
    ADD_FAILURE() << "the call must time out";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::timeout) << e.what();
  }
  EXPECT_EQ(client.pending_calls(), 0u);

  // Nothing expired is sent once the link is back.
  setup.faults->refuse(false);
  ASSERT_TRUE(peer->wait_connected(20s));
  std::this_thread::sleep_for(200ms);
  EXPECT_EQ(setup.lingers_started(client), 0);
}

// Records the request ids of the calls a proxy sends.
class IdRecorder final : public CallObserver {
 public:
  void sent(std::uint32_t request_id, const std::string&, std::string_view) override {
    std::lock_guard lock(mutex_);
    ids_.push_back(request_id);
  }
  void ended(std::uint32_t, const std::string&, std::string_view,
             const std::exception_ptr&) override {}
  std::vector<std::uint32_t> ids() {
    std::lock_guard lock(mutex_);
    return ids_;
  }

 private:
  std::mutex mutex_;
  std::vector<std::uint32_t> ids_;
};

TEST(IdempotentCall, CancelledWhileWaitingCompletesOnceAndIsNeverSent) {
  ProxiedServer setup;
  Communicator client;
  auto peer = client.connect("127.0.0.1", setup.faults->port());
  ASSERT_TRUE(peer->wait_connected(20s));
  setup.faults->refuse(true);
  setup.faults->cut();
  ASSERT_TRUE(planet_test::wait_until([&] { return !peer->is_connected(); }));

  Proxy echo = Proxy(client, peer, "/echo").with_timeout(30s);
  auto recorder = std::make_shared<IdRecorder>();
  echo.set_observer(recorder);
  Completions completions;
  echo.async_call(Echo::linger, {0}, completions.handler());
  ASSERT_EQ(recorder->ids().size(), 1u);
  EXPECT_TRUE(client.cancel_call(recorder->ids()[0], Error(ErrorKind::failed, "cancelled")));
  EXPECT_FALSE(client.cancel_call(recorder->ids()[0], Error(ErrorKind::failed, "again")));
  ASSERT_TRUE(planet_test::wait_until([&] { return completions.seen() == 1; }));
  EXPECT_EQ(kind_of(completions.error), ErrorKind::failed);

  setup.faults->refuse(false);
  ASSERT_TRUE(peer->wait_connected(20s));
  std::this_thread::sleep_for(200ms);
  EXPECT_EQ(setup.lingers_started(client), 0);
  EXPECT_EQ(completions.seen(), 1);
}

TEST(IdempotentCall, DestroyingTheCommunicatorEndsWaitingCallsWithAnError) {
  ProxiedServer setup;
  auto client = std::make_unique<Communicator>();
  auto peer = client->connect("127.0.0.1", setup.faults->port());
  ASSERT_TRUE(peer->wait_connected(20s));
  setup.faults->refuse(true);
  setup.faults->cut();
  ASSERT_TRUE(planet_test::wait_until([&] { return !peer->is_connected(); }));

  Proxy echo = Proxy(*client, peer, "/echo").with_timeout(60s);
  Completions completions;
  echo.async_call(Echo::linger, {0}, completions.handler());
  auto future = echo.async_call(Echo::linger, {0}, asio::use_future);
  std::promise<ErrorKind> sync_result;
  std::thread blocking([&] {
    try {
      echo.call(Echo::linger, 0);
      sync_result.set_value(ErrorKind::failed);
    } catch (const Error& e) {
      sync_result.set_value(e.kind());
    }
  });
  ASSERT_TRUE(planet_test::wait_until([&] { return client->pending_calls() == 3; }));
  std::this_thread::sleep_for(100ms);  // every start_call has returned

  const auto start = std::chrono::steady_clock::now();
  client.reset();
  EXPECT_LT(std::chrono::steady_clock::now() - start, 10s);
  blocking.join();
  EXPECT_EQ(sync_result.get_future().get(), ErrorKind::disconnected);
  ASSERT_EQ(future.wait_for(1s), std::future_status::ready);
  EXPECT_EQ(error_of(future), ErrorKind::disconnected);
  EXPECT_EQ(completions.seen(), 1);
  EXPECT_EQ(kind_of(completions.error), ErrorKind::disconnected);
}

TEST(IdempotentCall, OverAServerSideConnectionFailsAsBefore) {
  // The server calls back over the client's connection: when it is gone it is gone for good.
  std::promise<std::shared_ptr<Connection>> accepted;  // outlives the server's listener
  Communicator server;
  server.adapter().add("/echo", planet_test::make_echo_servant(server));
  const std::uint16_t port = server.listen("127.0.0.1", 0);
  server.connections().add_listener([&, done = false](const ConnectionEvent& e) mutable {
    if (!done && e.kind == LinkEventKind::connected) {
      done = true;
      accepted.set_value(e.connection);
    }
  });
  Communicator client;
  client.adapter().add("/echo", planet_test::make_echo_servant(client));
  auto peer = client.connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(20s));
  auto connection = accepted.get_future().get();
  Proxy back = Proxy(server, connection, "/echo").with_timeout(30s);
  EXPECT_EQ(back.call(Echo::linger, 0), 1);

  auto in_flight = back.async_call(Echo::linger, {500}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return server.pending_calls() == 1; }));
  peer->stop();
  ASSERT_EQ(in_flight.wait_for(10s), std::future_status::ready);
  EXPECT_EQ(error_of(in_flight), ErrorKind::disconnected);
  auto after = back.async_call(Echo::linger, {0}, asio::use_future);
  ASSERT_EQ(after.wait_for(5s), std::future_status::ready);
  EXPECT_EQ(error_of(after), ErrorKind::disconnected);
  EXPECT_EQ(server.pending_calls(), 0u);
}

}  // namespace
}  // namespace icars::planet
