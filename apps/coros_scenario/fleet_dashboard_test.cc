// `icars-coros run --http` as a browser reads it: the fleet page, and /api/snapshot with the office
// floor and the records of every agent, the robots' positions and the run's summary.
#include <gtest/gtest.h>
#include <httplib.h>
#include <signal.h>
#include <sys/wait.h>

#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>
#include <string>

#include "child_process.h"

using nlohmann::json;

namespace {

const std::string kCoros = ICARS_COROS_BINARY;
const std::string kMap = std::string(ICARS_HOUSES_DIR) + "/office_floor.xml";
#ifdef ICARS_AGENT_BINARY
const std::string kAgent = ICARS_AGENT_BINARY;
#else
const std::string kAgent;
#endif

TEST(FleetDashboard, ServesTheFleetPageAndTheRunsRecords) {
  if (kAgent.empty() || !std::filesystem::exists(kAgent)) GTEST_SKIP() << "icars-agent is not built";
  planet_test::ChildProcess coros({"/bin/sh", "-c", "exec \"$0\" \"$@\" 2>&1", kCoros, "run", "--map", kMap,
                                   "--robots", "2", "--deliveries", "office_101>office_112", "--agent-bin", kAgent,
                                   "--bid-window", "2000", "--neighbor-expiry", "3000", "--timeout", "100",
                                   "--http", "127.0.0.1:0", "--http-linger", "-1"});
  std::string output;
  int port = 0;
  bool lingering = false;
  const std::regex address(R"(\[icars-coros\] dashboard: http://127\.0\.0\.1:(\d+)/fleet)");
  while (const auto line = coros.read_line(std::chrono::seconds(120))) {
    output += *line + "\n";
    std::smatch m;
    if (std::regex_search(*line, m, address)) port = std::stoi(m[1]);
    if (line->find("the dashboard stays at") != std::string::npos) {
      lingering = true;
      break;
    }
  }
  ASSERT_NE(port, 0) << output;
  ASSERT_TRUE(lingering) << output;

  httplib::Client http("127.0.0.1", port);
  const auto page = http.Get("/fleet");
  ASSERT_TRUE(page) << "no answer from the dashboard";
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->body.find("/static/fleet.js"), std::string::npos) << page->body;
  const auto script = http.Get("/static/fleet.js");
  ASSERT_TRUE(script);
  EXPECT_EQ(script->status, 200);

  const auto answer = http.Get("/api/snapshot");
  ASSERT_TRUE(answer);
  ASSERT_EQ(answer->status, 200);
  const json s = json::parse(answer->body);
  EXPECT_EQ(s["mode"], "fleet");
  EXPECT_EQ(s["controls"], false);
  EXPECT_EQ(s["house"]["name"], "office_floor");
  std::set<std::string> rooms, sources, events;
  for (const auto& r : s["house"]["rooms"]) rooms.insert(r["name"].get<std::string>());
  EXPECT_TRUE(rooms.count("room_101") && rooms.count("room_112")) << s["house"]["rooms"].dump();
  bool positions = false, summary = false;
  for (const auto& r : s["records"]) {
    ASSERT_TRUE(r["t"].is_number() && r["time"].is_string() && r["text"].is_string()) << r.dump();
    const std::string kind = r["kind"];
    if (kind == "agent") {
      sources.insert(r["source"].get<std::string>());
      events.insert(r["event"].get<std::string>());
      if (r["event"] == "awarded") {
        EXPECT_TRUE(r["bids"].is_object()) << r.dump();
      }
    }
    if (kind == "robot") positions = positions || (r["x"].is_number() && r["y"].is_number() && r["path"].is_array());
    if (kind == "scenario" && r.value("event", "") == "summary") summary = r["success"].get<bool>();
  }
  EXPECT_EQ(sources, (std::set<std::string>{"robot1", "robot2", "user"}));
  for (const char* e : {"started", "neighbor_joined", "auction", "bid_received", "awarded", "assigned",
                        "task_stage", "delivery_finished"}) {
    EXPECT_TRUE(events.count(e)) << "no " << e << " record";
  }
  EXPECT_TRUE(positions) << "no robot position";
  EXPECT_TRUE(summary) << output;

  // It lingers until asked to stop, then ends with the run's exit code.
  coros.signal(SIGTERM);
  const auto status = coros.wait_for(std::chrono::seconds(30));
  ASSERT_TRUE(status) << "icars-coros did not end after SIGTERM";
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0) << output;
}

TEST(FleetDashboard, RefusesToListenBeyondLoopbackWithoutTls) {
  planet_test::ChildProcess coros({"/bin/sh", "-c", "exec \"$0\" \"$@\" 2>&1", kCoros, "run", "--map", kMap,
                                   "--deliveries", "office_101>office_112", "--agent-bin", "/bin/true",
                                   "--http", "0.0.0.0:0"});
  std::string output;
  while (const auto line = coros.read_line(std::chrono::seconds(30))) output += *line + "\n";
  const int status = coros.wait();
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 2) << output;
  EXPECT_NE(output.find("--http 0.0.0.0:0"), std::string::npos) << output;
  EXPECT_NE(output.find("TLS"), std::string::npos) << output;
}

}  // namespace
