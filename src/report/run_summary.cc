#include "icars/report/run_summary.h"

#include <fmt/format.h>

#include <cmath>

namespace icars::report {

RunSummary::RunSummary(bool keep_plot) : keep_plot_(keep_plot) {}

behavior::Trace::Sink RunSummary::sink() {
  return [this](const behavior::TraceRecord& r) { add(r); };
}

RunCounts RunSummary::counts() const {
  std::lock_guard lock(mutex_);
  return counts_;
}

std::vector<RunSummary::StateTime> RunSummary::states(Time to) const {
  std::lock_guard lock(mutex_);
  std::vector<StateTime> out;
  for (const auto& name : order_) {
    StateTime s{name, 0, Time(0)};
    if (const auto it = states_.find(name); it != states_.end()) {
      s.entered = it->second.first;
      s.spent = it->second.second;
    }
    if (const auto it = entered_.find(name); it != entered_.end() && to > it->second) s.spent += to - it->second;
    out.push_back(std::move(s));
  }
  return out;
}

std::vector<std::string> RunSummary::failures() const {
  std::lock_guard lock(mutex_);
  return failures_;
}

std::map<std::string, std::string> RunSummary::device_states() const {
  std::lock_guard lock(mutex_);
  return device_state_;
}

void RunSummary::print(std::FILE* out, const std::string& policy, Time from, Time to,
                       double wall_seconds, const std::string& clock) const {
  const auto c = counts();
  const double simulated_s = static_cast<double>((to - from).count()) / 1000.0;
  std::fprintf(out, "\n=== summary: policy %s, %s to %s (%.0f min simulated in %.1f s, %.0fx; %s) ===\n",
               policy.c_str(), format_time(from).c_str(), format_time(to).c_str(), simulated_s / 60.0, wall_seconds,
               wall_seconds > 0 ? simulated_s / wall_seconds : 0.0, clock.c_str());
  std::fprintf(out, "states (%d transitions):\n", c.transitions);
  for (const auto& s : states(to)) {
    std::fprintf(out, "  %-14s entered %2d times, %6.1f min\n", s.state.c_str(), s.entered,
                 static_cast<double>(s.spent.count()) / 60000.0);
  }
  std::fprintf(out, "behaviors: %d started, %d succeeded, %d failed, %d halted\n", c.behaviors_started,
               c.behaviors_succeeded, c.behaviors_failed, c.behaviors_halted);
  for (const auto& f : failures()) std::fprintf(out, "  %s\n", f.c_str());
  std::fprintf(out, "service calls: %d (%d failed); voice commands heard: %d\n", c.calls, c.failed_calls,
               c.voice_commands_heard);
  std::fprintf(out, "device commands: %d sent, %d acknowledged, %d failed\n", c.commands_sent,
               c.commands_acknowledged, c.commands_failed);
  std::fprintf(out, "device effects: %d; last effect per device:\n", c.effects);
  for (const auto& [device, state] : device_states()) std::fprintf(out, "  %-16s %s\n", device.c_str(), state.c_str());
  std::fprintf(out, "robot distance driven: %.1f m\n", c.robot_distance_m);
}

sim::PlotData RunSummary::plot(const std::string& title, const sim::House& house, Time from,
                               Time to) const {
  std::lock_guard lock(mutex_);
  sim::PlotData data;
  data.title = title;
  data.run_start = from;
  data.run_end = to;
  std::map<std::string, sim::PlotTrack> robots, users;
  sim::Point robot_at{0, 0};
  if (!house.robots.empty()) robot_at = sim::Point{house.robots.front().start.x, house.robots.front().start.y};
  for (const auto& r : plotted_) {
    if (r.kind == "robot" || r.kind == "user") {
      const auto x = r.number("x"), y = r.number("y");
      if (!x || !y) continue;
      const auto who = r.field(r.kind);
      auto& track = (r.kind == "robot" ? robots : users)[who];
      track.name = who;
      track.points.emplace_back(r.time, sim::Point{*x, *y});
      if (r.kind == "robot") robot_at = sim::Point{*x, *y};
    } else if (r.kind == "transition") {
      sim::PlotMark mark;
      mark.time = r.time;
      mark.at = robot_at;
      mark.label = fmt::format("{} {}", format_time(r.time).substr(3, 5), r.field("to"));
      data.marks.push_back(std::move(mark));
    }
  }
  // Where the house starts each robot and user, unless the trace placed them by then.
  const auto begin_at_start = [from](sim::PlotTrack& track, const std::string& name,
                                      sim::Point start) {
    track.name = name;
    if (track.points.empty() || track.points.front().first > from) {
      track.points.insert(track.points.begin(), std::pair{from, start});
    }
  };
  for (const auto& spec : house.robots) {
    begin_at_start(robots[spec.id], spec.id, spec.start.position());
  }
  for (const auto& spec : house.users) begin_at_start(users[spec.id], spec.id, spec.start);
  for (auto& [name, track] : robots) data.robots.push_back(std::move(track));
  for (auto& [name, track] : users) data.users.push_back(std::move(track));
  return data;
}

void RunSummary::add(const behavior::TraceRecord& r) {
  std::lock_guard lock(mutex_);
  if (keep_plot_ && (r.kind == "robot" || r.kind == "user" || r.kind == "transition")) plotted_.push_back(r);
  if (r.kind == "transition") {
    ++counts_.transitions;
  } else if (r.kind == "state") {
    const auto name = r.field("state");
    if (!states_.contains(name)) order_.push_back(name);
    if (r.field("event") == "enter") {
      ++states_[name].first;
      entered_[name] = r.time;
    } else if (entered_.contains(name)) {
      states_[name].second += r.time - entered_[name];
      entered_.erase(name);
    }
  } else if (r.kind == "behavior") {
    const auto e = r.field("event");
    counts_.behaviors_started += e == "start";
    counts_.behaviors_succeeded += e == "success";
    counts_.behaviors_halted += e == "halt";
    if (e == "failure") {
      ++counts_.behaviors_failed;
      if (failures_.size() < 5) failures_.push_back(fmt::format("[{}] {}", format_time(r.time), r.text));
    }
  } else if (r.kind == "call") {
    if (r.flag("ok") == false) {
      ++counts_.failed_calls;
    } else {
      ++counts_.calls;
    }
  } else if (r.kind == "command") {
    const auto e = r.field("event");
    counts_.commands_sent += e == "sent";
    counts_.commands_acknowledged += e == "acknowledged";
    counts_.commands_failed += e == "failed";
  } else if (r.kind == "effect") {
    ++counts_.effects;
    const auto value = r.field("value");
    device_state_[r.field("device")] = r.field("what") + (value.empty() ? "" : " " + value);
  } else if (r.kind == "speech") {
    ++counts_.voice_commands_heard;
  } else if (r.kind == "robot") {
    const auto x = r.number("x"), y = r.number("y");
    if (!x || !y) return;
    const auto robot = r.field("robot");
    if (const auto it = last_pose_.find(robot); it != last_pose_.end()) {
      counts_.robot_distance_m += std::hypot(*x - it->second.first, *y - it->second.second);
    }
    last_pose_[robot] = {*x, *y};
  }
}

}  // namespace icars::report
