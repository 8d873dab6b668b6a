// PLANET in lock-step (ConnectionOptions::activity): a call between two endpoints of one process
// that share an activity is work from the moment it is sent until its completion handler has
// run, through the reply and the bulk thread of large messages; a connection to an endpoint
// that does not share it counts nothing. Real sockets on loopback.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <thread>
#include <vector>

#include "icars/clock/activity.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "test_interfaces.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;
using planet_test::Echo;

CommunicatorOptions sharing(std::shared_ptr<Activity> activity, const char* name) {
  CommunicatorOptions o;
  o.name = name;
  o.connection.activity = std::move(activity);
  return o;
}

struct Pair {
  explicit Pair(std::shared_ptr<Activity> server_activity, std::shared_ptr<Activity> client_activity)
      : server(sharing(std::move(server_activity), "server")), client(sharing(std::move(client_activity), "client")) {
    server.adapter().add("/echo", planet_test::make_echo_servant(server));
    const auto port = server.listen("127.0.0.1", 0);
    peer = client.connect("127.0.0.1", port);
  }
  Communicator server;
  Communicator client;
  std::shared_ptr<Peer> peer;
};

TEST(PlanetLockStep, SettleWaitsForEveryCallsCompletionHandler) {
  const auto activity = Activity::create();
  Pair p(activity, activity);
  ASSERT_TRUE(p.peer->wait_connected(20s)) << p.peer->last_error();
  ASSERT_TRUE(activity->settle(30s));
  Proxy echo(p.client, p.peer, "/echo");
  std::atomic<int> completed{0};
  constexpr int kCalls = 50;
  for (int i = 0; i < kCalls; ++i) {
    echo.async_call(Echo::echo_int, {i}, [&](std::exception_ptr e, std::int32_t) {
      std::this_thread::sleep_for(1ms);  // a handler that takes a while: settle must wait for it
      if (!e) ++completed;
    });
  }
  ASSERT_TRUE(activity->settle(60s));
  EXPECT_EQ(completed.load(), kCalls) << "settled before every reply had been handled";
  EXPECT_EQ(activity->busy(), 0u);
}

TEST(PlanetLockStep, ALargeMessageHandledOnTheBulkThreadIsWaitedFor) {
  const auto activity = Activity::create();
  Pair p(activity, activity);
  ASSERT_TRUE(p.peer->wait_connected(20s)) << p.peer->last_error();
  Proxy echo(p.client, p.peer, "/echo");
  std::atomic<bool> done{false};
  std::vector<std::int32_t> big(600'000, 7);  // 2.4 MB: more than one reassembly block each way
  echo.async_call(Echo::echo_ints, {big}, [&](std::exception_ptr e, std::vector<std::int32_t> back) {
    done = !e && back.size() == 600'000;
  });
  ASSERT_TRUE(activity->settle(60s));
  EXPECT_TRUE(done.load());
}

TEST(PlanetLockStep, AnEndpointThatDoesNotShareTheActivityCountsNothing) {
  const auto server_activity = Activity::create();
  const auto client_activity = Activity::create();
  Pair p(server_activity, client_activity);
  ASSERT_TRUE(p.peer->wait_connected(20s)) << p.peer->last_error();
  Proxy echo(p.client, p.peer, "/echo");
  for (int i = 0; i < 10; ++i) EXPECT_EQ(echo.call(Echo::echo_int, i), i);
  // Neither side's messages were counted: the other end is not part of its activity.
  EXPECT_TRUE(server_activity->settle(10s));
  EXPECT_EQ(server_activity->busy(), 0u);
  EXPECT_EQ(server_activity->generation(), 0u);
  EXPECT_TRUE(client_activity->settle(10s));
  EXPECT_EQ(client_activity->busy(), 0u);
}

TEST(PlanetLockStep, ALinkThatClosesReleasesWhatWasInFlight) {
  const auto activity = Activity::create();
  auto p = std::make_unique<Pair>(activity, activity);
  ASSERT_TRUE(p->peer->wait_connected(20s)) << p->peer->last_error();
  Proxy echo(p->client, p->peer, "/echo");
  std::atomic<int> finished{0};
  for (int i = 0; i < 20; ++i) {
    echo.async_call(Echo::echo_int, {i}, [&](std::exception_ptr, std::int32_t) { ++finished; });
  }
  // Whatever was on its way is dropped: it must not hold the activity for ever.
  if (auto c = p->peer->connection()) c->close("cut by the test");
  ASSERT_TRUE(activity->settle(60s));
  EXPECT_EQ(finished.load(), 20) << "every call ended, answered or failed";
  p.reset();
  EXPECT_EQ(activity->busy(), 0u);
}

}  // namespace
}  // namespace icars::planet
