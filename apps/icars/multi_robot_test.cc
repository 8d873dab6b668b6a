// A home with two robots allocated by the COROS market (docs/distribution.md, "Robots"):
// examples/multi_robot/two_robot_home.xml on houses/two_robot_house.xml.
//  - In one process (lock-step): the robots bid for every robot="any" behavior, the night patrol
//    is split between them, every waypoint is reached once per round, and the trace holds the
//    auctions with every robot's bid.
//  - As processes: the mediator, a device manager with the house and robot1, one with robot2,
//    the robots' COROS agents beside them. robot2's device manager is SIGKILLed at a seeded
//    random moment of the night patrol: its waypoints are auctioned again and reached by robot1,
//    every waypoint is reached once per round or reported, no task fails, the run reaches the
//    morning, and the trace shows the re-auction with the bids.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "house_processes.h"
#include "icars/coros/authentication.h"
#include "icars/coros/transport.h"
#include "program_run.h"

namespace {

using namespace std::chrono_literals;
using icars_test::json;
using icars_test::str;

const std::string kIcars = ICARS_BINARY;
const std::string kDeviceManager = ICARS_DEVICE_MANAGER_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kHouse = kSource + "/houses/two_robot_house.xml";
const std::string kPolicy = kSource + "/examples/multi_robot/two_robot_home.xml";
const std::vector<std::string> kPatrol = {"entrance", "living_room_center", "kitchen_corner",
                                          "door",     "bedroom_center",     "bedroom_window"};
constexpr int kRounds = 3;  // the policy's PatrolHome rounds

std::vector<json> trace_of(const std::string& path) {
  try {
    return icars_test::read_json_lines(path);
  } catch (const std::exception&) {
    return {};
  }
}

bool patrol_auction(const json& j) {
  return str(j, "kind") == "auction" && str(j, "source").find("PatrolHome") != std::string::npos;
}

// What the night's patrol did, from the trace: who reached which waypoint, what was reported
// instead, the transitions.
struct Night {
  std::map<std::string, int> reached;             // waypoint -> times reached
  std::map<std::string, std::set<std::string>> by;  // robot -> waypoints it reached
  std::vector<std::string> skipped;               // "skips <waypoint>: why" notes
  std::vector<json> auctions, transitions;
  bool failed_transition = false;
};

Night read_night(const std::vector<json>& trace) {
  Night n;
  for (const auto& j : trace) {
    const auto kind = str(j, "kind");
    if (kind == "event" && str(j, "event") == "WaypointReached" && str(j, "source") == "SleepMode") {
      const auto waypoint = j.value(json::json_pointer("/properties/waypoint"), std::string());
      ++n.reached[waypoint];
      n.by[j.value(json::json_pointer("/properties/robot"), std::string())].insert(waypoint);
    } else if (kind == "note" && str(j, "text").find("PatrolHome: skips ") != std::string::npos) {
      n.skipped.push_back(str(j, "text"));
    } else if (patrol_auction(j)) {
      n.auctions.push_back(j);
    } else if (kind == "transition") {
      n.transitions.push_back(j);
      if (str(j, "event") == "failed") n.failed_transition = true;
    }
  }
  return n;
}

std::string dump(const std::vector<json>& records) {
  std::string out;
  for (const auto& j : records) out += j.dump() + "\n";
  return out;
}

TEST(MultiRobot, InOneProcessTheRobotsBidAndTheNightPatrolIsSplitBetweenThem) {
  const auto dir = icars_test::run_directory("", "icars_multi_robot");
  const auto trace = (dir / "trace.jsonl").string();
  const auto run = icars_test::run_program(
      kIcars, "run " + kPolicy + " --world " + kHouse + " --quiet --trace " + trace, 600);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const auto records = trace_of(trace);
  auto night = read_night(records);

  EXPECT_FALSE(night.failed_transition) << dump(night.transitions);
  // Both robots bid for every stop; each of the 6 waypoints x 3 rounds was awarded once.
  std::vector<json> awarded;
  for (const auto& a : night.auctions) {
    if (str(a, "outcome") != "awarded") continue;
    awarded.push_back(a);
    EXPECT_TRUE(a.contains("bid.robot1") && a.contains("bid.robot2")) << a.dump();
    EXPECT_EQ(a.value("cost", -1.0), std::min(a.value("bid.robot1", 1e9), a.value("bid.robot2", 1e9))) << a.dump();
  }
  EXPECT_EQ(awarded.size(), kPatrol.size() * kRounds) << dump(night.auctions);
  // Every waypoint reached once per round, and the work shared.
  for (const auto& w : kPatrol) EXPECT_EQ(night.reached[w], kRounds) << w;
  EXPECT_TRUE(night.skipped.empty()) << night.skipped.front();
  EXPECT_FALSE(night.by["robot1"].empty());
  EXPECT_FALSE(night.by["robot2"].empty());
  // The robots went to the user and docked through the market too.
  EXPECT_TRUE(std::any_of(records.begin(), records.end(), [](const json& j) {
    return str(j, "kind") == "auction" && str(j, "source").find("GoToUser") != std::string::npos &&
           str(j, "outcome") == "awarded";
  }));
  EXPECT_TRUE(std::any_of(records.begin(), records.end(), [](const json& j) {
    return str(j, "kind") == "auction" && str(j, "source").find("NightWatch/GoTo") != std::string::npos &&
           str(j, "stop") == "dock" && str(j, "outcome") == "awarded";
  }));
  // The night ended in the morning: the user got up and the coordinator observes again.
  ASSERT_FALSE(night.transitions.empty());
  EXPECT_EQ(str(night.transitions.back(), "to"), "Observation") << dump(night.transitions);
  if (!::testing::Test::HasFailure()) std::filesystem::remove_all(dir);
}

// A behavior with robot="any" started again (here a repeat's second run) listens to its robots
// again: every round's stops are reached, none stalls.
TEST(MultiRobot, ARepeatedPatrolListensToItsRobotsAgain) {
  const auto dir = icars_test::run_directory("", "icars_multi_robot_repeat");
  const auto trace = (dir / "trace.jsonl").string();
  const auto policy = (dir / "twice.xml").string();
  std::ofstream(policy) << R"xml(<?xml version="1.0" encoding="UTF-8"?>
<policy name="twice">
  <task name="Rounds">
    <repeat name="Twice" times="2">
      <behavior type="PatrolHome" robot="any" waypoints="kitchen_corner, bedroom_window, entrance, bedroom_center"/>
    </repeat>
  </task>
  <task name="Rest"><behavior type="Wait" duration="12h"/></task>
  <statechart initial="Patrolling">
    <state name="Patrolling" task="Rounds"><transition event="done" target="Resting"/></state>
    <state name="Resting" task="Rest"/>
  </statechart>
</policy>
)xml";
  const auto run = icars_test::run_program(
      kIcars, "run " + policy + " --world " + kHouse + " --quiet --until 20:00 --trace " + trace, 600);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const auto records = trace_of(trace);
  std::map<std::string, int> reached;
  std::set<std::string> robots;
  for (const auto& j : records) {
    if (str(j, "kind") == "event" && str(j, "event") == "WaypointReached" && str(j, "source") == "Rounds") {
      ++reached[j.value(json::json_pointer("/properties/waypoint"), std::string())];
      robots.insert(j.value(json::json_pointer("/properties/robot"), std::string()));
    }
    EXPECT_FALSE(str(j, "kind") == "auction" && str(j, "outcome") != "awarded") << j.dump();
  }
  for (const auto* w : {"kitchen_corner", "bedroom_window", "entrance", "bedroom_center"}) EXPECT_EQ(reached[w], 2) << w;
  EXPECT_EQ(robots, (std::set<std::string>{"robot1", "robot2"}));
  EXPECT_TRUE(std::any_of(records.begin(), records.end(), [](const json& j) {
    return str(j, "kind") == "transition" && str(j, "to") == "Resting";
  })) << run.output;
  if (!::testing::Test::HasFailure()) std::filesystem::remove_all(dir);
}

enum class Loss { killed, frozen };

// The night of two_robot_home as processes, robot2's device manager lost mid-patrol: SIGKILLed,
// or stopped (SIGSTOP: its link stays up until the heartbeat timeout, its robot reports nothing,
// so it stalls) and let go on after the night. Returns the reason of robot2's first re-auction.
std::string night_losing_robot2(Loss loss) {
  std::string first_reason;
  const auto dir = icars_test::run_directory("", loss == Loss::killed ? "icars_multi_robot_kill" : "icars_multi_robot_freeze");
  const auto env = icars_test::child_environment();
  const auto trace = (dir / "trace.jsonl").string();
  // The fleet: a port of its own and a key only this run knows.
  const auto port = std::to_string(icars::coros::free_udp_port());
  const auto key = (dir / "fleet.key").string();
  {
    std::ofstream out(key);
    out << icars::coros::FleetKey::generate().to_hex() << "\n";
  }
  ::chmod(key.c_str(), 0600);
  const std::vector<std::string> fleet = {"--fleet-port", port, "--fleet-key", key};
  const auto with_fleet = [&](std::vector<std::string> argv) {
    argv.insert(argv.end(), fleet.begin(), fleet.end());
    return argv;
  };
  // The house starts at 18:00; the managers start at 22:40 of it (--epoch in the past), with the
  // user in bed, and run at 300x: the night is about 100 s.
  constexpr double kSpeed = 300;
  const auto epoch =
      icars_test::SharedClock::wall_ms() - static_cast<std::int64_t>((4 * 3600 + 40 * 60) * 1000 / kSpeed);
  const auto speed = std::to_string(kSpeed);

  icars_test::Program mediator(
      dir / "icars.stderr", env,
      with_fleet({kIcars, "run", kPolicy, "--world", kHouse, "--external", "--listen", "127.0.0.1:0", "--until",
                  "07:30", "--wait-for", "robot1_wheels,robot2_wheels,robot2_camera", "--trace", trace, "--quiet"}));
  std::vector<std::string> output;
  const auto server_port = icars_test::start_mediator(mediator, output);
  if (server_port.empty()) {
    ADD_FAILURE() << mediator.stderr_text();
    return first_reason;
  }
  const auto server = "127.0.0.1:" + server_port;
  icars_test::Program house(
      dir / "house.stderr", env,
      with_fleet({kDeviceManager, "--house", kHouse, "--server", server, "--speedup", speed, "--epoch",
                  std::to_string(epoch), "--devices",
                  "tv,living_light,sofa_sensor,bedroom_light,bed_sensor,robot1_wheels,robot1_mic,robot1_speaker,"
                  "robot1_camera"}));
  icars_test::Program robot2(
      dir / "robot2.stderr", env,
      with_fleet({kDeviceManager, "--house", kHouse, "--server", server, "--speedup", speed, "--epoch",
                  std::to_string(epoch), "--no-engines", "--no-simulator", "--devices", "robot2_wheels,robot2_camera"}));

  // The moment of the loss: while robot2 holds a share of the patrol — once it has won a seeded
  // random number of waypoints (1 to 3: in the first round or the second), a random part of a
  // simulated second later (a leg takes 3 to 10 s, 10 to 33 ms here). The trace is followed as it
  // grows (parsing all of it each time would lag a leg behind on a loaded machine), and robot2 is
  // stopped first: it is lost only if it still holds a waypoint it won and has not reached,
  // otherwise it goes on and the next waypoint it wins decides.
  const auto seed = static_cast<std::uint32_t>(std::random_device{}());
  std::mt19937 random(seed);
  auto awards = static_cast<std::size_t>(std::uniform_int_distribution<int>(1, 3)(random));
  const auto extra = std::chrono::microseconds(
      static_cast<std::int64_t>(std::uniform_real_distribution<double>(0, 1)(random) * 1e6 / kSpeed));
  SCOPED_TRACE(testing::Message() << "seed " << seed << ": robot2 lost once it won " << awards
                                  << " waypoints, " << extra.count() << " us later");
  icars_test::JsonLinesTail tail(trace);
  std::size_t won = 0;
  std::map<std::string, int> won_at, reached_at;  // robot2's awards and arrivals, by waypoint
  const auto follow = [&] {
    try {
      for (const auto& j : tail.read()) {
        if (patrol_auction(j) && str(j, "outcome") == "awarded" && str(j, "robot") == "robot2") {
          ++won;
          ++won_at[str(j, "stop")];
        } else if (str(j, "kind") == "event" && str(j, "event") == "WaypointReached" &&
                   j.value(json::json_pointer("/properties/robot"), std::string()) == "robot2") {
          ++reached_at[j.value(json::json_pointer("/properties/waypoint"), std::string())];
        }
      }
    } catch (const std::exception& e) {
      ADD_FAILURE() << "the trace is not JSON lines: " << e.what();
    }
  };
  const auto holds_a_waypoint = [&] {
    return std::any_of(won_at.begin(), won_at.end(), [&](const auto& w) { return w.second > reached_at[w.first]; });
  };
  const auto deadline = std::chrono::steady_clock::now() + 240s;
  for (;;) {
    if (std::chrono::steady_clock::now() > deadline || mediator.exited()) {
      ADD_FAILURE() << "robot2 never got its share of the patrol\n" << icars_test::tail(mediator.stderr_text());
      return first_reason;
    }
    follow();
    if (won >= awards && holds_a_waypoint()) {
      std::this_thread::sleep_for(extra);
      robot2.freeze();
      // Arrivals robot2 reported before it stopped reach the trace in a few ms; this looks for
      // 200 ms (a simulated minute, less than the two minutes that make a robot stalled).
      const auto settled = std::chrono::steady_clock::now() + 200ms;
      while (std::chrono::steady_clock::now() < settled) {
        follow();
        std::this_thread::sleep_for(5ms);
      }
      if (holds_a_waypoint()) break;
      robot2.thaw();
      awards = won + 1;
    }
    std::this_thread::sleep_for(1ms);
  }
  // Stopped now; killed, or left stopped.
  if (loss == Loss::killed) robot2.signal(SIGKILL);

  const auto end = std::chrono::steady_clock::now() + 400s;
  while (!mediator.exited()) {
    if (std::chrono::steady_clock::now() > end) {
      ADD_FAILURE() << "the run did not reach 07:30";
      if (loss == Loss::frozen) robot2.thaw();
      return first_reason;
    }
    std::this_thread::sleep_for(100ms);
  }
  EXPECT_TRUE(icars_test::exit_problems("icars", mediator.wait(), mediator.stderr_text()).empty())
      << icars_test::tail(mediator.stderr_text());
  house.signal(SIGTERM);
  EXPECT_TRUE(icars_test::exit_problems("house", house.wait(), house.stderr_text()).empty())
      << icars_test::tail(house.stderr_text());
  if (loss == Loss::frozen) {
    robot2.thaw();
    robot2.signal(SIGTERM);
  }
  robot2.wait();

  const auto records = trace_of(trace);
  auto night = read_night(records);
  EXPECT_FALSE(night.failed_transition) << dump(night.transitions);
  // Every waypoint reached once per round, or reported.
  for (const auto& w : kPatrol) {
    const auto reported = std::count_if(night.skipped.begin(), night.skipped.end(),
                                        [&](const std::string& s) { return s.find("skips " + w + ":") != std::string::npos; });
    EXPECT_EQ(night.reached[w] + reported, kRounds) << w << "\n" << dump(night.auctions);
  }
  // robot2's share went to robot1: a re-auction naming robot2 and why, then an award to robot1
  // with the bids of that round (robot2 excluded).
  const auto lost = std::find_if(night.auctions.begin(), night.auctions.end(), [](const json& a) {
    return str(a, "outcome") == "reauction" && str(a, "robot") == "robot2";
  });
  EXPECT_NE(lost, night.auctions.end()) << "no re-auction of robot2's waypoints\n" << dump(night.auctions);
  if (lost == night.auctions.end()) return first_reason;
  first_reason = str(*lost, "reason");
  EXPECT_FALSE(first_reason.empty()) << lost->dump();
  const auto again = std::find_if(lost, night.auctions.end(), [&](const json& a) {
    return str(a, "outcome") == "awarded" && str(a, "errand") == str(*lost, "errand");
  });
  EXPECT_NE(again, night.auctions.end()) << dump(night.auctions);
  if (again == night.auctions.end()) return first_reason;
  EXPECT_EQ(str(*again, "robot"), "robot1") << again->dump();
  EXPECT_TRUE(again->contains("bid.robot1")) << again->dump();
  EXPECT_FALSE(again->contains("bid.robot2")) << again->dump();
  EXPECT_NE(str(*again, "excluded").find("robot2"), std::string::npos) << again->dump();
  EXPECT_GE(again->value("round", 0), 2) << again->dump();
  // The morning: the user got up and the coordinator observes again.
  EXPECT_FALSE(night.transitions.empty());
  if (!night.transitions.empty()) {
    EXPECT_EQ(str(night.transitions.back(), "to"), "Observation") << dump(night.transitions);
  }
  if (!::testing::Test::HasFailure()) std::filesystem::remove_all(dir);
  return first_reason;
}

TEST(MultiRobot, ARobotKilledMidPatrolHasItsWaypointsAuctionedAgainAndFinishedByTheOther) {
  const auto reason = night_losing_robot2(Loss::killed);
  EXPECT_NE(reason.find("robot2_wheels"), std::string::npos) << reason;  // its Navigation service went away
}

TEST(MultiRobot, ARobotThatStopsMovingMidPatrolStallsAndTheOtherFinishesItsWaypoints) {
  const auto reason = night_losing_robot2(Loss::frozen);
  // Two simulated minutes without a pose report (0.4 s) come long before the link's 5 s
  // heartbeat timeout.
  EXPECT_EQ(reason, "robot2 stalled");
}

// The fleet's options: a clear reason and exit code 2, never a half-started fleet.
TEST(MultiRobot, BadFleetOptionsStopWithTheReason) {
  const auto dir = icars_test::run_directory("", "icars_multi_robot_bad");
  const auto key = (dir / "fleet.key").string();
  {
    std::ofstream out(key);
    out << icars::coros::FleetKey::generate().to_hex() << "\n";
  }
  ::chmod(key.c_str(), 0600);
  const auto open_key = (dir / "open.key").string();
  {
    std::ofstream out(open_key);
    out << icars::coros::FleetKey::generate().to_hex() << "\n";
  }
  ::chmod(open_key.c_str(), 0644);
  const auto short_key = (dir / "short.key").string();
  {
    std::ofstream out(short_key);
    out << "00ff\n";
  }
  ::chmod(short_key.c_str(), 0600);
  const auto port = std::to_string(icars::coros::free_udp_port());
  struct Case {
    std::string program, args, reason;
  };
  const std::vector<Case> cases = {
      {kDeviceManager, "--house " + kHouse + " --fleet-port " + port, "--fleet-port needs --fleet-key FILE"},
      {kDeviceManager, "--house " + kHouse + " --fleet-port " + port + " --fleet-key " + key + " --devices tv",
       "this manager hosts no robot's Wheels"},
      {kDeviceManager, "--house " + kHouse + " --fleet-port " + port + " --fleet-key " + open_key, open_key},
      {kDeviceManager, "--house " + kHouse + " --fleet-port " + port + " --fleet-key " + short_key, short_key},
      {kIcars, "run " + kPolicy + " --world " + kHouse + " --external", "needs the fleet its robots' device managers joined"},
      {kIcars, "run " + kPolicy + " --world " + kHouse + " --fleet-port " + port, "--fleet-port needs --fleet-key FILE"},
      {kIcars, "run " + kPolicy + " --world " + kHouse + " --wait-for robot2_wheels", "--wait-for is for --external runs"},
      {kIcars, "serve --fleet-port " + port + " --fleet-key " + open_key, open_key},
  };
  for (const auto& c : cases) {
    const auto run = icars_test::run_program(c.program, c.args, 60);
    EXPECT_EQ(run.exit_code, 2) << c.args << "\n" << run.output;
    EXPECT_NE(run.output.find(c.reason), std::string::npos) << c.args << "\n" << run.output;
    EXPECT_EQ(run.output.find("AddressSanitizer"), std::string::npos) << run.output;
  }
  // Options a parser refuses: not an address, no such key file.
  for (const auto& args : {"--house " + kHouse + " --fleet-port " + port + " --fleet-address 10.0.0.300",
                           "--house " + kHouse + " --fleet-port " + port + " --fleet-key " + (dir / "none.key").string()}) {
    const auto run = icars_test::run_program(kDeviceManager, args, 60);
    EXPECT_NE(run.exit_code, 0) << args;
    EXPECT_NE(run.output.find("--fleet-"), std::string::npos) << run.output;
  }
  if (!::testing::Test::HasFailure()) std::filesystem::remove_all(dir);
}

}  // namespace
