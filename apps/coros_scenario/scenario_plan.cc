// icars-coros, planning (scenario_plan.h): the command line's deliveries and kill rule, the
// robots' starts, and the agents' configurations, built as coros::AgentConfiguration.
#include "scenario_plan.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <limits>
#include <random>

#include "icars/coros/transport.h"

namespace icars::coros_scenario {

namespace fs = std::filesystem;

namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

std::string format_point(sim::Point p) { return fmt::format("{:.2f},{:.2f}", p.x, p.y); }

// Mixes the run's seed, the faults' own seed and the agent's index into the agent's fault
// seed, so agents lose different datagrams and a run is repeatable.
std::uint64_t agent_fault_seed(std::uint64_t run_seed, std::uint64_t spec_seed, std::size_t i) {
  std::uint64_t x = run_seed * 0x9E3779B97F4A7C15ULL ^ (spec_seed + 0x632BE59BD9B4E019ULL);
  x ^= (static_cast<std::uint64_t>(i) + 1) * 0xBF58476D1CE4E5B9ULL;
  x ^= x >> 31;
  return x == 0 ? 1 : x;
}

}  // namespace

std::vector<Delivery> parse_deliveries(std::string_view text) {
  std::vector<Delivery> out;
  while (!text.empty()) {
    const auto comma = text.find(',');
    const std::string_view item = trim(text.substr(0, comma));
    text = comma == std::string_view::npos ? std::string_view() : text.substr(comma + 1);
    if (item.empty()) continue;
    const auto gt = item.find('>');
    const auto pickup = trim(item.substr(0, gt));
    const auto dropoff =
        gt == std::string_view::npos ? std::string_view() : trim(item.substr(gt + 1));
    if (gt == std::string_view::npos || pickup.empty() || dropoff.empty() ||
        dropoff.find('>') != std::string_view::npos) {
      throw UsageError(
          fmt::format("--deliveries: \"{}\" is not a delivery, expected PICKUP>DROPOFF, e.g. "
                      "office_101>office_112",
                      item));
    }
    if (pickup == dropoff) {
      throw UsageError(fmt::format(
          "--deliveries: \"{}\" picks up and drops off at the same place, expected two places",
          item));
    }
    out.push_back({std::string(pickup), std::string(dropoff)});
  }
  return out;
}

std::string KillRule::text() const {
  if (!stage.empty()) return robot + "@" + stage;
  if (delay.count() % 1000 == 0) return fmt::format("{}@{}s", robot, delay.count() / 1000);
  return fmt::format("{}@{}ms", robot, delay.count());
}

KillRule parse_kill(std::string_view text) {
  const auto usage = [&](const std::string& why) {
    return UsageError(
        fmt::format("--kill \"{}\": {}, expected ROBOT@STAGE (e.g. robot2@to_dropoff) "
                    "or ROBOT@DELAY after the first award (e.g. robot2@3s, "
                    "robot2@500ms)",
                    text, why));
  };
  const auto at = text.find('@');
  if (at == std::string_view::npos) throw usage("no '@'");
  KillRule rule;
  rule.robot = std::string(trim(text.substr(0, at)));
  const std::string_view when = trim(text.substr(at + 1));
  if (rule.robot.empty()) throw usage("no robot");
  if (when.empty()) throw usage("no stage or delay");
  if (when.front() >= '0' && when.front() <= '9') {
    double value = 0;
    const auto [end, error] = std::from_chars(when.data(), when.data() + when.size(), value);
    const std::string_view unit(end, static_cast<std::size_t>(when.data() + when.size() - end));
    if (error != std::errc() || !(value >= 0) || value > 86400 * 1000.0) throw usage("bad delay");
    double ms = 0;
    if (unit == "s") {
      ms = value * 1000.0;
    } else if (unit == "ms") {
      ms = value;
    } else {
      throw usage(fmt::format("unknown unit \"{}\"", unit));
    }
    rule.delay = std::chrono::milliseconds(static_cast<std::int64_t>(std::llround(ms)));
    return rule;
  }
  const auto stage = coros::parse_task_stage(when);
  if (!stage || *stage == coros::TaskStage::announced) {
    throw usage(
        fmt::format("unknown stage \"{}\" (stages: assigned, to_pickup, picked_up, "
                    "to_dropoff, delivered, failed)",
                    when));
  }
  rule.stage = std::string(when);
  return rule;
}

std::vector<std::pair<std::string, sim::Point>> robot_starts(const sim::House& house,
                                                             const sim::OccupancyGrid& grid,
                                                             std::size_t count) {
  const double radius = grid.inflate_radius();
  std::vector<std::pair<std::string, sim::Point>> starts;
  std::vector<sim::Point> taken;
  const auto docks = house.waypoints_tagged("dock");
  for (const auto* dock : docks) {
    if (!grid.free(dock->at)) {
      throw UsageError(
          fmt::format("dock \"{}\" at ({:g}, {:g}) of the map is too close to a "
                      "wall or furniture for a robot of radius {:g} m",
                      dock->name, dock->at.x, dock->at.y, radius));
    }
    taken.push_back(dock->at);
    if (starts.size() < count) starts.emplace_back(dock->name, dock->at);
  }
  if (starts.size() == count) return starts;

  // Candidates: a 0.5 m lattice over the corridors, free and joined to the first start.
  std::vector<const sim::Room*> areas;
  for (const auto& room : house.rooms) {
    if (room.name.rfind("corridor", 0) == 0) areas.push_back(&room);
  }
  if (areas.empty()) {
    for (const auto& room : house.rooms) areas.push_back(&room);
  }
  std::vector<sim::Point> candidates;
  constexpr double kStep = 0.5;
  for (const auto* room : areas) {
    for (double y = room->area.min.y + kStep / 2; y < room->area.max.y; y += kStep) {
      for (double x = room->area.min.x + kStep / 2; x < room->area.max.x; x += kStep) {
        const sim::Point p{x, y};
        if (!grid.free(p) || house.room_at(p) != room) continue;
        if (!taken.empty() && !grid.connected(taken.front(), p)) continue;
        candidates.push_back(p);
      }
    }
  }
  if (candidates.empty()) {
    throw UsageError(
        fmt::format("the map has {} dock{} and no free corridor spot for the other "
                    "robots, expected rooms named corridor_* with free floor",
                    docks.size(), docks.size() == 1 ? "" : "s"));
  }
  // Farthest-point order: each next start is as far as possible from those before it.
  std::vector<double> nearest(candidates.size(), std::numeric_limits<double>::infinity());
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    for (const auto& t : taken) nearest[i] = std::min(nearest[i], sim::distance(candidates[i], t));
  }
  while (starts.size() < count) {
    const auto best = static_cast<std::size_t>(std::max_element(nearest.begin(), nearest.end()) -
                                               nearest.begin());
    const sim::Point p = candidates[best];
    starts.emplace_back(format_point(p), p);
    for (std::size_t i = 0; i < candidates.size(); ++i) {
      nearest[i] = std::min(nearest[i], sim::distance(candidates[i], p));
    }
  }
  return starts;
}

std::chrono::milliseconds bid_window(const ScenarioOptions& options) {
  return std::chrono::milliseconds(options.bid_window_ms > 0
                                       ? options.bid_window_ms
                                       : 400 + 25 * std::max(0, options.robots - 16));
}

ScenarioPlan plan_scenario(const ScenarioOptions& options, const fs::path& dir,
                           std::uint16_t broadcast_port) {
  if (options.robots < 1 || options.robots > 500) {
    throw UsageError(fmt::format("--robots {}: expected 1 to 500 robots", options.robots));
  }
  if (!(options.speedup >= 0.1 && options.speedup <= 10000)) {
    throw UsageError(fmt::format("--speedup {:g}: expected 0.1 to 10000", options.speedup));
  }
  if (!(options.timeout_s > 0)) {
    throw UsageError(
        fmt::format("--timeout {:g}: expected a positive number of seconds", options.timeout_s));
  }
  if (options.random_deliveries < 0 || options.random_deliveries > 10000) {
    throw UsageError(
        fmt::format("--random-deliveries {}: expected 0 to 10000", options.random_deliveries));
  }
  if (options.delivery_interval_ms < 0) {
    throw UsageError("--delivery-interval: expected a number of milliseconds >= 0");
  }
  if (options.bid_window_ms < 0 || options.bid_window_ms > 600000) {
    throw UsageError(
        fmt::format("--bid-window {}: expected 0 (automatic) to 600000 ms", options.bid_window_ms));
  }
  if (options.neighbor_expiry_ms <= 200 || options.neighbor_expiry_ms > 3600000) {
    throw UsageError(
        fmt::format("--neighbor-expiry {}: expected more than the HELLO period "
                    "(200 ms), at most 3600000 ms",
                    options.neighbor_expiry_ms));
  }

  ScenarioPlan plan;
  plan.dir = dir;
  plan.broadcast_port = broadcast_port;
  std::error_code ec;
  plan.map = fs::absolute(options.map, ec);
  if (ec) plan.map = options.map;
  try {
    plan.house = sim::load_house(plan.map);
  } catch (const sim::HouseError& e) {
    throw UsageError(fmt::format("--map: {}", e.what()));
  }
  const auto& house = plan.house;

  const sim::OccupancyGrid grid(house, kRobotRadius);
  const auto starts = robot_starts(house, grid, static_cast<std::size_t>(options.robots));
  const sim::Point home = starts.front().second;

  // Deliveries: the given ones, then random pairs of offices.
  plan.deliveries = options.deliveries;
  if (options.random_deliveries > 0) {
    const auto offices = house.waypoints_tagged("office");
    if (offices.size() < 2) {
      throw UsageError(
          fmt::format("--random-deliveries needs at least two waypoints tagged "
                      "\"office\" in the map, {} has {}",
                      plan.map.string(), offices.size()));
    }
    std::mt19937_64 rng(options.seed);
    std::uniform_int_distribution<std::size_t> pick(0, offices.size() - 1);
    for (int i = 0; i < options.random_deliveries; ++i) {
      const std::size_t from = pick(rng);
      std::size_t to = pick(rng);
      while (to == from) to = pick(rng);
      plan.deliveries.push_back({offices[from]->name, offices[to]->name});
    }
  }
  if (plan.deliveries.empty()) {
    throw UsageError(
        "no deliveries: give --deliveries PICKUP>DROPOFF,... or --random-deliveries K");
  }
  for (const auto& d : plan.deliveries) {
    for (const auto& place : {d.pickup, d.dropoff}) {
      const auto at = house.locate(place);
      if (!at) {
        std::string offices;
        for (const auto* w : house.waypoints_tagged("office")) {
          offices += (offices.empty() ? "" : ", ") + w->name;
        }
        throw UsageError(
            fmt::format("--deliveries: unknown place \"{}\" on map {}, expected a "
                        "waypoint, furniture or room (offices: {})",
                        place, house.name, offices.empty() ? "none" : offices));
      }
      if (!grid.connected(home, *at)) {
        throw UsageError(
            fmt::format("--deliveries: place \"{}\" at ({:g}, {:g}) cannot be reached "
                        "by a robot of radius {:g} m from {}",
                        place, at->x, at->y, kRobotRadius, starts.front().first));
      }
    }
  }

  if (options.kill) {
    const auto& robot = options.kill->robot;
    bool known = false;
    for (int i = 1; i <= options.robots; ++i) known = known || robot == fmt::format("robot{}", i);
    if (!known) {
      throw UsageError(
          fmt::format("--kill {}: there is no robot \"{}\", expected robot1 to "
                      "robot{}",
                      options.kill->text(), robot, options.robots));
    }
  }
  std::optional<coros::FaultInjection> faults;
  if (!options.faults.empty()) {
    try {
      faults = coros::FaultInjection::parse(options.faults);
    } catch (const coros::CorosError& e) {
      throw UsageError(fmt::format("--faults \"{}\": {}", options.faults, e.what()));
    }
  }

  // One fleet key per run, in every agent's configuration: the agents sign and check every
  // datagram, and nothing else on the host can take part.
  const coros::FleetKey fleet_key = coros::FleetKey::generate();
  const auto base = [&](const std::string& id, const std::string& role, std::size_t index) {
    coros::AgentConfiguration c;
    c.id = id;
    c.role = role;
    c.transport.ip = "127.0.0.1";
    c.transport.port = 0;
    c.transport.broadcast_address = "127.255.255.255";
    c.transport.broadcast_port = broadcast_port;
    c.hello_period = std::chrono::milliseconds(200);
    c.neighbor_expiry = std::chrono::milliseconds(options.neighbor_expiry_ms);
    c.bid_window = bid_window(options);
    c.retry_period = std::chrono::milliseconds(100);
    c.max_retries = 20;
    c.map = plan.map;
    c.transport.key = fleet_key;
    if (faults) {
      c.transport.faults = *faults;
      c.transport.faults.seed = agent_fault_seed(options.seed, faults->seed, index);
    }
    return c;
  };
  for (std::size_t i = 0; i < starts.size(); ++i) {
    AgentPlan a;
    a.id = fmt::format("robot{}", i + 1);
    a.role = "robot";
    a.start = starts[i].first;
    a.start_at = starts[i].second;
    a.config_file = dir / (a.id + ".json");
    a.track_file = dir / (a.id + "-track.json");
    a.log_file = dir / (a.id + ".log");
    a.config = base(a.id, a.role, i);
    a.config.start = a.start;
    a.config.speed = kRobotSpeed;
    a.config.radius = kRobotRadius;
    a.config.speedup = options.speedup;
    a.config.robot_kind = "sim";
    a.config.track_file = a.track_file;
    // The robots share their distance fields (coros::FieldCache): on this one host each field
    // is computed once, not once per robot process.
    a.config.field_cache = dir / "fields";
    plan.agents.push_back(std::move(a));
  }
  AgentPlan user;
  user.id = kUserId;
  user.role = "user";
  user.config_file = dir / (user.id + ".json");
  user.log_file = dir / (user.id + ".log");
  user.config = base(user.id, user.role, starts.size());
  for (const auto& d : plan.deliveries) user.config.deliveries.emplace_back(d.pickup, d.dropoff);
  user.config.expect_robots = options.robots;
  user.config.start_after = std::chrono::milliseconds(10000);
  user.config.delivery_interval = std::chrono::milliseconds(options.delivery_interval_ms);
  user.config.exit_when_done = true;
  plan.agents.push_back(std::move(user));

  // The agents read what run_scenario() writes, config.to_json(), with the library's own
  // reader, which checks what building the configurations here does not: check it now.
  for (const auto& a : plan.agents) {
    try {
      coros::AgentConfiguration::parse(a.config.to_json().dump(), dir, a.config_file.string());
    } catch (const coros::CorosError& e) {
      throw std::logic_error(
          fmt::format("icars-coros wrote a configuration the agents reject: {}", e.what()));
    }
  }
  return plan;
}

fs::path default_agent_binary() {
  std::vector<fs::path> tried;
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    tried.push_back(self.parent_path() / "icars-agent");
    tried.push_back((self.parent_path() / ".." / "icars_agent" / "icars-agent").lexically_normal());
  }
#ifdef ICARS_AGENT_BINARY
  tried.emplace_back(ICARS_AGENT_BINARY);
#endif
  for (const auto& p : tried) {
    if (::access(p.c_str(), X_OK) == 0 && fs::is_regular_file(p, ec)) return p;
  }
  std::string where;
  for (const auto& p : tried) where += (where.empty() ? "" : ", ") + p.string();
  throw UsageError(
      fmt::format("cannot find icars-agent (looked at {}); build it (ninja "
                  "icars-agent) or give --agent-bin PATH",
                  where.empty() ? "nothing" : where));
}

}  // namespace icars::coros_scenario
