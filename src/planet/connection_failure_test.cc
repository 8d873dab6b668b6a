// Failures of the link: a killed server, a frozen (silently dead) peer, a denied client.
// The client must notice, fail calls promptly, tell its listeners, and reconnect by itself.
#include <gtest/gtest.h>
#include <signal.h>

#include <asio/use_future.hpp>
#include <future>
#include <mutex>

#include "child_process.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "test_interfaces.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;
using planet_test::Echo;

struct EventLog {
  std::mutex mutex;
  std::vector<LinkEventKind> kinds;
  std::vector<std::string> reasons;
  void record(const ConnectionEvent& e) {
    std::lock_guard lock(mutex);
    kinds.push_back(e.kind);
    reasons.push_back(e.reason);
  }
  std::vector<LinkEventKind> snapshot() {
    std::lock_guard lock(mutex);
    return kinds;
  }
};

TEST(ConnectionFailure, ClientReconnectsAfterTheServerIsKilledAndRestarted) {
  auto server = planet_test::start_test_server();
  const std::uint16_t port = server.port;
  EventLog events;  // outlives the client: its io thread reports the last disconnect
  Communicator client;
  client.connections().add_listener([&](const ConnectionEvent& e) { events.record(e); });
  auto peer = client.connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy echo(client, peer, "/echo");
  EXPECT_EQ(echo.call(Echo::echo_int, 1), 1);

  // A call in flight when the server dies fails promptly with `disconnected`.
  auto in_flight = echo.with_timeout(60s).async_call(Echo::block_ms, {30000}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return client.pending_calls() == 1; }));
  server.process->signal(SIGKILL);
  server.process->wait();
  ASSERT_EQ(in_flight.wait_for(20s), std::future_status::ready);
  try {
    in_flight.get();
    FAIL() << "the in-flight call must fail";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::disconnected) << e.what();
  }

  // During the outage calls fail at once instead of waiting for their deadline.
  ASSERT_TRUE(planet_test::wait_until([&] { return !peer->is_connected(); }));
  for (int i = 0; i < 5; ++i) {
    const auto start = std::chrono::steady_clock::now();
    try {
      echo.call(Echo::echo_int, 2);
      FAIL() << "a call during the outage must fail";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::disconnected) << e.what();
    }
    EXPECT_LT(std::chrono::steady_clock::now() - start, 1s);
  }

  // Restart on the same port: the client reconnects by itself and calls succeed again.
  auto restarted = planet_test::start_test_server({"--port", std::to_string(port)});
  ASSERT_TRUE(planet_test::wait_until([&] { return peer->connect_count() == 2; }, 30s))
      << peer->last_error();
  EXPECT_EQ(echo.call(Echo::echo_int, 3), 3);
  ASSERT_TRUE(planet_test::wait_until([&] { return events.snapshot().size() >= 3; }));
  EXPECT_EQ(events.snapshot(),
            (std::vector<LinkEventKind>{LinkEventKind::connected, LinkEventKind::disconnected,
                                        LinkEventKind::reconnected}));
}

TEST(ConnectionFailure, FrozenPeerIsDetectedByHeartbeatTimeout) {
  auto server = planet_test::start_test_server(
      {"--heartbeat-ms", "100", "--heartbeat-timeout-ms", "600000"});
  CommunicatorOptions options;
  options.connection.heartbeat_interval = 100ms;
  options.connection.heartbeat_timeout = 600ms;
  EventLog events;  // outlives the client: its io thread reports the last disconnect
  Communicator client(options);
  client.connections().add_listener([&](const ConnectionEvent& e) { events.record(e); });
  auto peer = client.connect("127.0.0.1", server.port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy echo(client, peer, "/echo");
  auto in_flight = echo.with_timeout(600s).async_call(Echo::echo_int, {5}, asio::use_future);
  (void)in_flight.wait_for(20s);

  // SIGSTOP: the TCP connection stays up, but the peer says nothing any more.
  server.process->freeze();
  auto stuck = echo.with_timeout(600s).async_call(Echo::echo_int, {6}, asio::use_future);
  const auto start = std::chrono::steady_clock::now();
  ASSERT_TRUE(planet_test::wait_until([&] { return !peer->is_connected(); }, 30s));
  const auto detected_after = std::chrono::steady_clock::now() - start;
  EXPECT_NE(peer->last_error().find("heartbeat timeout"), std::string::npos) << peer->last_error();
  EXPECT_LT(detected_after, 10s);
  // The call waiting on the frozen peer fails with `disconnected`, long before its deadline.
  ASSERT_EQ(stuck.wait_for(10s), std::future_status::ready);
  EXPECT_THROW(stuck.get(), Error);
  // The peer fails its pending calls and marks itself down before it tells its listeners.
  ASSERT_TRUE(planet_test::wait_until([&] { return events.snapshot().size() >= 2; }, 30s));
  {
    std::lock_guard lock(events.mutex);
    ASSERT_GE(events.kinds.size(), 2u);
    EXPECT_EQ(events.kinds[1], LinkEventKind::disconnected);
    EXPECT_NE(events.reasons[1].find("heartbeat timeout"), std::string::npos);
  }
  // Once it thaws, the client reconnects.
  server.process->thaw();
  ASSERT_TRUE(planet_test::wait_until([&] { return peer->connect_count() >= 2; }, 30s))
      << peer->last_error();
  EXPECT_EQ(echo.call(Echo::echo_int, 7), 7);
}

TEST(ConnectionFailure, ServerCanDenyAClientWithAReason) {
  Communicator server;
  server.connections().set_acceptor([](const ConnectRequest& request) {
    Admission admission;
    if (request.pun == "intruder") admission.deny = "unknown device 'intruder'";
    return admission;
  });
  const auto port = server.listen("127.0.0.1", 0);

  CommunicatorOptions options;
  options.pun = "intruder";
  Communicator bad(options);
  auto denied = bad.connect("127.0.0.1", port);
  ASSERT_TRUE(planet_test::wait_until(
      [&] { return denied->last_error().find("unknown device 'intruder'") != std::string::npos; }))
      << denied->last_error();
  EXPECT_FALSE(denied->is_connected());
  denied->stop();

  CommunicatorOptions good_options;
  good_options.pun = "tv-manager";
  Communicator good(good_options);
  auto accepted = good.connect("127.0.0.1", port);
  EXPECT_TRUE(accepted->wait_connected(20s));
}

TEST(ConnectionFailure, ServerCallsTheClientBackOverTheClientsConnection) {
  // The server never connects out: it calls the client over the link the client opened,
  // as a mediating server calls a device manager behind NAT.
  Communicator server;
  std::promise<std::shared_ptr<Connection>> client_link;
  server.connections().add_listener([&](const ConnectionEvent& e) {
    if (e.kind == LinkEventKind::connected) client_link.set_value(e.connection);
  });
  const auto port = server.listen("127.0.0.1", 0);

  Communicator device;
  device.adapter().add("/tv", planet_test::make_echo_servant(device));
  auto peer = device.connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(20s));
  auto link = client_link.get_future().get();
  Proxy tv(server, link, "/tv");
  EXPECT_EQ(tv.call(Echo::echo_string, "channel 5"), "channel 5");

  // When the client goes away, the server's proxy fails with `disconnected`.
  peer->stop();
  ASSERT_TRUE(planet_test::wait_until([&] { return !link->is_open(); }));
  try {
    tv.call(Echo::ping);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::disconnected);
  }
}

}  // namespace
}  // namespace icars::planet

namespace icars::planet {
namespace {

TEST(ConnectionFailure, OverlongPunIsRejectedBeforeAnyConnection) {
  CommunicatorOptions options;
  options.pun = std::string(2000, 'x');
  try {
    Communicator c(options);
    FAIL() << "a PUN that cannot fit a CONNECT frame must be refused";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("PUN of 2000 bytes"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace icars::planet
