// icars-coros --http: the run on the dashboard's fleet page (docs/dashboard.md, "The fleet
// page"). Every agent event the runner reads, the runner's own notes (kills, the summary) and
// the robots' positions from their track files become dashboard records, which the page folds
// into the office floor with the robots' tracks, the neighbour tables, the auctions round by
// round and the deliveries' outcome.
//
//   FleetDashboard fleet(plan, {.listen = "127.0.0.1:0"}, started_at);
//   fleet.start();                       // prints nothing; url() is http://127.0.0.1:PORT/fleet
//   fleet.agent_event("robot1", event);  // for each event line, as it is read
//   fleet.poll_tracks();                 // often: reads a track file only when it changed
//
// Records have the trace's shape (docs/trace.md): {"t": ms of wall time since the run started,
// "time": "mm:ss.mmm", "kind", "source", "text", ...}. Kinds: `agent` (an agent's event, its
// own fields kept), `robot` (a position), `scenario` (the plan, a kill, a note, the summary).
// Not thread-safe: the runner's thread calls it; the dashboard serves on threads of its own and
// never blocks the caller.
#pragma once

#include <filesystem>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "icars/dashboard/dashboard.h"
#include "scenario_plan.h"

namespace icars::coros_scenario {

class FleetDashboard {
 public:
  // Throws UsageError for a listen address the dashboard refuses (not loopback without TLS).
  FleetDashboard(const ScenarioPlan& plan, dashboard::DashboardOptions options, double started_at);

  // Binds and serves; publishes the plan (robots, their starts, the deliveries, the kill rule).
  // Throws std::runtime_error when the address cannot be bound.
  void start(const ScenarioOptions& options);
  std::string url() const;  // http://host:port/fleet

  void agent_event(const std::string& agent, const nlohmann::json& event);
  // What the runner says (a kill, a timeout); `fields` are added to the record.
  void note(const std::string& text, nlohmann::json fields = nlohmann::json::object());
  // Reads the robots' track files that changed since the last call and publishes each robot's
  // new position with the points it drove since (a robot writes its file every 2 s). Looks at
  // the files at most every 150 ms unless `now`.
  void poll_tracks(bool now = false);
  // The run's end: the report's JSON (ScenarioReport::to_json()) as the record's `report`.
  void summary(bool success, const std::string& text, nlohmann::json report);

 private:
  void publish(double wall, nlohmann::json record);

  struct Tail {
    std::filesystem::path file;
    std::filesystem::file_time_type seen{};
    std::size_t points = 0;  // points already published
    double last_x = 0, last_y = 0;
    bool any = false;
  };

  const ScenarioPlan& plan_;
  double started_at_;
  std::unique_ptr<dashboard::Dashboard> dashboard_;
  std::map<std::string, Tail> tails_;  // robot id -> its track file
  double next_poll_ = 0;               // wall seconds
};

// A readable line for an agent's event: "auction task1 round 1: office_101 > office_112".
std::string describe_event(const nlohmann::json& event);

}  // namespace icars::coros_scenario
