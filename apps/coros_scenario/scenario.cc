// icars-coros, process supervision (scenario.h): writes the plan's configurations, runs one
// icars-agent per agent, applies the kill rule, waits for the user to finish (or the timeout,
// or a signal), stops the agents and reports what their events said.
#include "scenario.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <poll.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <memory>
#include <set>

#include "agent_process.h"
#include "fleet_dashboard.h"
#include "icars/coros/transport.h"
#include "icars/sim/svg_plot.h"
#include "scenario_report.h"

namespace icars::coros_scenario {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

double wall_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

std::atomic<int> g_interrupted{0};  // the signal that asked us to stop, 0 for none
void on_stop_signal(int sig) { g_interrupted.store(sig); }

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
                 ScenarioReport& report, double started_at, FleetDashboard* fleet)
      : plan_(plan),
        options_(options),
        agent_bin_(std::move(agent_bin)),
        report_(report),
        started_at_(started_at),
        fleet_(fleet) {}

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
  // Prints a line of the run; the page gets it too (print() only prints: what the agents'
  // events already told the page).
  void say(const std::string& text) const {
    print(text);
    if (fleet_) fleet_->note(text);
  }
  void print(const std::string& text) const {
    if (options_.quiet) return;
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
        if (fleet_) {
          fleet_->note(fmt::format("{} ended ({})", p->id(), describe(*p)),
                       {{"event", "exited"}, {"agent", p->id()}, {"expected", expected}});
        }
      }
    }
    if (fleet_) fleet_->poll_tracks();
  }

  void handle(AgentProcess& from, const std::string& line) {
    if (line.empty()) return;
    const json event = json::parse(line, nullptr, /*allow_exceptions=*/false);
    if (!event.is_object() || !event.contains("event")) {
      if (options_.verbose) say(fmt::format("{} (not an event): {}", from.id(), line));
      return;
    }
    if (options_.verbose) print(fmt::format("{}: {}", from.id(), line));
    if (fleet_) fleet_->agent_event(from.id(), event);
    const std::string note = report_.on_event(event);
    if (!note.empty() && !options_.verbose) print(note);
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
    const auto text = fmt::format("killed {} (SIGKILL) {}", id, why);
    print(text);
    if (fleet_) fleet_->note(text, {{"event", "killed"}, {"robot", id}, {"reason", why}});
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
  FleetDashboard* fleet_;  // null without --http
  std::vector<std::unique_ptr<AgentProcess>> processes_;
  std::set<std::string> killed_;
  bool stopping_ = false, timed_out_ = false, interrupted_ = false;
  std::string problem_;
};

// A scenario ready to run: the agent binary found, the options checked against the map and
// the configurations written (nothing is written or started before everything was checked),
// stop signals caught.
class PreparedScenario {
 public:
  explicit PreparedScenario(const ScenarioOptions& options)
      : options_(options),
        started_at_(wall_now()),
        agent_bin_(agent_binary(options)),
        dir_(options.keep_dir),
        plan_(plan_scenario(options, dir_.path(),
                            options.broadcast_port != 0 ? options.broadcast_port
                                                        : coros::free_udp_port())) {
    dir_.create();
    for (const auto& a : plan_.agents) {
      write_private_file(a.config_file, a.config.to_json().dump(2) + "\n");
    }
    struct sigaction stop {};
    stop.sa_handler = on_stop_signal;
    ::sigemptyset(&stop.sa_mask);
    ::sigaction(SIGINT, &stop, nullptr);
    ::sigaction(SIGTERM, &stop, nullptr);
    ::signal(SIGPIPE, SIG_IGN);
  }

  double started_at() const { return started_at_; }
  const ScenarioPlan& plan() const { return plan_; }
  WorkDir& dir() { return dir_; }

  // Runs the agents from start to stop; the report has their events and the robots' tracks,
  // and is finished.
  ScenarioReport run(FleetDashboard* fleet) {
    ScenarioReport report(plan_, options_, started_at_);
    ScenarioRunner runner(plan_, options_, agent_bin_, report, started_at_, fleet);
    runner.run();
    for (const auto& a : plan_.agents) {  // a missing one shows in the report ("no track file")
      if (a.role == "robot") report.load_track(a.id, a.track_file);
    }
    report.finish(wall_now() - started_at_, runner.timed_out(), runner.interrupted(),
                  runner.problem());
    return report;
  }

 private:
  static fs::path agent_binary(const ScenarioOptions& options) {
    if (options.agent_bin.empty()) return default_agent_binary();
    if (::access(options.agent_bin.c_str(), X_OK) != 0 || fs::is_directory(options.agent_bin)) {
      throw UsageError(
          fmt::format("--agent-bin {}: not an executable file", options.agent_bin.string()));
    }
    return options.agent_bin;
  }

  const ScenarioOptions& options_;
  double started_at_;
  fs::path agent_bin_;
  WorkDir dir_;
  ScenarioPlan plan_;
};

}  // namespace

ScenarioReport run_agents(const ScenarioOptions& options) {
  PreparedScenario scenario(options);
  return scenario.run(nullptr);
}

int run_scenario(const ScenarioOptions& options) {
  PreparedScenario scenario(options);
  const ScenarioPlan& plan = scenario.plan();
  WorkDir& dir = scenario.dir();
  const double started_at = scenario.started_at();

  std::unique_ptr<FleetDashboard> fleet;
  if (!options.http.empty()) {
    dashboard::DashboardOptions http;
    http.listen = options.http;
    http.tls_cert = options.http_tls_cert;
    http.tls_key = options.http_tls_key;
    fleet = std::make_unique<FleetDashboard>(plan, std::move(http), started_at);
    fleet->start(options);
    std::printf("[icars-coros] dashboard: %s\n", fleet->url().c_str());
    std::fflush(stdout);
  }

  const ScenarioReport report = scenario.run(fleet.get());

  std::printf("\n%s", report.to_text().c_str());
  int code = report.succeeded() ? 0 : 1;
  if (fleet) {
    fleet->poll_tracks(/*now=*/true);  // the robots' last positions
    fleet->summary(report.succeeded(),
                   report.succeeded() ? "every delivery succeeded" : "not every delivery succeeded",
                   report.to_json());
  }
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
  if (fleet && options.http_linger_s != 0 && g_interrupted.load() == 0) {
    if (options.http_linger_s < 0) {
      std::printf("[icars-coros] the dashboard stays at %s until interrupted (Ctrl-C)\n", fleet->url().c_str());
    } else {
      std::printf("[icars-coros] the dashboard stays at %s for %g s (Ctrl-C ends it sooner)\n", fleet->url().c_str(),
                  options.http_linger_s);
    }
    std::fflush(stdout);
    const double until = wall_now() + options.http_linger_s;
    while (g_interrupted.load() == 0 && (options.http_linger_s < 0 || wall_now() < until)) ::usleep(50'000);
  }
  return code;
}

}  // namespace icars::coros_scenario
