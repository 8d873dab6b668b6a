// The live feed: records numbered and kept for a late page, every page its own bounded queue, a
// page that falls behind dropped and told how much, never slowing the publisher.
#include "icars/dashboard/event_hub.h"

#include <gtest/gtest.h>

#include <chrono>
#include <thread>

namespace icars::dashboard {
namespace {

using namespace std::chrono_literals;

TEST(EventHub, NumbersRecordsAndKeepsTheLatestForALatePage) {
  EventHub hub({.queue = 10, .history = 3, .max_clients = 4});
  for (int i = 0; i < 5; ++i) hub.publish_record("{\"t\":" + std::to_string(i) + "}");
  const auto h = hub.history();
  EXPECT_EQ(h.total, 5u);
  EXPECT_EQ(h.first_index, 2u);
  ASSERT_EQ(h.records.size(), 3u);
  EXPECT_EQ(h.records[0], "{\"index\":2,\"t\":2}");
  EXPECT_EQ(h.records[2], "{\"index\":4,\"t\":4}");
  hub.publish_record("{}");
  EXPECT_EQ(hub.history().records.back(), "{\"index\":5}");
}

TEST(EventHub, EachPageGetsWhatIsPublishedAfterItConnected) {
  EventHub hub;
  hub.publish_record("{\"t\":0}");
  auto a = hub.connect();
  hub.publish_record("{\"t\":1}");
  auto b = hub.connect();
  hub.publish_record("{\"t\":2}");
  hub.broadcast({"services", "[]"});
  const auto got_a = a->next(1s);
  ASSERT_TRUE(got_a);
  EXPECT_EQ(*got_a,
            "event: record\ndata: {\"index\":1,\"t\":1}\n\n"
            "event: record\ndata: {\"index\":2,\"t\":2}\n\n"
            "event: services\ndata: []\n\n");
  const auto got_b = b->next(1s);
  ASSERT_TRUE(got_b);
  EXPECT_EQ(*got_b, "event: record\ndata: {\"index\":2,\"t\":2}\n\nevent: services\ndata: []\n\n");
  // Nothing new: an empty batch after the wait (a keep-alive), not a hang.
  const auto idle = a->next(10ms);
  ASSERT_TRUE(idle);
  EXPECT_TRUE(idle->empty());
}

TEST(EventHub, AStuckPageIsDroppedAndToldNeverSlowingThePublisher) {
  EventHub hub({.queue = 100, .history = 10, .max_clients = 4});
  auto stuck = hub.connect();
  auto reader = hub.connect();
  const auto start = std::chrono::steady_clock::now();
  std::size_t read = 0;
  std::thread drain([&] {
    while (read < 100'000) {
      const auto b = reader->next(1s);
      if (!b) return;
      for (auto at = b->find("event: record"); at != std::string::npos; at = b->find("event: record", at + 1)) ++read;
    }
  });
  for (int i = 0; i < 100'000; ++i) hub.publish_record("{\"t\":1}");
  const auto took = std::chrono::steady_clock::now() - start;
  EXPECT_LT(took, 30s);  // bounded work per record: the stuck page costs one failed push each
  EXPECT_EQ(stuck->dropped(), 100'000u - 100u);
  const auto told = stuck->next(1s);
  ASSERT_TRUE(told);
  EXPECT_TRUE(told->starts_with("event: dropped\ndata: {\"dropped\":99900}\n\nevent: record\n")) << told->substr(0, 100);
  hub.close_all();
  drain.join();
  EXPECT_FALSE(stuck->next(10ms)) << "a closed page's stream ends";
}

TEST(EventHub, RefusesPagesBeyondItsLimit) {
  EventHub hub({.queue = 10, .history = 10, .max_clients = 2});
  auto a = hub.connect();
  auto b = hub.connect();
  EXPECT_EQ(hub.connect(), nullptr);
  hub.disconnect(a);
  EXPECT_NE(hub.connect(), nullptr);
  EXPECT_EQ(hub.clients(), 2u);
}

}  // namespace
}  // namespace icars::dashboard
