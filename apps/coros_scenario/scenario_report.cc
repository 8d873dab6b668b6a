#include "scenario_report.h"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>

#include "agent_process.h"

namespace icars::coros_scenario {

using nlohmann::json;

namespace {

std::string str(const json& j, const char* key) {
  const auto it = j.find(key);
  return it != j.end() && it->is_string() ? it->get<std::string>() : std::string();
}

double num(const json& j, const char* key, double otherwise = 0) {
  const auto it = j.find(key);
  return it != j.end() && it->is_number() ? it->get<double>() : otherwise;
}

int integer(const json& j, const char* key, int otherwise) {
  const auto it = j.find(key);
  return it != j.end() && it->is_number() ? static_cast<int>(std::lround(it->get<double>()))
                                          : otherwise;
}

bool boolean(const json& j, const char* key) {
  const auto it = j.find(key);
  return it != j.end() && it->is_boolean() && it->get<bool>();
}

// A place in an event: its name, whether the agent printed a name or a {name, x, y} object.
std::string place_name(const json& j, const char* key) {
  const auto it = j.find(key);
  if (it == j.end()) return {};
  if (it->is_string()) return it->get<std::string>();
  if (it->is_object()) return str(*it, "name");
  return {};
}

// "robot3 12.3, robot1 13.0, ..." lowest first, at most `limit` of them.
std::string bids_text(const std::map<std::string, double>& bids, std::size_t limit) {
  std::vector<std::pair<std::string, double>> sorted(bids.begin(), bids.end());
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const auto& a, const auto& b) { return a.second < b.second; });
  std::string out;
  for (std::size_t i = 0; i < sorted.size() && i < limit; ++i) {
    out += fmt::format("{}{} {:.1f}", i == 0 ? "" : ", ", sorted[i].first, sorted[i].second);
  }
  if (sorted.size() > limit) out += fmt::format(", ... ({} more)", sorted.size() - limit);
  return out.empty() ? "none" : out;
}

json optional_number(const std::optional<double>& v) { return v ? json(*v) : json(nullptr); }

}  // namespace

std::optional<double> RoundReport::completion_s() const {
  if (!auction_at || !assigned_at) return std::nullopt;
  return *assigned_at - *auction_at;
}

RoundReport& DeliveryReport::round(int number) {
  for (auto& r : rounds) {
    if (r.round == number) return r;
  }
  const auto at = std::find_if(rounds.begin(), rounds.end(),
                               [&](const RoundReport& r) { return r.round > number; });
  RoundReport fresh;
  fresh.round = number;
  return *rounds.insert(at, fresh);
}

ScenarioReport::ScenarioReport(const ScenarioPlan& plan, const ScenarioOptions& options,
                               double started_at)
    : map_name_(plan.house.name),
      map_file_(plan.map.string()),
      faults_(options.faults),
      kill_(options.kill ? options.kill->text() : ""),
      speedup_(options.speedup),
      started_at_(started_at),
      house_start_s_(std::chrono::duration<double>(plan.house.start_time).count()) {
  for (const auto& a : plan.agents) {
    if (a.role != "robot") continue;
    RobotReport r;
    r.id = a.id;
    r.start = a.start;
    r.start_at = a.start_at;
    robots_.emplace(a.id, r);
    robot_order_.push_back(a.id);
  }
  robot_count_ = robot_order_.size();
  for (const auto& d : plan.deliveries) {
    DeliveryReport report;
    report.delivery = d;
    deliveries_.push_back(report);
    for (const auto& name : {d.pickup, d.dropoff}) {
      if (auto p = plan.house.locate(name)) places_[name] = *p;
    }
  }
}

DeliveryReport* ScenarioReport::find_task(const std::string& task) {
  for (auto& d : deliveries_) {
    if (d.task == task) return &d;
  }
  return nullptr;
}

DeliveryReport& ScenarioReport::delivery_of(const std::string& task, const std::string& pickup,
                                            const std::string& dropoff) {
  if (auto* d = find_task(task)) return *d;
  for (auto& d : deliveries_) {  // the first requested one it can be
    if (d.task.empty() && d.delivery.pickup == pickup && d.delivery.dropoff == dropoff) {
      d.task = task;
      return d;
    }
  }
  DeliveryReport unexpected;  // the user auctioned something not asked for: show it anyway
  unexpected.task = task;
  unexpected.delivery = {pickup, dropoff};
  deliveries_.push_back(unexpected);
  return deliveries_.back();
}

std::optional<double> ScenarioReport::last_robot_start() const {
  std::optional<double> last;
  for (const auto& [id, r] : robots_) {
    if (r.started_at) last = std::max(last.value_or(*r.started_at), *r.started_at);
  }
  return last;
}

void ScenarioReport::check_convergence(double now) {
  if (converged_at_ || robot_count_ == 0 || !user_started_at_) return;
  for (const auto& [id, r] : robots_) {
    if (!r.started_at || r.neighbors < robot_count_) return;  // N others: N-1 robots + user
  }
  converged_at_ = now;
}

double ScenarioReport::sim_seconds(const RobotReport& robot, double wall) const {
  // A robot's simulated clock starts with it, at its track's first time (the house's start).
  const double base = robot.track.empty() ? house_start_s_ : robot.track.front().first;
  const double start = robot.started_at.value_or(started_at_);
  return base + std::max(0.0, (wall - start) * speedup_);
}

std::string ScenarioReport::on_event(const json& event) {
  ++events_;
  const std::string kind = str(event, "event");
  const std::string agent = str(event, "agent");
  const double t = num(event, "time", 0);
  const std::string task = str(event, "task");
  const int round_number = integer(event, "round", 1);
  const auto robot_it = robots_.find(agent);
  RobotReport* robot = robot_it == robots_.end() ? nullptr : &robot_it->second;

  if (kind == "started") {
    // Discovery is timed from the last agent's start: the user starts after the robots.
    if (robot || agent == kUserId) last_start_ = std::max(last_start_.value_or(t), t);
    if (robot) robot->started_at = t;
    if (agent == kUserId) user_started_at_ = t;
    check_convergence(t);
    return {};
  }
  if (kind == "neighbor_joined" || kind == "neighbor_left") {
    if (!robot) return {};
    robot->neighbors = static_cast<std::size_t>(std::max(0, integer(event, "size", 0)));
    robot->max_neighbors = std::max(robot->max_neighbors, robot->neighbors);
    const bool was = converged_at_.has_value();
    check_convergence(t);
    if (!was && converged_at_) {
      return fmt::format(
          "discovery converged: every robot has {} neighbours, {:.3f} s after "
          "the last agent started",
          robot_count_, *converged_at_ - last_start_.value_or(t));
    }
    return {};
  }
  if (kind == "stopped") {
    if (robot) robot->stopped_at = t;
    return {};
  }

  // The user's auction events.
  if (kind == "auction") {
    auto& d = delivery_of(task, place_name(event, "pickup"), place_name(event, "dropoff"));
    auto& r = d.round(round_number);
    if (!r.auction_at) r.auction_at = t;
    if (!d.auction_at) d.auction_at = t;
    if (const auto ex = event.find("exclude"); ex != event.end() && ex->is_array()) {
      for (const auto& id : *ex) {
        if (id.is_string()) r.excluded.push_back(id.get<std::string>());
      }
    }
    return fmt::format("{} round {}: auction {} > {}", task, round_number, d.delivery.pickup,
                       d.delivery.dropoff);
  }
  if (kind == "bid_received") {
    if (auto* d = find_task(task)) {
      auto& r = d->round(round_number);
      (r.awarded_at ? r.late_bids : r.bids)[str(event, "robot")] = num(event, "cost");
    }
    return {};
  }
  if (kind == "awarded") {
    auto* d = find_task(task);
    if (!d) return {};
    auto& r = d->round(round_number);
    r.winner = str(event, "robot");
    r.cost = num(event, "cost");
    r.awarded_at = t;
    if (const auto b = event.find("bids"); b != event.end() && b->is_object()) {
      r.bids.clear();  // the bids the auctioneer decided on
      for (const auto& [id, cost] : b->items()) {
        if (cost.is_number()) r.bids[id] = cost.get<double>();
      }
    }
    if (!first_award_at_) first_award_at_ = t;
    return fmt::format("{} round {}: {} won with {:.1f} m ({} bid{}: {})", task, round_number,
                       r.winner, r.cost, r.bids.size(), r.bids.size() == 1 ? "" : "s",
                       bids_text(r.bids, 5));
  }
  if (kind == "assigned") {
    auto* d = find_task(task);
    if (!d) return {};
    auto& r = d->round(round_number);
    r.assigned = true;
    r.assigned_at = t;
    if (r.winner.empty()) r.winner = str(event, "robot");
    const auto took = r.completion_s();
    return fmt::format("{} round {}: assigned to {}{}", task, round_number, r.winner,
                       took ? fmt::format(" ({:.2f} s after the auction)", *took) : "");
  }
  if (kind == "reauction") {
    auto* d = find_task(task);
    if (!d) return {};
    const std::string reason = str(event, "reason");
    // The reason belongs to the round that failed: the newest one heard of so far (the new
    // round's auction event comes after this one).
    if (!d->rounds.empty()) d->rounds.back().reauction_reason = reason;
    return fmt::format("{}: auctioned again (round {}): {}", task, round_number, reason);
  }
  if (kind == "delivery_finished") {
    auto* d = find_task(task);
    if (!d) return {};
    d->finished = true;
    d->success = boolean(event, "success");
    d->robot = str(event, "robot");
    d->distance = num(event, "distance");
    d->duration_s = num(event, "duration_s");
    d->detail = str(event, "detail");
    d->finished_at = t;
    if (const auto h = event.find("history"); h != event.end() && h->is_array()) {
      d->history.clear();
      for (const auto& item : *h) {
        if (item.is_string()) d->history.push_back(item.get<std::string>());
      }
    }
    if (d->success) {
      return fmt::format("{}: delivered by {}: {:.1f} m driven, {:.1f} s simulated", task, d->robot,
                         d->distance, d->duration_s);
    }
    return fmt::format("{}: FAILED{}{}", task, d->robot.empty() ? "" : " with " + d->robot,
                       d->detail.empty() ? "" : ": " + d->detail);
  }
  if (kind == "all_done") {
    all_done_ = true;
    all_done_at_ = t;
    user_deliveries_ = integer(event, "deliveries", -1);
    user_succeeded_ = integer(event, "succeeded", -1);
    return fmt::format("the user is done: {} of {} deliveries succeeded", user_succeeded_,
                       user_deliveries_);
  }

  // The robots' own events.
  if (kind == "task_stage" && robot) {
    const std::string stage = str(event, "stage");
    robot->stages.push_back(fmt::format("{}#{} {}", task, round_number, stage));
    auto* d = find_task(task);
    if (d && (stage == "picked_up" || stage == "delivered")) {
      const auto place =
          places_.find(stage == "picked_up" ? d->delivery.pickup : d->delivery.dropoff);
      if (place != places_.end()) robot->last_seen = std::pair{t, place->second};
    }
    if (stage == "picked_up") {
      if (d) d->pickups.emplace_back(agent, t);
      return fmt::format("{} picked up {} (round {})", agent, task, round_number);
    }
    if (stage == "failed")
      return fmt::format("{}: {} failed (round {})", agent, task, round_number);
    return {};
  }
  if (kind == "dropped" && robot) {
    const std::string reason = str(event, "reason");
    robot->dropped.push_back(fmt::format("{}#{}: {}", task, round_number, reason));
    return fmt::format("{} dropped {} round {}: {}", agent, task, round_number, reason);
  }
  return {};
}

void ScenarioReport::robot_killed(const std::string& id, double at, const std::string& why) {
  auto it = robots_.find(id);
  if (it == robots_.end()) return;
  it->second.killed = true;
  it->second.killed_at = at;
  it->second.kill_reason = why;
}

void ScenarioReport::agent_exited(const std::string& id, int wait_status) {
  if (auto it = robots_.find(id); it != robots_.end()) it->second.exit_status = wait_status;
}

bool ScenarioReport::load_track(const std::string& id, const std::filesystem::path& file) {
  auto it = robots_.find(id);
  if (it == robots_.end()) return false;
  auto& robot = it->second;
  std::ifstream in(file);
  if (!in) return false;
  const json track = json::parse(in, nullptr, /*allow_exceptions=*/false);
  if (!track.is_object()) return false;
  robot.track_found = true;
  robot.distance = num(track, "distance");
  robot.track.clear();
  if (const auto points = track.find("points"); points != track.end() && points->is_array()) {
    for (const auto& p : *points) {
      if (!p.is_array() || p.size() < 3 || !p[0].is_number() || !p[1].is_number() ||
          !p[2].is_number()) {
        continue;
      }
      robot.track.emplace_back(p[0].get<double>(),
                               sim::Point{p[1].get<double>(), p[2].get<double>()});
    }
  }
  return true;
}

void ScenarioReport::finish(double wall_time_s, bool timed_out, bool interrupted,
                            std::string problem) {
  wall_time_s_ = wall_time_s;
  timed_out_ = timed_out;
  interrupted_ = interrupted;
  problem_ = std::move(problem);
}

bool ScenarioReport::succeeded() const {
  if (deliveries_.empty()) return false;
  return std::all_of(deliveries_.begin(), deliveries_.end(),
                     [](const DeliveryReport& d) { return d.finished && d.success; });
}

json ScenarioReport::to_json() const {
  const auto rel = [&](const std::optional<double>& t) {
    return t ? json(*t - started_at_) : json(nullptr);
  };
  json out;
  out["map"] = map_file_;
  out["house"] = map_name_;
  out["robot_count"] = robot_count_;
  out["speedup"] = speedup_;
  out["faults"] = faults_.empty() ? json(nullptr) : json(faults_);
  out["kill"] = kill_.empty() ? json(nullptr) : json(kill_);
  out["success"] = succeeded();
  out["deliveries_requested"] = deliveries_.size();
  out["deliveries_succeeded"] =
      std::count_if(deliveries_.begin(), deliveries_.end(),
                    [](const DeliveryReport& d) { return d.finished && d.success; });
  out["all_done"] = all_done_;
  out["timed_out"] = timed_out_;
  out["interrupted"] = interrupted_;
  out["problem"] = problem_;
  out["wall_time_s"] = wall_time_s_;
  out["events"] = events_;

  json discovery;
  discovery["expected_neighbors"] = robot_count_;
  discovery["last_robot_start_s"] = rel(last_robot_start());
  discovery["user_start_s"] = rel(user_started_at_);
  discovery["last_agent_start_s"] = rel(last_start_);
  discovery["converged_at_s"] = rel(converged_at_);
  discovery["convergence_s"] =
      converged_at_ && last_start_ ? json(*converged_at_ - *last_start_) : json(nullptr);
  out["discovery"] = discovery;

  json auctions = json::array();
  double sum = 0, max = 0;
  std::size_t timed = 0;
  json deliveries = json::array();
  for (const auto& d : deliveries_) {
    json dj;
    dj["task"] = d.task.empty() ? json(nullptr) : json(d.task);
    dj["pickup"] = d.delivery.pickup;
    dj["dropoff"] = d.delivery.dropoff;
    dj["finished"] = d.finished;
    dj["success"] = d.finished && d.success;
    dj["robot"] = d.robot.empty() ? json(nullptr) : json(d.robot);
    dj["distance"] = d.distance;
    dj["duration_s"] = d.duration_s;
    dj["wall_duration_s"] =
        d.auction_at && d.finished_at ? json(*d.finished_at - *d.auction_at) : json(nullptr);
    dj["detail"] = d.detail;
    json rounds = json::array();
    json reauctions = json::array();
    for (const auto& r : d.rounds) {
      json rj;
      rj["round"] = r.round;
      rj["bids"] = json::object();
      for (const auto& [id, cost] : r.bids) rj["bids"][id] = cost;
      rj["late_bids"] = json::object();
      for (const auto& [id, cost] : r.late_bids) rj["late_bids"][id] = cost;
      rj["winner"] = r.winner.empty() ? json(nullptr) : json(r.winner);
      rj["cost"] = r.winner.empty() ? json(nullptr) : json(r.cost);
      rj["assigned"] = r.assigned;
      rj["excluded"] = r.excluded;
      rj["auction_at_s"] = rel(r.auction_at);
      rj["assigned_at_s"] = rel(r.assigned_at);
      rj["completion_s"] = optional_number(r.completion_s());
      rj["reauction_reason"] =
          r.reauction_reason.empty() ? json(nullptr) : json(r.reauction_reason);
      if (!r.reauction_reason.empty()) {
        reauctions.push_back({{"after_round", r.round}, {"reason", r.reauction_reason}});
      }
      if (const auto c = r.completion_s()) {
        auctions.push_back({{"task", d.task}, {"round", r.round}, {"completion_s", *c}});
        sum += *c;
        max = std::max(max, *c);
        ++timed;
      }
      rounds.push_back(rj);
    }
    dj["history"] = d.history;
    dj["rounds"] = rounds;
    dj["reauctions"] = reauctions;
    deliveries.push_back(dj);
  }
  out["deliveries"] = deliveries;
  out["auctions"] = auctions;
  out["auction_completion_mean_s"] = timed ? json(sum / static_cast<double>(timed)) : json(nullptr);
  out["auction_completion_max_s"] = timed ? json(max) : json(nullptr);

  json robots = json::array();
  for (const auto& id : robot_order_) {
    const auto& r = robots_.at(id);
    json rj;
    rj["id"] = r.id;
    rj["start"] = r.start;
    rj["start_x"] = r.start_at.x;
    rj["start_y"] = r.start_at.y;
    rj["distance"] = r.track_found ? json(r.distance) : json(nullptr);
    rj["track_points"] = r.track.size();
    rj["max_neighbors"] = r.max_neighbors;
    rj["started_at_s"] = rel(r.started_at);
    rj["killed"] = r.killed;
    rj["killed_at_s"] = r.killed ? json(r.killed_at - started_at_) : json(nullptr);
    rj["kill_reason"] = r.killed ? json(r.kill_reason) : json(nullptr);
    rj["stages"] = r.stages;
    rj["dropped"] = r.dropped;
    rj["exit"] = r.exit_status ? json(describe_wait_status(*r.exit_status)) : json(nullptr);
    robots.push_back(rj);
  }
  out["robots"] = robots;
  return out;
}

std::string ScenarioReport::to_text() const {
  std::string out;
  const auto line = [&](const std::string& s) { out += s + "\n"; };
  const auto succeeded_count =
      std::count_if(deliveries_.begin(), deliveries_.end(),
                    [](const DeliveryReport& d) { return d.finished && d.success; });
  line(fmt::format("Courier delivery on {}: {} robot{}, {} deliver{}, speedup {:g}{}{}", map_name_,
                   robot_count_, robot_count_ == 1 ? "" : "s", deliveries_.size(),
                   deliveries_.size() == 1 ? "y" : "ies", speedup_,
                   faults_.empty() ? "" : ", faults " + faults_,
                   kill_.empty() ? "" : ", kill " + kill_));
  if (converged_at_ && last_start_) {
    line(
        fmt::format("Discovery: every robot had {} neighbours {:.3f} s after the last agent "
                    "started (the user, {:.2f} s after the last robot)",
                    robot_count_, *converged_at_ - *last_start_,
                    user_started_at_.value_or(0) - last_robot_start().value_or(0)));
  } else {
    line(fmt::format("Discovery: did not converge (not every robot saw {} neighbours)",
                     robot_count_));
  }
  for (const auto& d : deliveries_) {
    const std::string name = d.task.empty() ? "(not auctioned)" : d.task;
    std::string outcome;
    if (d.finished && d.success) {
      outcome = fmt::format("delivered by {}, {:.1f} m driven, {:.1f} s simulated", d.robot,
                            d.distance, d.duration_s);
      if (d.auction_at && d.finished_at) {
        outcome += fmt::format(" ({:.1f} s wall)", *d.finished_at - *d.auction_at);
      }
    } else if (d.finished) {
      outcome = "FAILED" + (d.detail.empty() ? "" : ": " + d.detail);
    } else {
      outcome = "NOT FINISHED";
    }
    line(fmt::format("Delivery {}: {} > {}: {}", name, d.delivery.pickup, d.delivery.dropoff,
                     outcome));
    for (const auto& r : d.rounds) {
      std::string won = r.winner.empty() ? "nobody won"
                                         : fmt::format("{} won ({:.1f} m){}", r.winner, r.cost,
                                                       r.assigned ? "" : ", never assigned");
      if (const auto c = r.completion_s()) won += fmt::format(", assigned after {:.2f} s", *c);
      line(fmt::format("  round {}: bids {} -> {}", r.round, bids_text(r.bids, 10), won));
      if (!r.reauction_reason.empty()) {
        line(fmt::format("  auctioned again after round {}: {}", r.round, r.reauction_reason));
      }
    }
  }
  line("Robots:");
  for (const auto& id : robot_order_) {
    const auto& r = robots_.at(id);
    std::string s = fmt::format(
        "  {:<8} start {:<11} driven {}", r.id, r.start,
        r.track_found ? fmt::format("{:.1f} m", r.distance) : std::string("? (no track file)"));
    if (r.killed) {
      s += fmt::format(", killed at {:.1f} s ({})", r.killed_at - started_at_, r.kill_reason);
    }
    for (const auto& why : r.dropped) s += ", dropped " + why;
    line(s);
  }
  double sum = 0, max = 0;
  std::size_t timed = 0;
  for (const auto& d : deliveries_) {
    for (const auto& r : d.rounds) {
      if (const auto c = r.completion_s()) {
        sum += *c;
        max = std::max(max, *c);
        ++timed;
      }
    }
  }
  if (timed > 0) {
    line(
        fmt::format("Auctions: {} round{} completed, auction to assignment {:.2f} s on average, "
                    "{:.2f} s at most",
                    timed, timed == 1 ? "" : "s", sum / static_cast<double>(timed), max));
  }
  line(fmt::format("Wall time: {:.1f} s{}{}", wall_time_s_, timed_out_ ? " (timed out)" : "",
                   interrupted_ ? " (interrupted)" : ""));
  if (!problem_.empty()) line("Problem: " + problem_);
  line(fmt::format("Result: {} of {} deliveries succeeded", succeeded_count, deliveries_.size()));
  return out;
}

sim::PlotData ScenarioReport::plot() const {
  const auto to_time = [](double seconds) {
    return Time(static_cast<Time::rep>(std::llround(std::max(0.0, seconds) * 1000.0)));
  };
  sim::PlotData data;
  data.title = fmt::format("COROS courier delivery: {} robots, {} deliveries", robot_count_,
                           deliveries_.size());
  for (const auto& id : robot_order_) {
    const auto& r = robots_.at(id);
    sim::PlotTrack track;
    track.name = r.id;
    for (const auto& [t, p] : r.track) track.points.emplace_back(to_time(t), p);
    if (track.points.empty()) track.points.emplace_back(Time(0), r.start_at);
    data.robots.push_back(std::move(track));
  }
  const auto robot_time = [&](const std::string& id, std::optional<double> wall) {
    const auto it = robots_.find(id);
    if (it == robots_.end() || !wall) return Time(0);
    return to_time(sim_seconds(it->second, *wall));
  };
  for (const auto& d : deliveries_) {
    const std::string name = d.task.empty() ? d.delivery.pickup : d.task;
    if (const auto p = places_.find(d.delivery.pickup); p != places_.end()) {
      sim::PlotMark m;
      m.at = p->second;
      if (d.pickups.empty()) {
        m.label = fmt::format("{} pickup", name);
      } else {
        m.label = fmt::format("{} picked up by {}", name, d.pickups.back().first);
        m.time = robot_time(d.pickups.back().first, d.pickups.back().second);
      }
      data.marks.push_back(m);
    }
    if (const auto p = places_.find(d.delivery.dropoff); p != places_.end()) {
      sim::PlotMark m;
      m.at = p->second;
      if (d.finished && d.success) {
        m.label = fmt::format("{} delivered by {}", name, d.robot);
      } else {
        m.label = fmt::format("{} dropoff{}", name, d.finished ? " (failed)" : "");
      }
      if (d.finished) m.time = robot_time(d.robot, d.finished_at);
      data.marks.push_back(m);
    }
  }
  for (const auto& id : robot_order_) {
    const auto& r = robots_.at(id);
    if (!r.killed) continue;
    sim::PlotMark m;
    m.label = fmt::format("{} killed", r.id);
    const double at = sim_seconds(r, r.killed_at);
    m.time = to_time(at);
    // Where it was last seen before the kill: its track, or a later stage event's place.
    m.at = r.start_at;
    double seen = -1;
    for (const auto& [t, p] : r.track) {
      if (t > at) break;
      m.at = p;
      seen = t;
    }
    if (r.last_seen && r.last_seen->first <= r.killed_at &&
        sim_seconds(r, r.last_seen->first) > seen) {
      m.at = r.last_seen->second;
    }
    data.marks.push_back(m);
  }
  // Marks at the same place (a pickup office where a robot was killed) are stacked downwards
  // so their labels do not cover each other.
  std::vector<sim::Point> places;
  for (const auto& m : data.marks) places.push_back(m.at);
  for (std::size_t i = 0; i < data.marks.size(); ++i) {
    int same = 0;
    for (std::size_t j = 0; j < i; ++j) {
      if (sim::distance(places[j], places[i]) < 0.05) ++same;
    }
    data.marks[i].at.y -= 0.4 * same;
  }
  return data;
}

}  // namespace icars::coros_scenario
