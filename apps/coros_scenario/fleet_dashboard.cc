#include "fleet_dashboard.h"

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <stdexcept>

#include "icars/dashboard/views.h"

namespace icars::coros_scenario {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

double wall_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

std::string str(const json& j, const char* key) {
  const auto it = j.find(key);
  if (it == j.end()) return {};
  if (it->is_string()) return it->get<std::string>();
  if (it->is_object() && it->contains("name") && (*it)["name"].is_string()) return (*it)["name"];
  return it->dump();
}

double num(const json& j, const char* key) {
  const auto it = j.find(key);
  return it != j.end() && it->is_number() ? it->get<double>() : 0.0;
}

// A track's points come every 200 ms of simulated time: those closer than this to the last
// one kept are left out of the page's track.
constexpr double kTrackStep = 0.05;  // metres
constexpr double kPollPeriod = 0.15;  // seconds between looks at the track files

}  // namespace

std::string describe_event(const json& e) {
  const std::string kind = str(e, "event");
  const std::string task = str(e, "task");
  const std::string round = e.contains("round") ? str(e, "round") : "?";
  if (kind == "started") return fmt::format("started as {}", str(e, "role"));
  if (kind == "stopped") return "stopped";
  if (kind == "neighbor_joined") return fmt::format("{} joined ({} neighbours)", str(e, "neighbor"), str(e, "size"));
  if (kind == "neighbor_left") return fmt::format("{} left ({} neighbours)", str(e, "neighbor"), str(e, "size"));
  if (kind == "auction") {
    return fmt::format("auction {} round {}: {} > {}", task, round, str(e, "pickup"), str(e, "dropoff"));
  }
  if (kind == "bid") return fmt::format("bids {:.2f} m for {} round {}", num(e, "cost"), task, round);
  if (kind == "no_bid") return fmt::format("does not bid for {}: {}", task, str(e, "reason"));
  if (kind == "declined") {
    return fmt::format("{} round {}: {} declined: {}", task, round, str(e, "robot"), str(e, "reason"));
  }
  if (kind == "bid_received") {
    return fmt::format("{} round {}: {} bid {:.2f} m", task, round, str(e, "robot"), num(e, "cost"));
  }
  if (kind == "awarded") {
    return fmt::format("{} round {}: {} won at {:.2f} m", task, round, str(e, "robot"), num(e, "cost"));
  }
  if (kind == "assigned") return fmt::format("{} round {}: {} acknowledged", task, round, str(e, "robot"));
  if (kind == "task_stage") return fmt::format("{} round {}: {}", task, round, str(e, "stage"));
  if (kind == "reauction") return fmt::format("{} auctioned again (round {}): {}", task, round, str(e, "reason"));
  if (kind == "dropped") return fmt::format("dropped {} round {}: {}", task, round, str(e, "reason"));
  if (kind == "delivery_finished") {
    const bool ok = e.value("success", false);
    return fmt::format("{} {} by {}{}", task, ok ? "delivered" : "failed", str(e, "robot"),
                       ok ? "" : ": " + str(e, "detail"));
  }
  if (kind == "all_done") return fmt::format("all done: {} of {} delivered", str(e, "succeeded"), str(e, "deliveries"));
  return task.empty() ? kind : fmt::format("{} {}", kind, task);
}

FleetDashboard::FleetDashboard(const ScenarioPlan& plan, dashboard::DashboardOptions options,
                               double started_at)
    : plan_(plan), started_at_(started_at) {
  // A run's records are few (hundreds per robot): keep them all for a page that opens late.
  options.hub.history = std::max<std::size_t>(options.hub.history, 50000);
  const std::string listen = options.listen;
  try {
    dashboard::Views views;
    views.mode = "fleet";
    views.house = [&plan] { return dashboard::house_view(plan.house); };
    dashboard_ = std::make_unique<dashboard::Dashboard>(std::move(options), std::move(views));
  } catch (const std::invalid_argument& e) {
    throw UsageError(fmt::format("--http {}: {}", listen, e.what()));
  }
  for (const auto& a : plan.agents) {
    if (a.role == "robot") tails_[a.id].file = a.track_file;
  }
}

void FleetDashboard::start(const ScenarioOptions& options) {
  dashboard_->start();
  json robots = json::array();
  for (const auto& a : plan_.agents) {
    if (a.role == "robot") robots.push_back({{"id", a.id}, {"start", a.start}, {"x", a.start_at.x}, {"y", a.start_at.y}});
  }
  json deliveries = json::array();
  for (const auto& d : plan_.deliveries) deliveries.push_back({{"pickup", d.pickup}, {"dropoff", d.dropoff}});
  const auto text =
      fmt::format("{} robot{}, {} deliver{} on {}", robots.size(), robots.size() == 1 ? "" : "s", deliveries.size(),
                  deliveries.size() == 1 ? "y" : "ies", plan_.map.filename().string());
  note(text,
       {{"event", "plan"},
        {"robots", std::move(robots)},
        {"deliveries", std::move(deliveries)},
        {"kill", options.kill ? json(options.kill->text()) : json(nullptr)},
        {"speedup", options.speedup}});
}

std::string FleetDashboard::url() const { return dashboard_->url() + "fleet"; }

void FleetDashboard::publish(double wall, json record) {
  const double t = std::max(0.0, (wall - started_at_) * 1000.0);
  const auto ms = static_cast<long long>(std::llround(t));
  record["t"] = ms;
  record["time"] = fmt::format("{:02}:{:02}.{:03}", ms / 60000, (ms / 1000) % 60, ms % 1000);
  dashboard_->hub().publish_record(record.dump());
}

void FleetDashboard::agent_event(const std::string& agent, const json& event) {
  json record = {{"kind", "agent"}, {"source", agent}, {"text", describe_event(event)}};
  for (const auto& [key, value] : event.items()) {
    // The event's own wall time becomes the record's t; its agent is the source.
    if (key == "time" || key == "agent" || record.contains(key)) continue;
    record[key] = value;
  }
  const auto time = event.find("time");
  publish(time != event.end() && time->is_number() ? time->get<double>() : wall_now(), std::move(record));
}

void FleetDashboard::note(const std::string& text, json fields) {
  json record = {{"kind", "scenario"}, {"source", "icars-coros"}, {"text", text}};
  for (auto& [key, value] : fields.items()) {
    if (!record.contains(key)) record[key] = std::move(value);
  }
  publish(wall_now(), std::move(record));
}

void FleetDashboard::summary(bool success, const std::string& text, json report) {
  note(text, {{"event", "summary"}, {"success", success}, {"report", std::move(report)}});
}

void FleetDashboard::poll_tracks(bool force) {
  const double now = wall_now();
  if (now < next_poll_ && !force) return;
  next_poll_ = now + kPollPeriod;
  for (auto& [id, tail] : tails_) {
    std::error_code ec;
    const auto modified = fs::last_write_time(tail.file, ec);
    if (ec || modified == tail.seen) continue;
    std::ifstream in(tail.file);
    const json track = json::parse(in, nullptr, /*allow_exceptions=*/false);
    const auto points = track.is_object() ? track.find("points") : track.end();
    if (points == track.end() || !points->is_array()) continue;  // half written: next time
    tail.seen = modified;
    json path = json::array();
    for (std::size_t i = tail.points; i < points->size(); ++i) {
      const json& p = (*points)[i];
      if (!p.is_array() || p.size() < 3 || !p[1].is_number() || !p[2].is_number()) continue;
      const double x = p[1].get<double>(), y = p[2].get<double>();
      if (tail.any && std::hypot(x - tail.last_x, y - tail.last_y) < kTrackStep) continue;
      path.push_back({std::round(x * 1000) / 1000, std::round(y * 1000) / 1000});
      tail.last_x = x;
      tail.last_y = y;
      tail.any = true;
    }
    const bool moving = !path.empty() && tail.points > 0;
    tail.points = points->size();
    if (!tail.any) continue;
    publish(now, {{"kind", "robot"},
                  {"source", id},
                  {"text", fmt::format("{} at ({:.2f}, {:.2f}){}", id, tail.last_x, tail.last_y, moving ? " moving" : "")},
                  {"robot", id},
                  {"x", tail.last_x},
                  {"y", tail.last_y},
                  {"moving", moving},
                  {"distance", num(track, "distance")},
                  {"path", std::move(path)}});
  }
}

}  // namespace icars::coros_scenario
