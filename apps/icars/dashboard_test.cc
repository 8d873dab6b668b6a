// `icars run --http` and `icars replay --http` as a script drives them: the real program as a
// child process, its dashboard over HTTP — the snapshot of the house, the policy and the services,
// the controls behind the printed token reaching the simulated house and the lock-step clock,
// and a recorded trace paged through in a replay.
#include <gtest/gtest.h>
#include <httplib.h>

#include <nlohmann/json.hpp>

#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <thread>
#include <utility>

#include "child_process.h"
#include "program_run.h"

using nlohmann::json;
using namespace std::chrono_literals;

namespace {

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;

struct Address {
  int port = 0;
  std::string token;
};

// Reads the program's lines until it prints the dashboard's URL.
Address dashboard_address(planet_test::ChildProcess& icars, const std::string& prefix) {
  const std::regex url(R"(http://127\.0\.0\.1:(\d+)/(\?token=([0-9a-f]+))?)");
  while (auto line = icars.read_line(60s)) {
    std::smatch m;
    if (line->starts_with(prefix) && std::regex_search(*line, m, url)) return {std::stoi(m[1]), m[3]};
  }
  return {};
}

json get(httplib::Client& c, const std::string& path) {
  const auto r = c.Get(path.c_str());
  if (!r || r->status != 200) return nullptr;
  return json::parse(r->body, nullptr, false);
}

// The simulated time of the newest record the dashboard holds.
std::int64_t newest_time(httplib::Client& c) {
  const auto s = get(c, "/api/snapshot");
  return s.is_object() && !s["records"].empty() ? s["records"].back().value("t", std::int64_t{0}) : 0;
}

}  // namespace

TEST(IcarsDashboard, ARunsDashboardShowsItAndItsControlsDriveIt) {
  planet_test::ChildProcess icars({kIcars, "run", kSource + "/examples/smart_home/paper_home.xml", "--world",
                                   kSource + "/houses/paper_house.xml", "--speed", "60", "--until", "23:00", "--quiet",
                                   "--http", "127.0.0.1:0"});
  const auto address = dashboard_address(icars, "[icars] dashboard:");
  ASSERT_NE(address.port, 0) << "no dashboard URL printed";
  ASSERT_EQ(address.token.size(), 64u);
  httplib::Client c("127.0.0.1", address.port);
  c.set_read_timeout(30, 0);
  const httplib::Headers auth{{"Authorization", "Bearer " + address.token}};

  // The page, and a snapshot of the house, the policy and the services.
  const auto page = c.Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  ASSERT_TRUE(planet_test::wait_until([&] {
    const auto s = get(c, "/api/snapshot");
    return s.is_object() && s["policy"].is_object() && !s["services"].empty();
  }, 60s));
  const auto snapshot = get(c, "/api/snapshot");
  EXPECT_EQ(snapshot["mode"], "live");
  EXPECT_EQ(snapshot["controls"], true);
  EXPECT_EQ(snapshot["house"]["name"], "paper_house");
  EXPECT_EQ(snapshot["house"]["rooms"].size(), 2u);
  EXPECT_EQ(snapshot["policy"]["name"], "paper_home");
  EXPECT_TRUE(snapshot["policy"]["tasks"].contains("RestMode"));
  EXPECT_NE(snapshot["services"].dump().find("\"TVControl\""), std::string::npos);

  // A user's sentence: only with the token, only a user of the house; then heard by the robot.
  auto r = c.Post("/api/say", R"({"user":"user1","text":"play music"})", "application/json");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 401);
  r = c.Post("/api/say", auth, R"({"user":"nobody","text":"play music"})", "application/json");
  EXPECT_EQ(r->status, 400);
  EXPECT_NE(r->body.find("no user 'nobody' (users: user1)"), std::string::npos) << r->body;
  const auto before = newest_time(c);
  r = c.Post("/api/say", auth, R"({"user":"user1","text":"play music"})", "application/json");
  EXPECT_EQ(r->status, 200) << r->body;
  // Heard: recognized as a phrase of the running policy's voice behaviors, or (none listening)
  // as free speech; either way a speech record of the robot's microphone.
  EXPECT_TRUE(planet_test::wait_until([&] {
    const auto snapshot_now = get(c, "/api/snapshot");
    if (!snapshot_now.is_object()) return false;
    for (const auto& record : snapshot_now["records"]) {
      if (record.value("kind", "") == "speech" && record.value("t", std::int64_t{0}) >= before) return true;
    }
    return false;
  }, 60s)) << "the sentence never reached the robot's microphone";

  // A policy that does not load: its error; the running one goes on.
  r = c.Post("/api/policy", auth, R"({"name":"no_such_policy"})", "application/json");
  EXPECT_EQ(r->status, 422);
  EXPECT_NE(r->body.find("\"no_such_policy.xml:0: error: cannot read the policy file"), std::string::npos)
      << r->body;  // named from the repository: the server's directories stay its own
  EXPECT_EQ(get(c, "/api/snapshot")["policy"]["name"], "paper_home");

  // Paused, the simulated clock stands still; resumed and faster, it goes on.
  r = c.Post("/api/pause", auth, "{}", "application/json");
  ASSERT_EQ(r->status, 200) << r->body;
  // What was under way at the pause finishes at the paused instant; then nothing comes later.
  std::int64_t paused_at = newest_time(c);
  ASSERT_TRUE(planet_test::wait_until([&] {
    std::this_thread::sleep_for(300ms);
    const auto now = newest_time(c);
    return std::exchange(paused_at, now) == now;
  }, 30s));
  std::this_thread::sleep_for(1500ms);  // what must not happen: records after the pause
  EXPECT_EQ(newest_time(c), paused_at) << "the clock moved while paused";
  r = c.Post("/api/speed", auth, R"({"speed":3000})", "application/json");
  EXPECT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(json::parse(r->body)["paused"], true);
  r = c.Post("/api/resume", auth, "{}", "application/json");
  EXPECT_EQ(r->status, 200);
  EXPECT_TRUE(planet_test::wait_until([&] { return newest_time(c) > paused_at; }, 60s));
  r = c.Post("/api/speed", auth, R"({"speed":-1})", "application/json");
  EXPECT_EQ(r->status, 400);

  icars.signal(SIGTERM);
  const auto status = icars.wait_for(60s);
  ASSERT_TRUE(status);
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0) << *status;
}

TEST(IcarsDashboard, AReplayPagesThroughARecordedTrace) {
  const auto trace = icars_test::temp_path("dashboard", "replay.jsonl");
  const auto recorded = icars_test::run_program(kIcars, "run " + kSource + "/examples/smart_home/paper_home.xml --world " +
                                                            kSource + "/houses/paper_house.xml --speed max --until 19:00 "
                                                            "--quiet --trace " + trace);
  ASSERT_EQ(recorded.exit_code, 0) << recorded.output;
  std::size_t lines = 0;
  {
    std::ifstream in(trace);
    for (std::string l; std::getline(in, l);) {
      if (!l.empty()) ++lines;
    }
  }
  planet_test::ChildProcess replay({kIcars, "replay", trace, "--world", kSource + "/houses/paper_house.xml", "--policy",
                                    kSource + "/examples/smart_home/paper_home.xml", "--http", "127.0.0.1:0"});
  const auto address = dashboard_address(replay, "[icars] replaying");
  ASSERT_NE(address.port, 0);
  EXPECT_TRUE(address.token.empty()) << "a replay has no controls";
  httplib::Client c("127.0.0.1", address.port);
  const auto snapshot = get(c, "/api/snapshot");
  ASSERT_TRUE(snapshot.is_object());
  EXPECT_EQ(snapshot["mode"], "replay");
  EXPECT_EQ(snapshot["total"], lines);
  EXPECT_EQ(snapshot["policy"]["name"], "paper_home");
  EXPECT_EQ(snapshot["time"]["start_ms"], 18 * 3600 * 1000);
  const auto last = get(c, "/api/records?from=" + std::to_string(lines - 1) + "&count=10");
  ASSERT_EQ(last["records"].size(), 1u);
  EXPECT_EQ(last["records"][0]["t"], snapshot["time"]["end_ms"]);
  replay.signal(SIGTERM);
  const auto status = replay.wait_for(30s);
  ASSERT_TRUE(status);
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0) << *status;

  // A broken trace is refused at its line.
  {
    std::ofstream out(trace, std::ios::app);
    out << "not a record\n";
  }
  const auto broken = icars_test::run_program(kIcars, "replay " + trace + " --world " + kSource +
                                                          "/houses/paper_house.xml --http 127.0.0.1:0");
  EXPECT_EQ(broken.exit_code, 2);
  EXPECT_NE(broken.output.find(":" + std::to_string(lines + 1) + ": not a JSON object"), std::string::npos)
      << broken.output;
  std::filesystem::remove(trace);
}

TEST(IcarsDashboard, ADashboardBeyondLoopbackNeedsTls) {
  const auto r = icars_test::run_program(kIcars, "run " + kSource + "/examples/smart_home/paper_home.xml --world " +
                                                     kSource + "/houses/paper_house.xml --http 0.0.0.0:0");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("--http 0.0.0.0:0: the dashboard on 0.0.0.0:0 would be reachable from other machines"),
            std::string::npos)
      << r.output;
}
