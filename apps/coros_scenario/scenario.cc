#include "scenario.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <memory>
#include <random>
#include <set>

#include "agent_process.h"
#include "icars/coros/knowledge.h"
#include "icars/coros/transport.h"
#include "icars/sim/planner.h"
#include "icars/sim/svg_plot.h"
#include "scenario_report.h"

namespace icars::coros_scenario {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

double wall_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
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

std::atomic<int> g_interrupted{0};  // the signal that asked us to stop, 0 for none
void on_stop_signal(int sig) { g_interrupted.store(sig); }

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
  const std::string fleet_key = coros::FleetKey::generate().to_hex();
  const auto base = [&](const std::string& id, const std::string& role, std::size_t index) {
    json c;
    c["id"] = id;
    c["role"] = role;
    c["ip"] = "127.0.0.1";
    c["port"] = 0;
    c["broadcast"] = {{"address", "127.255.255.255"}, {"port", broadcast_port}};
    c["hello_period_ms"] = 200;
    c["neighbor_expiry_ms"] = options.neighbor_expiry_ms;
    c["bid_window_ms"] = options.bid_window_ms > 0
                             ? options.bid_window_ms
                             : 400 + 25 * std::max(0, options.robots - 16);
    c["retry_period_ms"] = 100;
    c["max_retries"] = 20;
    c["map"] = plan.map.string();
    c["key"] = fleet_key;
    if (faults) {
      c["faults"] = fmt::format(
          "drop={},duplicate={},delay={},max_delay_ms={},seed={}", faults->drop, faults->duplicate,
          faults->delay, faults->max_delay_ms, agent_fault_seed(options.seed, faults->seed, index));
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
    a.config["robot"] = {{"start", a.start},
                         {"speed", kRobotSpeed},
                         {"radius", kRobotRadius},
                         {"speedup", options.speedup},
                         {"kind", "sim"}};
    a.config["track_file"] = a.track_file.string();
    plan.agents.push_back(std::move(a));
  }
  AgentPlan user;
  user.id = kUserId;
  user.role = "user";
  user.config_file = dir / (user.id + ".json");
  user.log_file = dir / (user.id + ".log");
  user.config = base(user.id, user.role, starts.size());
  json deliveries = json::array();
  for (const auto& d : plan.deliveries) deliveries.push_back({d.pickup, d.dropoff});
  user.config["user"] = {{"deliveries", deliveries},
                         {"expect_robots", options.robots},
                         {"start_after_ms", 10000},
                         {"delivery_interval_ms", options.delivery_interval_ms},
                         {"exit_when_done", true}};
  plan.agents.push_back(std::move(user));

  // The agents read these with the library's own reader: check them the same way now.
  for (const auto& a : plan.agents) {
    try {
      coros::AgentConfiguration::parse(a.config.dump(), dir, a.config_file.string());
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

namespace {

// The scenario's working directory: --keep-dir (created by create(), once the options were
// found usable), or a fresh temporary one removed at the end unless keep() was called (a
// failed run keeps it for the agents' logs).
class WorkDir {
 public:
  explicit WorkDir(const fs::path& keep) {
    if (!keep.empty()) {
      path_ = fs::absolute(keep);
      keep_ = true;
      return;
    }
    std::string pattern = (fs::temp_directory_path() / "icars-coros-XXXXXX").string();
    if (::mkdtemp(pattern.data()) == nullptr) {
      throw std::runtime_error(
          fmt::format("cannot create a temporary directory {}: {}", pattern, std::strerror(errno)));
    }
    path_ = pattern;
  }
  ~WorkDir() {
    if (!keep_) {
      std::error_code ec;
      fs::remove_all(path_, ec);
    }
  }
  WorkDir(const WorkDir&) = delete;
  WorkDir& operator=(const WorkDir&) = delete;

  void create() const {
    std::error_code ec;
    fs::create_directories(path_, ec);
    if (ec || !fs::is_directory(path_)) {
      throw UsageError(fmt::format("--keep-dir {}: cannot create the directory: {}", path_.string(),
                                   ec ? ec.message() : "not a directory"));
    }
  }
  const fs::path& path() const { return path_; }
  void keep() { keep_ = true; }
  bool kept() const { return keep_; }

 private:
  fs::path path_;
  bool keep_ = false;
};

void write_file(const fs::path& file, const std::string& text) {
  std::ofstream out(file, std::ios::trunc);
  out << text;
  out.close();
  if (!out) throw std::runtime_error(fmt::format("cannot write {}", file.string()));
}

// An agent configuration holds the fleet key: only its owner may read it (mode 0600, also
// when --keep-dir reuses a file that was readable).
void write_private_file(const fs::path& file, const std::string& text) {
  const int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  bool ok = fd >= 0 && ::fchmod(fd, 0600) == 0;
  for (std::size_t done = 0; ok && done < text.size();) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    ok = n > 0;
    if (ok) done += static_cast<std::size_t>(n);
  }
  const int error = errno;
  if (fd >= 0 && ::close(fd) != 0) ok = false;
  if (!ok) {
    throw std::runtime_error(
        fmt::format("cannot write {}: {}", file.string(), std::strerror(error)));
  }
}

// Runs the agents of a plan until the user is done, the timeout passes or we are asked to
// stop; feeds their events to the report and prints the interesting ones.
class ScenarioRunner {
 public:
  ScenarioRunner(const ScenarioPlan& plan, const ScenarioOptions& options, fs::path agent_bin,
                 ScenarioReport& report, double started_at)
      : plan_(plan),
        options_(options),
        agent_bin_(std::move(agent_bin)),
        report_(report),
        started_at_(started_at) {}

  void run() {
    // Robots first; the user once every robot is up (or has ended), so that its auctions
    // find the whole fleet however long a large fleet takes to start.
    for (const auto& a : plan_.agents) {
      if (a.role == "robot") start(a);
    }
    say(fmt::format(
        "starting {} robot{} (broadcast port {}, datagrams signed with a fresh fleet key, agent "
        "logs in {})",
        plan_.agents.size() - 1, plan_.agents.size() == 2 ? "" : "s", plan_.broadcast_port,
        plan_.dir.string()));
    while (!should_stop()) {
      pump(100);
      std::size_t up = 0, ended = 0;
      for (const auto& p : processes_) {
        if (report_.robots().at(p->id()).started_at) {
          ++up;
        } else if (p->exited()) {
          ++ended;
        }
      }
      if (up + ended < processes_.size()) continue;
      if (up == 0) {
        problem_ = fmt::format("no robot started: every icars-agent ended at once; see {}",
                               plan_.agents.front().log_file.string());
        say(problem_);
        break;
      }
      say(ended == 0 ? std::string("every robot is up: starting the user")
                     : fmt::format("{} of {} robots are up ({} ended): starting the user", up,
                                   processes_.size(), ended));
      start(plan_.agents.back());
      break;
    }
    if (!process(kUserId)) {
      stop_all();
      return;
    }
    while (!should_stop()) {
      pump(100);
      check_timed_kill();
      if (report_.all_done()) break;
      if (const auto* user = process(kUserId); user->exited() && user->stdout_fd() < 0) {
        problem_ = fmt::format("the user agent ended ({}) before all deliveries were done; see {}",
                               describe(*user), plan_.agents.back().log_file.string());
        say(problem_);
        break;
      }
    }
    stop_all();
  }

  bool timed_out() const { return timed_out_; }
  bool interrupted() const { return interrupted_; }
  const std::string& problem() const { return problem_; }

 private:
  void say(const std::string& text) const {
    std::printf("[%6.2fs] %s\n", wall_now() - started_at_, text.c_str());
    std::fflush(stdout);
  }

  static std::string describe(const AgentProcess& p) {
    const auto status = p.wait_status();
    return status ? describe_wait_status(*status) : "running";
  }

  void start(const AgentPlan& agent) {
    processes_.push_back(std::make_unique<AgentProcess>(
        agent.id, std::vector<std::string>{agent_bin_.string(), agent.config_file.string()},
        agent.log_file));
  }

  // Interrupted by a signal, or out of time (noted once).
  bool should_stop() {
    if (interrupted_ || timed_out_) return true;
    if (const int sig = g_interrupted.load(); sig != 0) {
      interrupted_ = true;
      say(fmt::format("interrupted (signal {}): stopping the agents", sig));
    } else if (wall_now() > started_at_ + options_.timeout_s) {
      timed_out_ = true;
      say(fmt::format("timed out after {:g} s: stopping the agents", options_.timeout_s));
    }
    return interrupted_ || timed_out_;
  }

  AgentProcess* process(const std::string& id) {
    for (auto& p : processes_) {
      if (p->id() == id) return p.get();
    }
    return nullptr;
  }

  // Waits up to `timeout_ms` for output, handles every line that came, reaps exited agents.
  void pump(int timeout_ms) {
    std::vector<pollfd> fds;
    std::vector<AgentProcess*> owners;
    for (auto& p : processes_) {
      if (p->stdout_fd() < 0) continue;
      fds.push_back({p->stdout_fd(), POLLIN, 0});
      owners.push_back(p.get());
    }
    if (fds.empty()) {
      ::usleep(static_cast<useconds_t>(timeout_ms) * 1000U);
    } else if (::poll(fds.data(), fds.size(), timeout_ms) > 0) {
      for (std::size_t i = 0; i < fds.size(); ++i) {
        if ((fds[i].revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
        for (const auto& line : owners[i]->read_lines()) handle(*owners[i], line);
      }
    }
    for (auto& p : processes_) {
      const bool was = p->exited();
      if (p->reap() && !was) {
        report_.agent_exited(p->id(), *p->wait_status());
        const bool expected =
            stopping_ || killed_.count(p->id()) > 0 || (p->id() == kUserId && report_.all_done());
        if (!expected) say(fmt::format("{} ended unexpectedly ({})", p->id(), describe(*p)));
      }
    }
  }

  void handle(AgentProcess& from, const std::string& line) {
    if (line.empty()) return;
    const json event = json::parse(line, nullptr, /*allow_exceptions=*/false);
    if (!event.is_object() || !event.contains("event")) {
      if (options_.verbose) say(fmt::format("{} (not an event): {}", from.id(), line));
      return;
    }
    if (options_.verbose) say(fmt::format("{}: {}", from.id(), line));
    const std::string note = report_.on_event(event);
    if (!note.empty() && !options_.verbose) say(note);
    // A kill at a stage: the robot's own event says it reached it.
    const auto& kill = options_.kill;
    if (kill && !kill->stage.empty() && from.id() == kill->robot &&
        event.value("event", "") == "task_stage" && event.value("stage", "") == kill->stage) {
      kill_robot(kill->robot, fmt::format("at stage {} of {}", kill->stage,
                                          event.value("task", std::string("?"))));
    }
  }

  void check_timed_kill() {
    const auto& kill = options_.kill;
    if (!kill || !kill->stage.empty() || !report_.first_award_at()) return;
    const double at = *report_.first_award_at() + static_cast<double>(kill->delay.count()) / 1000.0;
    if (wall_now() >= at) {
      kill_robot(kill->robot, fmt::format("{:g} s after the first award",
                                          static_cast<double>(kill->delay.count()) / 1000.0));
    }
  }

  void kill_robot(const std::string& id, const std::string& why) {
    if (killed_.count(id) > 0) return;
    killed_.insert(id);
    auto* p = process(id);
    if (!p || p->exited()) {
      say(fmt::format("{} should be killed {}, but it has already ended", id, why));
      return;
    }
    p->signal(SIGKILL);
    report_.robot_killed(id, wall_now(), why);
    say(fmt::format("killed {} (SIGKILL) {}", id, why));
  }

  // SIGTERM to every agent still running, SIGKILL to those still there after 2 s; their
  // output is read to the end meanwhile (the "stopped" events, last lines).
  void stop_all() {
    stopping_ = true;
    for (auto& p : processes_) p->signal(SIGTERM);
    const double grace_end = wall_now() + 2.0;
    const auto all_gone = [&] {
      return std::all_of(processes_.begin(), processes_.end(),
                         [](const auto& p) { return p->exited() && p->stdout_fd() < 0; });
    };
    while (!all_gone() && wall_now() < grace_end) pump(50);
    bool forced = false;
    for (auto& p : processes_) {
      if (!p->exited()) {
        p->signal(SIGKILL);
        forced = true;
      }
    }
    if (forced) say("agents still running after 2 s were killed (SIGKILL)");
    const double end = wall_now() + 2.0;
    while (!all_gone() && wall_now() < end) pump(50);
  }

  const ScenarioPlan& plan_;
  const ScenarioOptions& options_;
  fs::path agent_bin_;
  ScenarioReport& report_;
  double started_at_;
  std::vector<std::unique_ptr<AgentProcess>> processes_;
  std::set<std::string> killed_;
  bool stopping_ = false, timed_out_ = false, interrupted_ = false;
  std::string problem_;
};

}  // namespace

int run_scenario(const ScenarioOptions& options) {
  const double started_at = wall_now();
  fs::path agent_bin = options.agent_bin;
  if (agent_bin.empty()) {
    agent_bin = default_agent_binary();
  } else if (::access(agent_bin.c_str(), X_OK) != 0 || fs::is_directory(agent_bin)) {
    throw UsageError(fmt::format("--agent-bin {}: not an executable file", agent_bin.string()));
  }
  const std::uint16_t port = options.broadcast_port != 0 ? options.broadcast_port : coros::free_udp_port();

  // Everything is checked before anything is written or started.
  WorkDir dir(options.keep_dir);
  const ScenarioPlan plan = plan_scenario(options, dir.path(), port);
  dir.create();
  for (const auto& a : plan.agents) write_private_file(a.config_file, a.config.dump(2) + "\n");

  struct sigaction stop {};
  stop.sa_handler = on_stop_signal;
  ::sigemptyset(&stop.sa_mask);
  ::sigaction(SIGINT, &stop, nullptr);
  ::sigaction(SIGTERM, &stop, nullptr);
  ::signal(SIGPIPE, SIG_IGN);

  ScenarioReport report(plan, options, started_at);
  ScenarioRunner runner(plan, options, agent_bin, report, started_at);
  runner.run();
  for (const auto& a : plan.agents) {  // a missing one shows in the report ("no track file")
    if (a.role == "robot") report.load_track(a.id, a.track_file);
  }
  report.finish(wall_now() - started_at, runner.timed_out(), runner.interrupted(),
                runner.problem());

  std::printf("\n%s", report.to_text().c_str());
  int code = report.succeeded() ? 0 : 1;
  if (!options.json.empty()) {
    try {
      write_file(options.json, report.to_json().dump(2) + "\n");
      std::printf("Summary written to %s\n", options.json.c_str());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "icars-coros: %s\n", e.what());
      code = 1;
    }
  }
  if (!options.svg.empty()) {
    try {
      sim::write_svg(options.svg.string(), plan.house, report.plot());
      std::printf("Plot written to %s\n", options.svg.c_str());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "icars-coros: %s\n", e.what());
      code = 1;
    }
  }
  if (code != 0 && !dir.kept()) {
    dir.keep();
    std::printf("Agent configurations, logs and tracks kept in %s\n", dir.path().c_str());
  }
  std::fflush(stdout);
  return code;
}

}  // namespace icars::coros_scenario
