// Remote invocation against a server in another process: every type round-trips, errors arrive
// typed, AMI works with callbacks, futures and coroutines, and objects passed by reference can
// be called back over the caller's own connection.
#include <gtest/gtest.h>

#include <asio/co_spawn.hpp>
#include <asio/detached.hpp>
#include <asio/use_awaitable.hpp>
#include <asio/use_future.hpp>
#include <future>
#include <limits>
#include <signal.h>
#include <thread>

#include "child_process.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "call_race.h"
#include "test_interfaces.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;
using planet_test::Callback;
using planet_test::Color;
using planet_test::Echo;
using planet_test::Pose;
using planet_test::Reading;

class RmiCall : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { server_ = new planet_test::TestServer(planet_test::start_test_server()); }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
  }
  void SetUp() override {
    peer_ = client_.connect("127.0.0.1", server_->port);
    ASSERT_TRUE(peer_->wait_connected(20s)) << peer_->last_error();
  }

  static planet_test::TestServer* server_;
  Communicator client_;
  std::shared_ptr<Peer> peer_;
  Proxy echo() { return Proxy(client_, peer_, "/echo"); }
};
planet_test::TestServer* RmiCall::server_ = nullptr;

TEST_F(RmiCall, EveryTypeRoundTrips) {
  auto e = echo();
  e.call(Echo::ping);
  EXPECT_TRUE(e.call(Echo::echo_bool, true));
  EXPECT_EQ(e.call(Echo::echo_byte, std::uint8_t{200}), 200);
  EXPECT_EQ(e.call(Echo::echo_short, std::int16_t{-12345}), -12345);
  EXPECT_EQ(e.call(Echo::echo_int, std::numeric_limits<std::int32_t>::min()),
            std::numeric_limits<std::int32_t>::min());
  EXPECT_EQ(e.call(Echo::echo_long, std::numeric_limits<std::int64_t>::max()),
            std::numeric_limits<std::int64_t>::max());
  EXPECT_EQ(e.call(Echo::echo_float, 3.25f), 3.25f);
  EXPECT_EQ(e.call(Echo::echo_double, -1e300), -1e300);
  EXPECT_EQ(e.call(Echo::echo_string, std::string()), "");
  EXPECT_EQ(e.call(Echo::echo_string, std::string("grüße")), "grüße");
  EXPECT_EQ(e.call(Echo::echo_binary, Binary{}), Binary{});
  EXPECT_EQ(e.call(Echo::echo_stream, StreamRef{77}), StreamRef{77});
  EXPECT_EQ(e.call(Echo::echo_enum, Color::blue), Color::blue);
  EXPECT_EQ(e.call(Echo::echo_pose, Pose{1, 2, 3}), (Pose{1, 2, 3}));
  const Reading reading{"sonar", {Pose{1, 1, 0}, Pose{2, 2, 1}}, Color::green, 1234567890123};
  EXPECT_EQ(e.call(Echo::echo_reading, reading), reading);

  Event ev("SoundEvent");
  ev.set("direction", 45.0).set("level", std::int32_t{70}).set("who", std::string("tv"));
  ev.set("path", std::vector<Pose>{Pose{0, 0, 0}});
  const Event back = e.call(Echo::echo_event, ev);
  EXPECT_EQ(back, ev);
  EXPECT_EQ(back.get<std::int32_t>("level"), 70);

  const RemoteException ex("icars::home::Busy", "try later", Properties().set("retry_ms", std::int32_t{5}));
  const RemoteException exb = e.call(Echo::echo_exception, ex);
  EXPECT_EQ(exb.type_id(), "icars::home::Busy");
  EXPECT_EQ(exb.properties().get<std::int32_t>("retry_ms"), 5);

  const ObjectRef ref{"robot:1", "/robot/wheels", "nav::Wheels"};
  EXPECT_EQ(e.call(Echo::echo_remote, ref), ref);
}

TEST_F(RmiCall, SequencesOfEveryTypeIncludingNestedAndEmpty) {
  auto e = echo();
  EXPECT_EQ(e.call(Echo::echo_bools, {true, false, true}), (std::vector<bool>{true, false, true}));
  EXPECT_EQ(e.call(Echo::echo_bytes, {}), std::vector<std::uint8_t>{});
  EXPECT_EQ(e.call(Echo::echo_bytes, {1, 2, 255}), (std::vector<std::uint8_t>{1, 2, 255}));
  EXPECT_EQ(e.call(Echo::echo_shorts, {-1, 0, 1}), (std::vector<std::int16_t>{-1, 0, 1}));
  EXPECT_EQ(e.call(Echo::echo_ints, {1, 2, 3}), (std::vector<std::int32_t>{1, 2, 3}));
  EXPECT_EQ(e.call(Echo::echo_longs, {-5}), (std::vector<std::int64_t>{-5}));
  EXPECT_EQ(e.call(Echo::echo_floats, {0.5f}), (std::vector<float>{0.5f}));
  EXPECT_EQ(e.call(Echo::echo_doubles, {0.25, 1e-9}), (std::vector<double>{0.25, 1e-9}));
  EXPECT_EQ(e.call(Echo::echo_strings, {"", "a", "bc"}), (std::vector<std::string>{"", "a", "bc"}));
  const std::vector<Binary> bins{Binary{}, Binary{{std::byte{1}, std::byte{2}}}};
  EXPECT_EQ(e.call(Echo::echo_binaries, bins), bins);
  EXPECT_EQ(e.call(Echo::echo_enums, {Color::red, Color::blue}),
            (std::vector<Color>{Color::red, Color::blue}));
  EXPECT_EQ(e.call(Echo::echo_poses, {Pose{1, 2, 3}}), (std::vector<Pose>{Pose{1, 2, 3}}));
  const std::vector<Event> events{Event("A"), Event("B")};
  EXPECT_EQ(e.call(Echo::echo_events, events), events);
  const std::vector<ObjectRef> refs{ObjectRef{"", "/x", "T"}};
  EXPECT_EQ(e.call(Echo::echo_remotes, refs), refs);
  const std::vector<std::vector<std::vector<std::int32_t>>> nested{{{1, 2}, {}}, {}, {{3}}};
  EXPECT_EQ(e.call(Echo::echo_nested, nested), nested);
  EXPECT_EQ(e.call(Echo::mix, 1, "abc", 2.0), 6);
}

TEST_F(RmiCall, HugeValuesRoundTrip) {
  auto e = echo().with_timeout(60s);
  Binary big;
  big.bytes.resize(20u << 20);
  for (std::size_t i = 0; i < big.bytes.size(); ++i) big.bytes[i] = std::byte(i * 31);
  EXPECT_EQ(e.call(Echo::echo_binary, big), big);
  std::vector<std::string> strings(200000, "planet");
  EXPECT_EQ(e.call(Echo::echo_strings, strings), strings);
  EXPECT_EQ(e.call(Echo::echo_string, std::string(3u << 20, 'x')).size(), 3u << 20);
}

TEST_F(RmiCall, RemoteExceptionArrivesTypedWithServersMessage) {
  try {
    echo().call(Echo::refuse, "the door is locked");
    FAIL() << "expected RemoteException";
  } catch (const RemoteException& e) {
    EXPECT_EQ(e.type_id(), "test::Refused");
    EXPECT_EQ(e.remote_message(), "the door is locked");
    EXPECT_EQ(e.properties().get<std::int32_t>("code"), 42);
    EXPECT_EQ(e.kind(), ErrorKind::failed);
  }
  try {
    echo().call(Echo::crash);
    FAIL();
  } catch (const RemoteException& e) {
    EXPECT_EQ(e.type_id(), "std::exception");
    EXPECT_EQ(e.remote_message(), "servant crashed on purpose");
  }
}

TEST_F(RmiCall, UnknownObjectAndMethodGetClearErrorsAndTheLinkStaysUp) {
  const Operation<void()> missing{"no_such_method"};
  try {
    Proxy(client_, peer_, "/nobody").call(Echo::ping);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::unimplemented);
    EXPECT_NE(std::string(e.what()).find("no servant at path '/nobody'"), std::string::npos)
        << e.what();
  }
  try {
    echo().call(missing);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::unimplemented);
    EXPECT_NE(std::string(e.what()).find("no method 'no_such_method'"), std::string::npos)
        << e.what();
  }
  // Same name, wrong parameter types: a bad_data error naming the argument.
  const Operation<std::int32_t(std::string)> wrong{"echo_int"};
  try {
    echo().call(wrong, "seven");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_data);
    EXPECT_NE(std::string(e.what()).find("argument 1 of 'echo_int': expected int, got string"),
              std::string::npos)
        << e.what();
  }
  EXPECT_EQ(echo().call(Echo::echo_int, 5), 5);
  EXPECT_EQ(peer_->connect_count(), 1u);
}

TEST_F(RmiCall, AsyncWithCallbackFutureAndCoroutine) {
  std::promise<std::int32_t> via_callback;
  echo().async_call(Echo::echo_int, {11}, [&](std::exception_ptr e, std::int32_t v) {
    if (e) {
      via_callback.set_exception(e);
    } else {
      via_callback.set_value(v);
    }
  });
  EXPECT_EQ(via_callback.get_future().get(), 11);

  std::future<std::string> f = echo().async_call(Echo::echo_string, {"future"}, asio::use_future);
  EXPECT_EQ(f.get(), "future");

  std::future<void> refused = echo().async_call(Echo::refuse, {"no"}, asio::use_future);
  EXPECT_THROW(refused.get(), RemoteException);

  std::promise<std::int32_t> via_coroutine;
  auto proxy = echo();
  asio::co_spawn(
      client_.io(),
      [&]() -> asio::awaitable<void> {
        const std::int32_t a = co_await proxy.async_call(Echo::echo_int, {20}, asio::use_awaitable);
        const std::int32_t b = co_await proxy.async_call(Echo::echo_int, {22}, asio::use_awaitable);
        via_coroutine.set_value(a + b);
      },
      asio::detached);
  EXPECT_EQ(via_coroutine.get_future().get(), 42);
}

TEST_F(RmiCall, ManyConcurrentAsyncCallsAllComplete) {
  constexpr int kCalls = 2000;
  std::atomic<int> ok{0};
  std::atomic<int> done{0};
  for (int i = 0; i < kCalls; ++i) {
    echo().async_call(Echo::echo_int, {i}, [&, i](std::exception_ptr e, std::int32_t v) {
      if (!e && v == i) ++ok;
      ++done;
    });
  }
  ASSERT_TRUE(planet_test::wait_until([&] { return done.load() == kCalls; }));
  EXPECT_EQ(ok.load(), kCalls);
  EXPECT_EQ(client_.pending_calls(), 0u);
}

ConnectionStats stats_of(const Peer& peer) {
  auto c = peer.connection();
  return c ? c->stats() : ConnectionStats{};
}

// A synchronous caller reads its own reply when nothing else is arriving: the reply does not
// pass through the io thread.
TEST_F(RmiCall, ACallerReadsItsOwnReplyOnAnIdleConnection) {
  const auto before = stats_of(*peer_);
  for (int i = 0; i < 200; ++i) ASSERT_EQ(echo().call(Echo::echo_int, i), i);
  const auto after = stats_of(*peer_);
  // Most, on an idle machine; a caller finding the io thread at the socket (a heartbeat, or
  // the io thread re-arming its wait as the call starts) leaves the reply to it, so how many is
  // a matter of scheduling (measured in bench/compare, not here): a tenth at least.
  EXPECT_GE(after.messages_read_by_callers - before.messages_read_by_callers, 20u);
  EXPECT_EQ(after.messages_received - before.messages_received, 200u);
}

// Callers reading their own replies race the io thread reading everything else on the same
// connection (other callers' replies, async replies, the server's calls to this client): every
// message is handled once, in its place, by the right party.
TEST_F(RmiCall, RepliesReadByCallersAndByTheIoThreadRaceWithoutLossOrMixUp) {
  auto callback = std::make_shared<Servant>(std::string(Callback::type_id));
  std::atomic<int> callbacks{0};
  callback->implement(Callback::notify_me, [&](const std::string& text) {
    ++callbacks;
    return "heard " + text;
  });
  client_.adapter().add("/me/racer", callback);
  const auto me = client_.reference<Callback>("/me/racer");
  const auto before = stats_of(*peer_);

  constexpr int kThreads = 4;
  constexpr int kCalls = 400;
  const auto race = planet_test::race_calls(client_, peer_, me, kThreads, kCalls, false);
  ASSERT_TRUE(race.async_all_done);
  EXPECT_EQ(race.wrong, 0);
  EXPECT_EQ(race.async_ok, kCalls);
  EXPECT_EQ(callbacks.load(), kCalls / 20);
  EXPECT_EQ(client_.pending_calls(), 0u);
  const auto after = stats_of(*peer_);
  const auto by_callers = after.messages_read_by_callers - before.messages_read_by_callers;
  const auto received = after.messages_received - before.messages_received;
  // Both paths ran: callers read some replies, the io thread the rest (and every callback).
  EXPECT_GT(by_callers, 0u);
  EXPECT_GT(received, by_callers);
  EXPECT_EQ(received, static_cast<std::uint64_t>(kThreads * kCalls + kCalls + kCalls / 20));
  client_.adapter().remove("/me/racer");
}

// A caller reading its own reply learns at once that its server died: the end of the stream
// wakes it, and the io thread fails the call, long before its reply or deadline would come.
TEST(RmiCallDirectRead, AServerThatDiesWhileTheCallerWaitsFailsTheCallAtOnce) {
  auto server = planet_test::start_test_server();
  Communicator client;
  auto peer = client.connect("127.0.0.1", server.port);
  ASSERT_TRUE(peer->wait_connected(20s)) << peer->last_error();
  Proxy echo = Proxy(client, peer, "/echo").with_timeout(60s);
  ASSERT_EQ(echo.call(Echo::echo_int, 1), 1);
  std::thread killer([&] {
    // Once the call below is waiting at the server (it answers after 20 s).
    planet_test::wait_until([&] { return echo.call(Echo::lingers_started) > 0; }, 20s);
    server.process->signal(SIGKILL);
  });
  const auto start = std::chrono::steady_clock::now();
  try {
    echo.call(Echo::linger_once, 20000);
    ADD_FAILURE() << "the call returned although its server was killed";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::disconnected) << e.what();
  }
  killer.join();
  EXPECT_LT(std::chrono::steady_clock::now() - start, 15s) << "the call waited for its deadline";
}

TEST_F(RmiCall, OneWayNotificationsArriveInOrderOfSending) {
  const auto before = echo().call(Echo::counted);
  for (int i = 0; i < 1000; ++i) echo().notify(Echo::count, 1);
  // A call sent after the notifications on the same connection is answered after them.
  EXPECT_EQ(echo().call(Echo::counted), before + 1000);
}

TEST_F(RmiCall, SlowServantTimesOutWithATimeoutError) {
  const auto start = std::chrono::steady_clock::now();
  try {
    echo().with_timeout(200ms).call(Echo::block_ms, 1500);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::timeout) << e.what();
  }
  EXPECT_LT(std::chrono::steady_clock::now() - start, 1400ms);
  // The late reply is dropped quietly and the link still works.
  EXPECT_EQ(echo().with_timeout(10s).call(Echo::echo_int, 3), 3);
}

// A relay (Servant::forward_others + Proxy::async_call_raw): calls, results of any size, typed
// exceptions, unknown methods and notifications pass through a third endpoint undecoded.
Servant::AsyncResult forward_to(Proxy target, ForwardedCall call) {
  if (call.oneway) {
    target.notify_raw(call.method, call.args);
    co_return std::vector<std::byte>{};
  }
  co_return co_await target.async_call_raw(call.method, std::move(call.args), CallMode::at_most_once,
                                           asio::use_awaitable);
}

TEST_F(RmiCall, ARelayForwardsCallsNotificationsAndErrorsUndecoded) {
  Communicator relay;
  const auto relay_port = relay.listen("127.0.0.1", 0);
  auto to_server = relay.connect("127.0.0.1", server_->port);
  ASSERT_TRUE(to_server->wait_connected(20s)) << to_server->last_error();
  auto forwarder = std::make_shared<Servant>(std::string(Echo::type_id));
  forwarder->forward_others([&relay, to_server](ForwardedCall call) {
    return forward_to(Proxy(relay, to_server, "/echo"), std::move(call));
  });
  relay.adapter().add("/echo", forwarder);
  auto via = client_.connect("127.0.0.1", relay_port);
  ASSERT_TRUE(via->wait_connected(20s)) << via->last_error();
  Proxy relayed(client_, via, "/echo");

  EXPECT_EQ(relayed.call(Echo::echo_int, -7), -7);
  std::vector<std::string> strings(50000, "relay");
  EXPECT_EQ(relayed.call(Echo::echo_strings, strings), strings);
  try {
    relayed.call(Echo::refuse, "not through here");
    FAIL() << "expected RemoteException";
  } catch (const RemoteException& e) {
    EXPECT_EQ(e.type_id(), "test::Refused");
    EXPECT_EQ(e.remote_message(), "not through here");
    EXPECT_EQ(e.properties().get<std::int32_t>("code"), 42);
  }
  const Operation<void()> missing{"no_such_method"};
  try {
    relayed.call(missing);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::unimplemented);
    EXPECT_NE(std::string(e.what()).find("no method 'no_such_method'"), std::string::npos) << e.what();
  }
  const auto before = relayed.call(Echo::counted);
  for (int i = 0; i < 100; ++i) relayed.notify(Echo::count, 1);
  EXPECT_TRUE(planet_test::wait_until([&] { return relayed.call(Echo::counted) == before + 100; }, 20s));
  relay.adapter().remove("/echo");
}

TEST_F(RmiCall, ServerCallsBackAnObjectPassedByReference) {
  auto callback = std::make_shared<Servant>(std::string(Callback::type_id));
  std::atomic<int> calls{0};
  callback->implement(Callback::notify_me, [&](const std::string& text) {
    ++calls;
    return "client heard: " + text;
  });
  client_.adapter().add("/me/callback", callback);
  const auto me = client_.reference<Callback>("/me/callback");
  EXPECT_EQ(echo().call(Echo::call_back, me, "hello"), "client heard: hello");
  EXPECT_EQ(calls.load(), 1);
  // A reference that names this client by its PUN resolves to the same connection.
  const auto named = Ref<Callback>(ObjectRef{echo().call(Echo::caller_pun), "/me/callback",
                                             std::string(Callback::type_id)});
  EXPECT_EQ(echo().call(Echo::call_back, named, "again"), "client heard: again");
  EXPECT_EQ(calls.load(), 2);
  client_.adapter().remove("/me/callback");
}

TEST_F(RmiCall, ReferencesToUnknownEndpointsOrOfTheWrongTypeAreRefusedClearly) {
  const auto elsewhere = Ref<Callback>(
      ObjectRef{"no-such-endpoint", "/x", std::string(Callback::type_id)});
  try {
    echo().call(Echo::call_back, elsewhere, "hi");
    FAIL() << "a reference to an unknown endpoint was used";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no-such-endpoint"), std::string::npos) << e.what();
  }
  // A reference to an object of another interface fails to decode at the servant.
  const auto wrong = Ref<Callback>(ObjectRef{"", "/echo", "test::Echo"});
  try {
    echo().call(Echo::call_back, wrong, "hi");
    FAIL() << "a reference of the wrong type was accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_data) << e.what();
    EXPECT_NE(std::string(e.what()).find("expected a reference to test::Callback"),
              std::string::npos)
        << e.what();
  }
  EXPECT_EQ(echo().call(Echo::echo_int, 5), 5);
}

TEST_F(RmiCall, SynchronousCallOnTheIoThreadIsRefusedInsteadOfDeadlocking) {
  std::promise<std::string> outcome;
  auto proxy = echo();
  asio::post(client_.io(), [&] {
    try {
      proxy.call(Echo::ping);
      outcome.set_value("returned");
    } catch (const Error& e) {
      outcome.set_value(e.what());
    }
  });
  EXPECT_NE(outcome.get_future().get().find("would deadlock"), std::string::npos);
}

TEST_F(RmiCall, ServerSeesTheClientsPun) {
  CommunicatorOptions options;
  options.pun = "kitchen-robot";
  Communicator named(options);
  auto peer = named.connect("127.0.0.1", server_->port);
  ASSERT_TRUE(peer->wait_connected(20s));
  EXPECT_EQ(Proxy(named, peer, "/echo").call(Echo::caller_pun), "kitchen-robot");
  EXPECT_NE(peer->connection()->peer_pun(), "");
}

}  // namespace
}  // namespace icars::planet
