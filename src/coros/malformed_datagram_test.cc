// A flood of malformed datagrams, as an agent's operator meets it: 20,000 datagrams of garbage
// over real loopback UDP to one agent cost a few bad_datagram events a second (one per source
// a second), not one each, and the events' counts add up to every datagram sent, as do the
// transport's drop counts for the source. The aggregation itself, with time passed in, reports
// a source's first bad datagram at once, the rest once a period, and bounds its sources.
#include <gtest/gtest.h>

#include <asio/io_context.hpp>
#include <asio/ip/udp.hpp>
#include <chrono>
#include <mutex>
#include <vector>

#include "bad_datagram_reporter.h"
#include "child_process.h"
#include "icars/coros/agent.h"
#include "icars/coros/discovery.h"

namespace icars::coros {
namespace {

using namespace std::chrono_literals;
using planet_test::wait_until;
using Reason = BadDatagramReporter::Reason;

asio::ip::udp::endpoint endpoint(const char* ip, std::uint16_t port) {
  return {asio::ip::make_address(ip), port};
}

TEST(BadDatagramReporter, ReportsTheFirstAtOnceAndTheRestOncePerPeriodWithTheirCount) {
  BadDatagramReporter reporter(1000ms);
  const auto t0 = BadDatagramReporter::Clock::time_point{} + 1h;
  const auto first = reporter.add(endpoint("10.0.0.1", 5000), Reason::malformed, "bad magic", t0);
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->count, 1u);
  EXPECT_EQ(first->source, "10.0.0.1");
  EXPECT_EQ(first->from, "10.0.0.1:5000");
  EXPECT_EQ(first->error, "bad magic");
  for (int i = 0; i < 998; ++i) {
    EXPECT_FALSE(
        reporter.add(endpoint("10.0.0.1", 5001), Reason::malformed, "bad magic", t0 + 10ms));
  }
  EXPECT_FALSE(reporter.add(endpoint("10.0.0.1", 5002), Reason::refused, "no handler", t0 + 20ms));
  EXPECT_TRUE(reporter.due(t0 + 999ms).empty());
  EXPECT_EQ(reporter.next_due(), t0 + 1000ms);
  const auto second = reporter.due(t0 + 1000ms);
  ASSERT_EQ(second.size(), 1u);
  EXPECT_EQ(second[0].count, 999u);
  EXPECT_EQ(second[0].malformed, 998u);
  EXPECT_EQ(second[0].refused, 1u);
  EXPECT_EQ(second[0].from, "10.0.0.1:5002");  // the last one's
  EXPECT_EQ(second[0].error, "no handler");
  // Within the new period: counted, not reported; a quiet period after it forgets the source.
  EXPECT_FALSE(reporter.add(endpoint("10.0.0.1", 5000), Reason::malformed, "x", t0 + 1500ms));
  EXPECT_EQ(reporter.due(t0 + 2000ms).at(0).count, 1u);
  EXPECT_TRUE(reporter.due(t0 + 3000ms).empty());
  EXPECT_FALSE(reporter.next_due().has_value());
  EXPECT_TRUE(reporter.add(endpoint("10.0.0.1", 5000), Reason::malformed, "x", t0 + 3001ms));
}

TEST(BadDatagramReporter, SourcesBeyondTheLimitShareOneEntryAndFlushReportsTheRest) {
  BadDatagramReporter reporter(1000ms, 2);
  const auto t0 = BadDatagramReporter::Clock::time_point{} + 1h;
  EXPECT_TRUE(reporter.add(endpoint("10.0.0.1", 1), Reason::malformed, "x", t0));
  EXPECT_TRUE(reporter.add(endpoint("10.0.0.2", 1), Reason::malformed, "x", t0));
  const auto third = reporter.add(endpoint("10.0.0.3", 1), Reason::malformed, "x", t0);
  ASSERT_TRUE(third.has_value());
  EXPECT_EQ(third->source, "other");
  EXPECT_FALSE(reporter.add(endpoint("10.0.0.4", 1), Reason::malformed, "x", t0));
  EXPECT_FALSE(reporter.add(endpoint("10.0.0.1", 1), Reason::refused, "y", t0));
  const auto rest = reporter.flush();
  std::uint64_t total = 0;
  for (const auto& r : rest) total += r.count;
  EXPECT_EQ(total, 2u);
  EXPECT_FALSE(reporter.next_due().has_value());
}

// Every event of an agent, thread-safe.
class Events {
 public:
  Agent::EventSink sink() {
    return [this](const nlohmann::json& e) {
      std::lock_guard lock(mutex_);
      events_.push_back(e);
    };
  }
  std::vector<nlohmann::json> find(const std::string& kind) const {
    std::lock_guard lock(mutex_);
    std::vector<nlohmann::json> out;
    for (const auto& e : events_) {
      if (e.value("event", "") == kind) out.push_back(e);
    }
    return out;
  }
  std::uint64_t counted(const std::string& field) const {
    std::uint64_t n = 0;
    for (const auto& e : find("bad_datagram")) n += e.value(field, std::uint64_t{0});
    return n;
  }

 private:
  mutable std::mutex mutex_;
  std::vector<nlohmann::json> events_;
};

TEST(MalformedDatagrams, TwentyThousandCostAFewEventsASecondWhoseCountsAddUp) {
  constexpr std::uint64_t kDatagrams = 20000;
  constexpr std::uint64_t kBatch = 100;  // what the receive buffer surely holds
  AgentConfiguration config;
  config.id = "robot1";
  config.role = "robot";
  config.transport.broadcast_port = free_udp_port();
  config.transport.key = FleetKey::generate();
  Events events;
  Agent agent(config);
  agent.set_event_sink(events.sink());
  agent.add_operator(std::make_shared<DiscoveryOperator>());
  agent.start();
  const auto to = agent.call([&] { return agent.transport().local_endpoint(); });

  asio::io_context io;
  asio::ip::udp::socket s(io, asio::ip::udp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
  const auto started = std::chrono::steady_clock::now();
  std::vector<std::byte> garbage(48);
  for (std::uint64_t sent = 0; sent < kDatagrams;) {
    // In batches, each received before the next goes: loopback drops what overflows the
    // receive buffer, and every datagram must arrive for the counts to add up.
    for (std::uint64_t i = 0; i < kBatch; ++i, ++sent) {
      garbage[0] = static_cast<std::byte>(sent & 0xff);  // never the COROS magic
      garbage[1] = static_cast<std::byte>((sent >> 8) & 0xff);
      s.send_to(asio::buffer(garbage), to);
    }
    ASSERT_TRUE(wait_until([&] { return agent.stats().malformed >= sent; }, 30s))
        << "sent " << sent << ", received " << agent.stats().malformed;
  }
  // The events' counts reach every datagram within a period of the last one.
  ASSERT_TRUE(wait_until([&] { return events.counted("count") >= kDatagrams; }, 30s))
      << events.counted("count");
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  const auto reports = events.find("bad_datagram");
  // One source: the first at once, then at most one a second (plus one for the rounding).
  EXPECT_LE(static_cast<double>(reports.size()), seconds + 2) << seconds << " s";
  EXPECT_EQ(events.counted("count"), kDatagrams);
  EXPECT_EQ(events.counted("malformed"), kDatagrams);
  EXPECT_EQ(events.counted("refused"), 0u);
  for (const auto& r : reports) {
    EXPECT_EQ(r["source"], "127.0.0.1");
    EXPECT_FALSE(r.value("error", "").empty());
  }
  EXPECT_EQ(agent.call([&] { return agent.bad_datagrams(); }), kDatagrams);
  const auto stats = agent.stats();
  EXPECT_EQ(stats.malformed, kDatagrams);
  ASSERT_TRUE(stats.dropped_by_source.contains("127.0.0.1"));
  EXPECT_EQ(stats.dropped_by_source.at("127.0.0.1").malformed, kDatagrams);

  agent.stop();
  const auto stopped = events.find("stopped");
  ASSERT_EQ(stopped.size(), 1u);
  EXPECT_EQ(stopped[0]["datagrams"]["dropped_by_source"]["127.0.0.1"]["malformed"], kDatagrams);
  EXPECT_EQ(events.counted("count"), kDatagrams);  // nothing more at stop: all reported
}

TEST(MalformedDatagrams, WhatIsLeftIsReportedWhenTheAgentStops) {
  AgentConfiguration config;
  config.id = "robot1";
  config.role = "robot";
  config.transport.broadcast_port = free_udp_port();
  config.transport.key = FleetKey::generate();
  Events events;
  Agent agent(config);
  agent.set_event_sink(events.sink());
  agent.start();
  const auto to = agent.call([&] { return agent.transport().local_endpoint(); });
  asio::io_context io;
  asio::ip::udp::socket s(io, asio::ip::udp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
  const std::vector<std::byte> garbage(8);
  for (int i = 0; i < 10; ++i) s.send_to(asio::buffer(garbage), to);
  ASSERT_TRUE(wait_until([&] { return agent.stats().malformed >= 10; }, 20s));
  agent.stop();  // most likely within the source's first second: the rest come with the stop
  EXPECT_EQ(events.counted("count"), 10u);
}

}  // namespace
}  // namespace icars::coros
