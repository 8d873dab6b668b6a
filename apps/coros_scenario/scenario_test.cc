// `icars-coros run` as a user runs it: real icars-agent processes over loopback UDP on the
// office floor, checked from the JSON summary and the SVG plot it writes.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "child_process.h"

using nlohmann::json;
namespace fs = std::filesystem;

namespace {

const std::string kCoros = ICARS_COROS_BINARY;
const std::string kMap = std::string(ICARS_HOUSES_DIR) + "/office_floor.xml";
#ifdef ICARS_AGENT_BINARY
const std::string kAgent = ICARS_AGENT_BINARY;
#else
const std::string kAgent;
#endif
const std::string kDeliveries = "office_101>office_112,office_104>office_109";

struct ScenarioRun {
  int exit_code = -1;
  std::string output;
  json summary;
  std::string svg;
};

fs::path make_temp_dir() {
  std::string pattern = ::testing::TempDir() + "coros_scenario_XXXXXX";
  if (::mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
  return pattern;
}

std::string read_file(const fs::path& file) {
  std::ifstream in(file);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Runs `icars-coros run` with the office floor and `extra` arguments, reading its output to
// the end; the summary and the plot are read back when written.
ScenarioRun run_coros(const std::vector<std::string>& extra, bool with_agent = true) {
  const fs::path dir = make_temp_dir();
  // Through a shell only to see stderr too: the usage errors are printed there.
  std::vector<std::string> argv = {"/bin/sh",
                                   "-c",
                                   "exec \"$0\" \"$@\" 2>&1",
                                   kCoros,
                                   "run",
                                   "--map",
                                   kMap,
                                   "--timeout",
                                   "100",
                                   "--json",
                                   (dir / "summary.json").string(),
                                   "--svg",
                                   (dir / "plot.svg").string()};
  if (with_agent && !kAgent.empty()) {
    argv.push_back("--agent-bin");
    argv.push_back(kAgent);
  }
  if (with_agent) {
    // Generous bounds for sanitizer builds on a loaded 2-core machine: an auction still
    // closes as soon as every robot has bid; a dead robot is noticed after 3 s.
    argv.insert(argv.end(), {"--bid-window", "2000", "--neighbor-expiry", "3000"});
  }
  argv.insert(argv.end(), extra.begin(), extra.end());
  ScenarioRun run;
  planet_test::ChildProcess child(argv);
  // read_line gives nullopt at end of output (the run is over) or when the time is up.
  while (const auto line = child.read_line(std::chrono::seconds(150))) run.output += *line + "\n";
  const int status = child.wait();
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  if (fs::exists(dir / "summary.json")) run.summary = json::parse(read_file(dir / "summary.json"));
  run.svg = read_file(dir / "plot.svg");
  fs::remove_all(dir);
  return run;
}

std::size_t count(const std::string& text, const std::string& what) {
  std::size_t n = 0;
  for (auto at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

// The winner of a round is a bidder with the lowest bid.
void expect_lowest_bidder_won(const json& round, const std::string& task) {
  ASSERT_TRUE(round["winner"].is_string()) << task << " round " << round["round"];
  ASSERT_FALSE(round["bids"].empty()) << task << " round " << round["round"];
  double lowest = std::numeric_limits<double>::infinity();
  for (const auto& [robot, cost] : round["bids"].items())
    lowest = std::min(lowest, cost.get<double>());
  const std::string winner = round["winner"];
  ASSERT_TRUE(round["bids"].contains(winner)) << task << ": " << winner << " won without a bid";
  EXPECT_DOUBLE_EQ(round["bids"][winner].get<double>(), lowest)
      << task << " round " << round["round"] << " went to " << winner
      << ", not the lowest bidder: " << round["bids"].dump();
}

class CorosScenario : public ::testing::Test {
 protected:
  void SetUp() override {
    if (kAgent.empty() || !fs::exists(kAgent)) GTEST_SKIP() << "icars-agent is not built";
  }
};

TEST_F(CorosScenario, BothDeliveriesGoToTheLowestBidders) {
  const ScenarioRun run = run_coros({"--robots", "5", "--deliveries", kDeliveries});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const json& s = run.summary;
  ASSERT_TRUE(s.is_object()) << run.output;
  EXPECT_TRUE(s["success"].get<bool>()) << run.output;
  ASSERT_EQ(s["deliveries"].size(), 2U) << run.output;
  const std::vector<std::pair<std::string, std::string>> asked = {{"office_101", "office_112"},
                                                                  {"office_104", "office_109"}};
  for (std::size_t i = 0; i < 2; ++i) {
    const json& d = s["deliveries"][i];
    const std::string task = d["task"].is_string() ? d["task"].get<std::string>() : "?";
    EXPECT_EQ(d["pickup"], asked[i].first);
    EXPECT_EQ(d["dropoff"], asked[i].second);
    EXPECT_TRUE(d["success"].get<bool>()) << task << ": " << d.dump() << "\n" << run.output;
    ASSERT_FALSE(d["rounds"].empty()) << task;
    for (const auto& round : d["rounds"]) {
      if (round["winner"].is_string()) expect_lowest_bidder_won(round, task);
    }
    EXPECT_EQ(d["rounds"].back()["winner"], d["robot"]) << task;
    EXPECT_GT(d["distance"].get<double>(), 0) << task;
  }
  EXPECT_EQ(s["robots"].size(), 5U);
  EXPECT_TRUE(s["discovery"]["convergence_s"].is_number()) << run.output;
  EXPECT_EQ(count(run.svg, "<polyline class=\"robot-track\""), 5U) << run.output;
}

TEST_F(CorosScenario, KilledWinnerIsReplacedByAnotherRobot) {
  // The first delivery's winner when nothing goes wrong: bids are planned path lengths from
  // fixed docks, so the same robot wins again in the run where it is killed.
  const ScenarioRun baseline = run_coros({"--robots", "5", "--deliveries", kDeliveries});
  ASSERT_EQ(baseline.exit_code, 0) << baseline.output;
  const std::string victim = baseline.summary["deliveries"][0]["rounds"][0]["winner"];

  const ScenarioRun run =
      run_coros({"--robots", "5", "--deliveries", kDeliveries, "--kill", victim + "@to_dropoff"});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const json& first = run.summary["deliveries"][0];
  ASSERT_GE(first["rounds"].size(), 2U) << "not auctioned again: " << first.dump() << "\n"
                                        << run.output;
  EXPECT_EQ(first["rounds"][0]["winner"], victim) << run.output;
  EXPECT_TRUE(first["rounds"][0]["reauction_reason"].is_string()) << first.dump();
  EXPECT_EQ(first["rounds"][1]["round"], 2);
  EXPECT_TRUE(first["success"].get<bool>()) << first.dump() << "\n" << run.output;
  ASSERT_TRUE(first["robot"].is_string()) << first.dump();
  EXPECT_NE(first["robot"], victim) << run.output;
  for (const auto& round : first["rounds"]) {
    if (round["winner"].is_string()) expect_lowest_bidder_won(round, "the first delivery");
  }
  bool killed = false;
  for (const auto& r : run.summary["robots"]) {
    if (r["id"] == victim) killed = r["killed"].get<bool>();
  }
  EXPECT_TRUE(killed) << run.output;
  EXPECT_TRUE(run.summary["deliveries"][1]["success"].get<bool>()) << run.output;
}

TEST_F(CorosScenario, LossyNetworkDeliversEveryTaskOnce) {
  // Every agent process drops, duplicates and delays a share of its datagrams (the transport's
  // fault hook), and a robot dies on its way: each delivery is still completed, and by
  // exactly one robot.
  const ScenarioRun run =
      run_coros({"--robots", "6", "--deliveries",
                 "office_101>office_112,office_104>office_109,office_110>office_102", "--faults",
                 "drop=0.2,duplicate=0.2,delay=0.3,max_delay_ms=80", "--kill", "robot2@3s"});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const json& s = run.summary;
  ASSERT_EQ(s["deliveries"].size(), 3U) << run.output;
  std::map<std::string, int> delivered;  // task -> robots that reached "delivered"
  for (const auto& r : s["robots"]) {
    for (const auto& stage : r["stages"]) {
      const std::string text = stage;
      const auto space = text.find(' ');
      if (text.substr(space + 1) == "delivered") ++delivered[text.substr(0, text.find('#'))];
    }
  }
  for (const auto& d : s["deliveries"]) {
    const std::string task = d["task"];
    EXPECT_TRUE(d["success"].get<bool>()) << task << ": " << d.dump() << "\n" << run.output;
    EXPECT_EQ(delivered[task], 1) << task << " delivered " << delivered[task] << " times\n"
                                  << run.output;
  }
}

TEST_F(CorosScenario, AgentsShareAFreshKeyAndRefuseToStartWithout) {
  const fs::path keep = make_temp_dir();
  const ScenarioRun run = run_coros(
      {"--robots", "2", "--deliveries", "office_101>office_112", "--keep-dir", keep.string()});
  ASSERT_EQ(run.exit_code, 0) << run.output;
  // Every agent got the run's key, in a configuration only its owner may read.
  const json robot = json::parse(read_file(keep / "robot1.json"));
  const json user = json::parse(read_file(keep / "user.json"));
  ASSERT_TRUE(robot["key"].is_string()) << robot.dump();
  EXPECT_EQ(robot["key"].get<std::string>().size(), 64U);
  EXPECT_EQ(robot["key"], user["key"]);
  EXPECT_EQ(fs::status(keep / "robot1.json").permissions() &
                (fs::perms::group_all | fs::perms::others_all),
            fs::perms::none);

  // The same configuration without its key: icars-agent refuses to start and says why.
  json keyless = robot;
  keyless.erase("key");
  const fs::path file = keep / "keyless.json";
  std::ofstream(file) << keyless.dump(2) << "\n";
  planet_test::ChildProcess agent(
      {"/bin/sh", "-c", "exec \"$0\" \"$@\" 2>&1", kAgent, file.string()});
  std::string output;
  while (const auto line = agent.read_line(std::chrono::seconds(30))) output += *line + "\n";
  const int status = agent.wait();
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 2) << output;
  EXPECT_NE(output.find("keyless.json: no fleet key"), std::string::npos) << output;
  EXPECT_NE(output.find("'insecure': true"), std::string::npos) << output;
  fs::remove_all(keep);
}

TEST(CorosScenarioUsage, BadInputsExitWithTwoAndSayWhy) {
  struct Case {
    std::vector<std::string> args;
    std::string message;
  };
  const std::vector<Case> cases = {
      {{"--deliveries", "office_101>office_999"}, "unknown place \"office_999\""},
      {{"--deliveries", "office_101"}, "expected PICKUP>DROPOFF"},
      {{"--deliveries", kDeliveries, "--kill", "robot9@to_dropoff"}, "no robot \"robot9\""},
      {{"--deliveries", kDeliveries, "--kill", "robot1@sleeping"}, "unknown stage"},
      {{"--deliveries", kDeliveries, "--faults", "drop=2"}, "--faults"},
      {{"--robots", "0", "--deliveries", kDeliveries}, "--robots 0"},
      {{}, "no deliveries"},
      {{"--deliveries", kDeliveries, "--agent-bin", "/nonexistent/icars-agent"}, "--agent-bin"},
  };
  for (const auto& c : cases) {
    std::vector<std::string> args = c.args;
    // Usage errors are found before any agent starts, so any executable does as the agent.
    if (std::find(args.begin(), args.end(), "--agent-bin") == args.end()) {
      args.insert(args.end(), {"--agent-bin", "/bin/true"});
    }
    const ScenarioRun run = run_coros(args, /*with_agent=*/false);
    std::string joined;
    for (const auto& a : c.args) joined += a + " ";
    EXPECT_EQ(run.exit_code, 2) << joined << "\n" << run.output;
    EXPECT_NE(run.output.find(c.message), std::string::npos)
        << joined << ": the message does not say \"" << c.message << "\":\n"
        << run.output;
    EXPECT_TRUE(run.summary.is_null()) << joined;
  }
}

}  // namespace
