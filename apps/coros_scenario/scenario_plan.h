// icars-coros, planning: the scenario's options checked against the map and laid out as one
// agent configuration per process, before anything is written or started.
//
//   parse_deliveries, parse_kill   the command line's delivery list and kill rule
//   robot_starts                   where the robots start on the map
//   plan_scenario                  the options validated and turned into a ScenarioPlan: the
//                                  deliveries and one coros::AgentConfiguration per agent
//   default_agent_binary           the icars-agent to run when --agent-bin is not given
//
// Running the plan (the agent processes, kill rules, waiting, the events) is scenario.h's.
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "icars/coros/knowledge.h"
#include "icars/sim/house.h"
#include "icars/sim/planner.h"

namespace icars::coros_scenario {

// A command line or input the scenario cannot run with. main() prints it and exits with 2.
class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct Delivery {
  std::string pickup, dropoff;  // places of the map (office waypoints)
  friend bool operator==(const Delivery&, const Delivery&) = default;
};

// "office_101>office_112,office_104>office_109" (spaces around names are ignored).
std::vector<Delivery> parse_deliveries(std::string_view text);

// When to kill a robot (SIGKILL, a crash): at its own task_stage event with `stage`
// ("robot2@to_dropoff"), or `delay` of wall time after the run's first award ("robot2@3s",
// "robot2@500ms").
struct KillRule {
  std::string robot;
  std::string stage;  // "" for a delay
  std::chrono::milliseconds delay{0};
  std::string text() const;  // as written on the command line
};
KillRule parse_kill(std::string_view text);

struct ScenarioOptions {
  std::filesystem::path map;
  int robots = 5;
  std::vector<Delivery> deliveries;
  int random_deliveries = 0;
  std::uint64_t seed = 1;  // random deliveries and fault seeds
  double speedup = 20;     // simulated seconds per wall second
  std::optional<KillRule> kill;
  std::string faults;  // FaultInjection spec for every agent, "" for none
  std::filesystem::path svg, json;
  std::filesystem::path agent_bin;  // "" for default_agent_binary()
  std::filesystem::path keep_dir;   // "" for a temporary directory
  double timeout_s = 120;
  int delivery_interval_ms = 0;
  // How long the user waits for bids; 0: 400 ms, plus 25 ms per robot beyond 16 (every agent
  // process plans its bids on this one host's cores).
  int bid_window_ms = 0;
  int neighbor_expiry_ms = 1000;     // no HELLO for this long: the agent is gone
  std::uint16_t broadcast_port = 0;  // 0: a free one
  bool verbose = false;              // echo every agent event
  bool quiet = false;                // print nothing while running (run_agents() callers)
  // The dashboard's fleet page (docs/dashboard.md) on this host:port, "" for none; TLS with a
  // certificate and key (required off loopback); how long it stays after the summary (seconds,
  // negative: until SIGINT or SIGTERM).
  std::string http, http_tls_cert, http_tls_key;
  double http_linger_s = 0;
};

// One agent process to start: its configuration and where it writes.
struct AgentPlan {
  std::string id, role;  // role: robot or user (as in config)
  std::string start;     // robots: a waypoint name or "x,y" (as in config)
  sim::Point start_at;   // robots
  std::filesystem::path config_file, track_file, log_file;
  coros::AgentConfiguration config;  // config_file holds config.to_json()
};

struct ScenarioPlan {
  sim::House house;
  std::filesystem::path map;         // absolute
  std::vector<Delivery> deliveries;  // the given ones, then the random ones
  std::vector<AgentPlan> agents;     // robot1..robotN, then the user ("user")
  std::uint16_t broadcast_port = 0;
  std::filesystem::path dir;  // configurations, tracks and agent logs
};

inline constexpr double kRobotRadius = 0.25;
inline constexpr double kRobotSpeed = 0.5;
inline constexpr const char* kUserId = "user";

// Where robots start: the waypoints tagged "dock" in file order, then free points of the
// rooms named corridor_* (all rooms when there are none), each as far as possible from the
// starts chosen before, so a large fleet spreads along the corridors. `grid` is the house's
// grid for the robots' radius. Throws UsageError when the map has no free spot at all.
std::vector<std::pair<std::string, sim::Point>> robot_starts(const sim::House& house,
                                                             const sim::OccupancyGrid& grid,
                                                             std::size_t count);

// The user's bid window: options.bid_window_ms, or when 0, 400 ms plus 25 ms per robot beyond
// 16. An upper bound: the user's auction closes as soon as every robot it knows of has bid.
std::chrono::milliseconds bid_window(const ScenarioOptions& options);

// Validates the options against the map (places known, kill rule about an existing robot,
// faults well-formed) and lays out the agents' configurations in `dir`; writes nothing.
// Throws UsageError.
ScenarioPlan plan_scenario(const ScenarioOptions& options, const std::filesystem::path& dir,
                           std::uint16_t broadcast_port);

// The icars-agent binary when --agent-bin is not given: next to this executable, then in the
// build tree beside it (../icars_agent/icars-agent), then the path CMake built it at. Throws
// UsageError naming the places it looked.
std::filesystem::path default_agent_binary();

}  // namespace icars::coros_scenario
