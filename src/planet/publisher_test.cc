// Publish/subscribe: listeners passed by reference receive every published event as a typed
// NOTIFY; unsubscribed and disconnected listeners stop receiving; and a stopped subscriber among
// 50 subscriber processes does not slow the other 49, which receive every event in order; a
// listener whose link dropped gets the events published meanwhile when it subscribes again (the
// same listener only, bounded, once), also when the publisher's own process was stopped.
#include <gtest/gtest.h>

#include <signal.h>

#include <numeric>
#include <thread>

#include "child_process.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "icars/planet/publisher.h"
#include "test_interfaces.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;
using planet_test::Tick;
using planet_test::TickListener;
using planet_test::TickSource;

// Serves TickSource at /ticks on `communicator`, adding subscribers to `publisher`.
void serve_ticks(Communicator& communicator, Publisher<Tick>& publisher) {
  auto source = std::make_shared<Servant>(std::string(TickSource::type_id));
  source->implement(TickSource::subscribe,
                    [&communicator, &publisher](Ref<TickListener> listener, const Current& c) {
                      publisher.subscribe(Proxy(communicator, c.connection, listener.object()));
                    });
  communicator.adapter().add("/ticks", source);
}

Tick tick(std::int64_t seq, std::size_t payload_bytes = 0) {
  return Tick{seq, Binary{std::vector<std::byte>(payload_bytes, std::byte{0x5A})}};
}

TEST(Publisher, EveryListenerReceivesEveryEventTypedAndInOrder) {
  Communicator publisher_side;
  Publisher<Tick> ticks(TickListener::on_tick);
  serve_ticks(publisher_side, ticks);
  const auto port = publisher_side.listen("127.0.0.1", 0);

  Communicator subscriber_side;
  std::mutex mutex;
  std::vector<std::int64_t> seen_a;
  std::vector<std::int64_t> seen_b;
  for (auto* seen : {&seen_a, &seen_b}) {
    auto listener = std::make_shared<Servant>(std::string(TickListener::type_id));
    listener->implement(TickListener::on_tick, [&mutex, seen](const Tick& t) {
      std::lock_guard lock(mutex);
      seen->push_back(t.seq);
    });
    subscriber_side.adapter().add(seen == &seen_a ? "/a" : "/b", listener);
  }
  auto peer = subscriber_side.connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy source(subscriber_side, peer, "/ticks");
  source.call(TickSource::subscribe, subscriber_side.reference<TickListener>("/a"));
  source.call(TickSource::subscribe, subscriber_side.reference<TickListener>("/b"));
  ASSERT_EQ(ticks.size(), 2u);

  for (std::int64_t i = 0; i < 100; ++i) EXPECT_EQ(ticks.publish(tick(i, 100)), 2u);
  ASSERT_TRUE(planet_test::wait_until([&] {
    std::lock_guard lock(mutex);
    return seen_a.size() == 100 && seen_b.size() == 100;
  }));
  std::vector<std::int64_t> expected(100);
  std::iota(expected.begin(), expected.end(), 0);
  EXPECT_EQ(seen_a, expected);
  EXPECT_EQ(seen_b, expected);
  for (const auto& s : ticks.subscribers()) {
    EXPECT_EQ(s.delivered, 100u);
    EXPECT_EQ(s.dropped, 0u);
  }
}

TEST(Publisher, SubscribersBeyondMaxSubscribersAreRefusedAndTheOthersKeepTheirEvents) {
  Communicator publisher_side;
  PublisherOptions options;
  options.max_subscribers = 2;
  Publisher<Tick> ticks(TickListener::on_tick, options);
  serve_ticks(publisher_side, ticks);
  const auto port = publisher_side.listen("127.0.0.1", 0);

  Communicator subscriber_side;
  std::atomic<int> received{0};
  for (const char* path : {"/a", "/b", "/c"}) {
    auto listener = std::make_shared<Servant>(std::string(TickListener::type_id));
    listener->implement(TickListener::on_tick, [&received](const Tick&) { ++received; });
    subscriber_side.adapter().add(path, listener);
  }
  auto peer = subscriber_side.connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy source(subscriber_side, peer, "/ticks");
  source.call(TickSource::subscribe, subscriber_side.reference<TickListener>("/a"));
  source.call(TickSource::subscribe, subscriber_side.reference<TickListener>("/b"));
  try {
    source.call(TickSource::subscribe, subscriber_side.reference<TickListener>("/c"));
    FAIL() << "a third subscriber must be refused";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::overloaded) << e.what();
    EXPECT_NE(std::string(e.what()).find("max_subscribers"), std::string::npos) << e.what();
  }
  EXPECT_EQ(ticks.size(), 2u);
  EXPECT_EQ(ticks.publish(tick(1)), 2u);
  EXPECT_TRUE(planet_test::wait_until([&] { return received.load() == 2; }));
}

TEST(Publisher, UnsubscribedAndDisconnectedListenersAreDropped) {
  Communicator publisher_side;
  Publisher<Tick> ticks(TickListener::on_tick);
  serve_ticks(publisher_side, ticks);
  const auto port = publisher_side.listen("127.0.0.1", 0);

  std::atomic<int> received{0};
  auto subscriber_side = std::make_unique<Communicator>();
  auto listener = std::make_shared<Servant>(std::string(TickListener::type_id));
  listener->implement(TickListener::on_tick, [&](const Tick&) { ++received; });
  subscriber_side->adapter().add("/l", listener);
  auto peer = subscriber_side->connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy source(*subscriber_side, peer, "/ticks");
  source.call(TickSource::subscribe, subscriber_side->reference<TickListener>("/l"));
  source.call(TickSource::subscribe, subscriber_side->reference<TickListener>("/l"));
  ASSERT_EQ(ticks.size(), 2u);
  EXPECT_TRUE(ticks.unsubscribe(ticks.subscribers().front().id));
  EXPECT_EQ(ticks.publish(tick(0)), 1u);
  ASSERT_TRUE(planet_test::wait_until([&] { return received.load() == 1; }));

  subscriber_side.reset();  // the subscriber's process goes away
  ASSERT_TRUE(planet_test::wait_until([&] {
    ticks.publish(tick(1));
    return ticks.size() == 0;
  }));
  EXPECT_EQ(ticks.removed(), 1u);
}

TEST(Publisher, AStoppedSubscriberDoesNotSlowFortyNineOthers) {
  constexpr int kSubscribers = 50;
  constexpr std::int64_t kEvents = 1500;
  constexpr std::size_t kPayload = 8u << 10;
  constexpr auto kPeriod = 5ms;  // 200 events per second to each subscriber

  CommunicatorOptions options;
  options.name = "publisher";
  // The stopped subscriber must be handled by the publisher's policy, not by heartbeats.
  options.connection.heartbeat_timeout = 120s;
  Communicator communicator(options);
  PublisherOptions policy;
  policy.max_backlog_bytes = 2u << 20;
  policy.stall_timeout = 1s;
  Publisher<Tick> ticks(TickListener::on_tick, policy);
  serve_ticks(communicator, ticks);
  const auto port = communicator.listen("127.0.0.1", 0);

  std::vector<std::unique_ptr<planet_test::ChildProcess>> children;
  for (int i = 0; i < kSubscribers; ++i) {
    children.push_back(std::make_unique<planet_test::ChildProcess>(std::vector<std::string>{
        planet_test::event_subscriber_path(), "--port", std::to_string(port)}));
  }
  for (auto& child : children) {
    ASSERT_EQ(child->read_line(120s).value_or("EOF"), "SUBSCRIBED");
  }
  ASSERT_EQ(ticks.size(), static_cast<std::size_t>(kSubscribers));
  // Subscription order is not child order; find the stopped child's subscription by its
  // connection once the publisher has seen the stop (its backlog grows, then it is dropped).
  children[0]->freeze();

  const auto start = std::chrono::steady_clock::now();
  auto slowest_publish = std::chrono::steady_clock::duration::zero();
  std::uint64_t most_dropped_seen = 0;
  for (std::int64_t i = 0; i < kEvents; ++i) {
    std::this_thread::sleep_until(start + i * kPeriod);
    const auto before = std::chrono::steady_clock::now();
    ticks.publish(tick(i, kPayload));
    slowest_publish = std::max(slowest_publish, std::chrono::steady_clock::now() - before);
    if (i % 50 == 0) {
      for (const auto& s : ticks.subscribers()) most_dropped_seen = std::max(most_dropped_seen, s.dropped);
    }
  }
  const auto elapsed = std::chrono::steady_clock::now() - start;
  const auto subscribers = ticks.subscribers();  // before they exit on the end mark
  ticks.publish(tick(-1));

  int complete = 0;
  for (int i = 1; i < kSubscribers; ++i) {
    const auto line = children[static_cast<std::size_t>(i)]->read_line(120s).value_or("EOF");
    EXPECT_EQ(line, "DONE " + std::to_string(kEvents) + " 1") << "subscriber " << i;
    complete += line == "DONE " + std::to_string(kEvents) + " 1";
  }
  std::uint64_t healthy_drops = 0;
  for (const auto& s : subscribers) healthy_drops += s.dropped;
  const double seconds = std::chrono::duration<double>(elapsed).count();
  std::cout << complete << " of " << kSubscribers - 1 << " running subscribers got all " << kEvents
            << " events at " << static_cast<double>(kEvents) / seconds << " events/s (target "
            << 1000 / kPeriod.count() << "); slowest publish() "
            << std::chrono::duration<double, std::milli>(slowest_publish).count()
            << " ms; stopped subscriber dropped " << most_dropped_seen
            << " events before removal; subscribers left " << subscribers.size() << "\n";

  EXPECT_EQ(complete, kSubscribers - 1);
  // The stopped subscriber was over its backlog, had events dropped, and was unsubscribed.
  EXPECT_GT(most_dropped_seen, 0u);
  EXPECT_EQ(ticks.removed(), 1u);
  EXPECT_EQ(subscribers.size(), static_cast<std::size_t>(kSubscribers - 1));
  EXPECT_EQ(healthy_drops, 0u);
  // publish() never waits for a subscriber (a generous bound: it takes microseconds).
  EXPECT_LT(slowest_publish, 2s);
  children[0]->thaw();
}

// A subscriber process hosting /l, named `pun`, recording the Ticks it receives.
struct TickSubscriber {
  explicit TickSubscriber(const std::string& pun, std::chrono::milliseconds heartbeat_timeout = 5s) {
    CommunicatorOptions options;
    options.pun = pun;
    options.name = pun;
    options.connection.heartbeat_interval = std::min<std::chrono::milliseconds>(1000ms, heartbeat_timeout / 4);
    options.connection.heartbeat_timeout = heartbeat_timeout;
    communicator = std::make_unique<Communicator>(options);
    auto listener = std::make_shared<Servant>(std::string(TickListener::type_id));
    listener->implement(TickListener::on_tick, [this](const Tick& t) {
      std::lock_guard lock(mutex);
      seen.push_back(t.seq);
    });
    communicator->adapter().add("/l", listener);
  }
  std::shared_ptr<Peer> subscribe(std::uint16_t port) {
    auto peer = communicator->connect("127.0.0.1", port);
    EXPECT_TRUE(peer->wait_connected(20s));
    subscribe_over(peer);
    return peer;
  }
  void subscribe_over(const std::shared_ptr<Peer>& peer) {
    Proxy source(*communicator, peer, "/ticks");
    source.call(TickSource::subscribe, communicator->reference<TickListener>("/l"));
  }
  std::vector<std::int64_t> received() {
    std::lock_guard lock(mutex);
    return seen;
  }
  std::mutex mutex;
  std::vector<std::int64_t> seen;
  std::unique_ptr<Communicator> communicator;
};

std::vector<std::int64_t> range(std::int64_t from, std::int64_t to) {
  std::vector<std::int64_t> out;
  for (std::int64_t i = from; i < to; ++i) out.push_back(i);
  return out;
}

TEST(Publisher, AListenerBackAfterItsLinkDroppedGetsTheEventsPublishedMeanwhileInOrder) {
  Communicator publisher_side;
  Publisher<Tick> ticks(TickListener::on_tick);
  serve_ticks(publisher_side, ticks);
  const auto port = publisher_side.listen("127.0.0.1", 0);

  auto first = std::make_unique<TickSubscriber>("mediator");
  first->subscribe(port);
  auto other = std::make_unique<TickSubscriber>("someone-else");
  other->subscribe(port);
  for (int i = 0; i < 3; ++i) ticks.publish(tick(i));
  ASSERT_TRUE(planet_test::wait_until([&] { return first->received().size() == 3; }));

  first.reset();  // the listener's link is gone (its process restarts, or its link broke)
  ASSERT_TRUE(planet_test::wait_until([&] { return ticks.size() == 1; }));
  for (int i = 3; i < 8; ++i) ticks.publish(tick(i));
  ASSERT_EQ(ticks.lapsed().size(), 1u);
  EXPECT_EQ(ticks.lapsed().front().held, 5u);

  // Someone else with a listener at the same path gets nothing of what was held.
  TickSubscriber stranger("stranger");
  stranger.subscribe(port);
  // The same listener (same PUN and path) back: the held events first, then the new ones.
  TickSubscriber back("mediator");
  back.subscribe(port);
  ticks.publish(tick(8));
  ASSERT_TRUE(planet_test::wait_until([&] { return back.received().size() == 6; }));
  ASSERT_TRUE(planet_test::wait_until([&] { return stranger.received().size() == 1; }));
  EXPECT_EQ(back.received(), range(3, 9));
  EXPECT_EQ(stranger.received(), range(8, 9));
  ASSERT_TRUE(planet_test::wait_until([&] { return other->received().size() == 9; }));
  EXPECT_EQ(other->received(), range(0, 9));
  EXPECT_TRUE(ticks.lapsed().empty());
  std::uint64_t replayed = 0;
  for (const auto& s : ticks.subscribers()) replayed += s.replayed;
  EXPECT_EQ(replayed, 5u);
}

TEST(Publisher, HeldEventsAreBoundedAndCanBeTurnedOff) {
  for (const bool off : {false, true}) {
    SCOPED_TRACE(off ? "hold_for 0" : "max_held 4");
    Communicator publisher_side;
    PublisherOptions options;
    options.max_held = 4;
    if (off) options.hold_for = 0ms;
    Publisher<Tick> ticks(TickListener::on_tick, options);
    serve_ticks(publisher_side, ticks);
    const auto port = publisher_side.listen("127.0.0.1", 0);
    auto first = std::make_unique<TickSubscriber>("mediator");
    first->subscribe(port);
    first.reset();
    ASSERT_TRUE(planet_test::wait_until([&] { return ticks.size() == 0; }));
    for (int i = 0; i < 10; ++i) ticks.publish(tick(i));
    TickSubscriber back("mediator");
    back.subscribe(port);
    ticks.publish(tick(10));
    const auto expected = off ? range(10, 11) : range(6, 11);  // the newest four and the new one
    ASSERT_TRUE(planet_test::wait_until([&] { return back.received().size() == expected.size(); }));
    EXPECT_EQ(back.received(), expected);
    ASSERT_EQ(ticks.subscribers().size(), 1u);
    if (!off) {
      EXPECT_EQ(ticks.subscribers().front().dropped, 6u) << "the oldest held events go";
    }
    EXPECT_TRUE(ticks.lapsed().empty());
  }
}

// A burst of events of very different sizes (one frame, several interleavable frames, several
// MiB handled on the receiver's bulk thread) arrives in publish order.
TEST(Publisher, EventsOfMixedSizesArriveInPublishOrder) {
  CommunicatorOptions options;
  options.connection.send_queue_limit = 64u << 20;
  Communicator publisher_side(options);
  PublisherOptions policy;
  policy.max_backlog_bytes = 64u << 20;  // the whole burst is queued: none is dropped
  Publisher<Tick> ticks(TickListener::on_tick, policy);
  serve_ticks(publisher_side, ticks);
  const auto port = publisher_side.listen("127.0.0.1", 0);
  TickSubscriber listener("listener");
  listener.subscribe(port);
  constexpr std::int64_t kEvents = 120;
  for (std::int64_t i = 0; i < kEvents; ++i) {
    const std::size_t size = i % 40 == 7 ? (2u << 20) : i % 3 == 0 ? 40000 : i % 3 == 1 ? 10 : 20000;
    ticks.publish(tick(i, size));
  }
  ASSERT_TRUE(planet_test::wait_until([&] { return listener.received().size() == kEvents; }, 60s))
      << listener.received().size() << " received, dropped " << ticks.subscribers().front().dropped;
  EXPECT_EQ(listener.received(), range(0, kEvents));
}

// The publisher's process is stopped (SIGSTOP) longer than the heartbeat timeout: the listener's
// side drops the link and reconnects. The ticks the publisher sends when it runs again, before
// it has read that its link is gone, are held, and delivered once the listener subscribes
// again: the listener sees every tick from its first to its last, none twice.
TEST(Publisher, EventsPublishedByAProcessResumedAfterItsLinkTimedOutAreNotLost) {
  auto server = planet_test::start_test_server(
      {"--tick-every-ms", "50", "--heartbeat-ms", "250", "--heartbeat-timeout-ms", "1000"});
  TickSubscriber listener("mediator", 1000ms);
  auto peer = listener.subscribe(server.port);
  ASSERT_TRUE(planet_test::wait_until([&] { return listener.received().size() >= 5; }));
  server.process->freeze();
  ASSERT_TRUE(planet_test::wait_until([&] { return !peer->is_connected(); }));  // heartbeat timeout
  const auto before = listener.received().size();
  server.process->thaw();
  ASSERT_TRUE(planet_test::wait_until([&] { return peer->connect_count() >= 2 && peer->is_connected(); }));
  listener.subscribe_over(peer);
  ASSERT_TRUE(planet_test::wait_until([&] { return listener.received().size() >= before + 20; }));
  const auto seen = listener.received();
  ASSERT_FALSE(seen.empty());
  EXPECT_EQ(seen, range(seen.front(), seen.front() + static_cast<std::int64_t>(seen.size())))
      << "a tick was lost or delivered twice across the outage";
}

}  // namespace
}  // namespace icars::planet
