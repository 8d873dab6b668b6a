// What a courier scenario did, rebuilt from the agents' stdout events and the robots' track
// files: the auctions round by round, the deliveries, the robots, discovery convergence.
//
// ScenarioReport is fed events in the order each agent printed them (agents are read
// concurrently, so events of different agents interleave by arrival); every duration is
// computed from the events' own "time" stamps (wall seconds since the epoch), except the
// total wall time and the moments of kills, which the runner measures on the same clock.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "icars/sim/svg_plot.h"
#include "scenario.h"

namespace icars::coros_scenario {

struct RoundReport {
  int round = 1;
  std::map<std::string, double> bids;       // robot -> cost: those the round was decided on
  std::map<std::string, double> late_bids;  // received after the award
  std::string winner;                       // "" when nobody won the round
  double cost = 0;                          // the winner's bid
  bool assigned = false;                    // the winner acknowledged the award
  std::optional<double> auction_at, awarded_at, assigned_at;  // wall seconds
  std::vector<std::string> excluded;  // robots the user left out of this round
  std::string reauction_reason;       // why this round was auctioned again ("" if it was not)
  std::optional<double> completion_s() const;  // auction to assigned
};

struct DeliveryReport {
  Delivery delivery;
  std::string task;  // the user's task id; "" when it was never auctioned
  std::vector<RoundReport> rounds;
  bool finished = false;
  bool success = false;
  std::string robot;  // who finished it
  std::string detail;
  double distance = 0;    // metres the finishing robot drove for it
  double duration_s = 0;  // as the user reported it (the robot's simulated seconds)
  std::optional<double> auction_at, finished_at;        // wall seconds
  std::vector<std::pair<std::string, double>> pickups;  // robot, wall time of picked_up
  std::vector<std::string> history;                     // the user's own account, when it gives one

  RoundReport& round(int number);  // created when missing, rounds kept in order
};

struct RobotReport {
  std::string id;
  std::string start;  // waypoint name or "x,y"
  sim::Point start_at;
  std::optional<double> started_at, stopped_at;  // wall seconds of its events
  std::size_t neighbors = 0;                     // the last "size" it reported
  std::size_t max_neighbors = 0;
  std::vector<std::string> stages;   // "task1#1 to_pickup", in order
  std::vector<std::string> dropped;  // "task1#1: reason"
  bool killed = false;
  double killed_at = 0;
  std::string kill_reason;
  std::optional<int> exit_status;  // raw wait status
  bool track_found = false;
  double distance = 0;                               // from its track file
  std::vector<std::pair<double, sim::Point>> track;  // simulated time (s since day 0), position
  // Where its stage events last put it (a pickup or dropoff place) and when (wall seconds):
  // where a killed robot was when its track file is older than the kill.
  std::optional<std::pair<double, sim::Point>> last_seen;
};

class ScenarioReport {
 public:
  // `started_at`: the run's start (wall seconds); the report's times are relative to it.
  ScenarioReport(const ScenarioPlan& plan, const ScenarioOptions& options, double started_at);

  // One event line of an agent, already parsed. Returns a one-line description of what it
  // meant for the run ("task1 round 1: robot3 won ...") when worth printing, else "".
  std::string on_event(const nlohmann::json& event);

  void robot_killed(const std::string& id, double at, const std::string& why);
  void agent_exited(const std::string& id, int wait_status);
  // Reads a robot's track file; false when it is missing or unreadable (noted in the report).
  bool load_track(const std::string& id, const std::filesystem::path& file);
  void finish(double wall_time_s, bool timed_out, bool interrupted, std::string problem = "");

  bool all_done() const { return all_done_; }
  std::optional<double> first_award_at() const { return first_award_at_; }
  bool succeeded() const;  // every requested delivery delivered
  const std::vector<DeliveryReport>& deliveries() const { return deliveries_; }
  const std::map<std::string, RobotReport>& robots() const { return robots_; }

  nlohmann::json to_json() const;
  std::string to_text() const;
  sim::PlotData plot() const;  // tracks and marks for sim::render_svg

 private:
  DeliveryReport& delivery_of(const std::string& task, const std::string& pickup,
                              const std::string& dropoff);
  DeliveryReport* find_task(const std::string& task);
  void check_convergence(double now);
  double sim_seconds(const RobotReport& robot, double wall) const;

  std::string map_name_, map_file_, faults_, kill_;
  double speedup_ = 1;
  double started_at_ = 0;
  double house_start_s_ = 0;              // simulated time of day the robots' clocks start at
  std::vector<std::string> robot_order_;  // robot1..robotN
  std::size_t robot_count_ = 0;
  std::vector<DeliveryReport> deliveries_;  // requested order
  std::map<std::string, RobotReport> robots_;
  std::map<std::string, sim::Point> places_;  // pickup and dropoff positions
  std::optional<double> last_robot_start() const;

  std::optional<double> last_start_, user_started_at_, converged_at_, first_award_at_;
  std::optional<double> all_done_at_;
  bool all_done_ = false;
  int user_deliveries_ = -1, user_succeeded_ = -1;  // from all_done
  double wall_time_s_ = 0;
  bool timed_out_ = false, interrupted_ = false;
  std::string problem_;
  std::uint64_t events_ = 0;
};

}  // namespace icars::coros_scenario
