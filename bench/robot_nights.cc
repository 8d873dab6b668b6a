// Nights of the two-robot home with a robot killed mid-patrol (docs/distribution.md, "Robots"):
// over many simulated nights, how much of the night patrol gets done, how often errands are
// auctioned again, how long the surviving robot takes to pick up the dead one's waypoints, and
// that no waypoint is left hanging and no task fails.
//
//   robot_nights_bench [--nights 100] [--seed 1] [--speedup 600] [--until 23:30] [--keep DIR]
//
// Every night is a fresh run of real processes on loopback, one night at a time: `icars run
// examples/multi_robot/two_robot_home.xml --world houses/two_robot_house.xml --external`
// (the mediator, with the robot market), one icars-device-manager per robot (its carried
// devices, --no-engines --no-simulator, its COROS agent on the night's fleet) and one with the
// house's static devices, the speech and vision engines and the Simulation device (the clock).
// The robots' managers register first, so the policy (which starts once the clock is known)
// finds both robots. Every manager gets the same --epoch, chosen so the house is at 22:40 (the
// user already in bed) when the managers start; the night ends at --until (the patrol of three
// rounds of six waypoints is over by about 23:05 at 600x).
//
// Night i draws from seed + i: which robot dies (robot1 or robot2), and when: once it has won k
// patrol waypoints (k uniform in 1..4, counted from the trace's "auction" records with outcome
// "awarded" for that robot, read as they are written) plus a uniform 0..1 simulated second; then
// its device manager (with its COROS agent) gets SIGKILL. A night where that robot never wins k
// waypoints before the patrol is over has no kill.
//
// Per night, from the trace (docs/trace.md): patrol awards, errands reached (WaypointReached),
// skips reported ("PatrolHome: skips ..."), re-auctions, failure transitions (must be 0), stuck
// waypoints (a waypoint of a round neither reached nor reported; a run that does not end by
// itself at --until counts too). Time to recover, per errand of the killed robot auctioned
// again: from the kill to (a) its award to the other robot and (b) that waypoint reached, in
//   simulated seconds: the record's simulated time minus the kill's, 18:00 + (kill wall time -
//     epoch) x speedup (the managers' clock; the mediator reads it every 5 ms, so a record's
//     simulated time lags the house by up to 5 ms x speedup: 3 s at 600x);
//   wall milliseconds: from the kill until this program read the record in the trace (it
//     follows the file with inotify).
// Printed: one line per night and a summary with medians and maxima over all recovered errands.
#include <fmt/format.h>
#include <poll.h>
#include <signal.h>
#include <sys/inotify.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "announcement.h"
#include "bench_util.h"
#include "child_process.h"
#include "icars/clock/time.h"
#include "icars/coros/authentication.h"
#include "icars/coros/transport.h"
#include "icars/sim/house.h"

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using icars::Time;

const std::string kIcars = ICARS_BINARY;
const std::string kDeviceManager = ICARS_DEVICE_MANAGER_BINARY;
const std::string kHouse = std::string(ICARS_HOUSES_DIR) + "/two_robot_house.xml";
const std::string kPolicy = std::string(ICARS_EXAMPLES_DIR) + "/multi_robot/two_robot_home.xml";
constexpr int kRounds = 3;                    // the policy's PatrolHome rounds="3"
constexpr const char* kNightStart = "22:40";  // the managers start there: the user is in bed
constexpr auto kStartBound = 60s;  // a process printing its first lines on a loaded machine
constexpr auto kEndSlack = 60s;    // past --until before a run that has not ended is stuck

std::int64_t wall_us() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

Time time_of_day(const std::string& text) {
  const auto t = icars::parse_time_of_day(text);
  if (!t) throw std::invalid_argument("not a time of day (HH:MM): " + text);
  return *t;
}

std::string join(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& item : items) out += (out.empty() ? "" : ",") + item;
  return out;
}

std::string read_text(const fs::path& file) {
  std::ifstream in(file);
  return {std::istreambuf_iterator<char>(in), {}};
}

std::string tail(const fs::path& file, std::size_t lines = 20) {
  const auto text = read_text(file);
  auto at = text.size();
  for (std::size_t n = 0; n <= lines && at != std::string::npos && at > 0; ++n)
    at = text.rfind('\n', at - 1);
  return at == std::string::npos || at >= text.size() ? text : text.substr(at + 1);
}

std::string describe_status(int status) {
  if (WIFEXITED(status)) return fmt::format("exit status {}", WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return fmt::format("killed by signal {}", WTERMSIG(status));
  return fmt::format("wait status {}", status);
}

// --- Child processes -----------------------------------------------------------------------------

// A program with its stderr in a log file and its stdout read line by line; killed (SIGKILL) and
// reaped on destruction.
class Program {
 public:
  Program(std::string name, const fs::path& dir, const std::vector<std::string>& argv)
      : name_(std::move(name)), log_(dir / (name_ + ".stderr")) {
    // `sh` replaces itself by the program (exec), so the pid is the program's.
    std::vector<std::string> shell = {"/bin/sh", "-c", "log=$1; shift; exec \"$@\" 2>\"$log\"",
                                      "sh", log_.string()};
    shell.insert(shell.end(), argv.begin(), argv.end());
    process_ = std::make_unique<planet_test::ChildProcess>(shell);
  }

  const std::string& name() const { return name_; }
  // Reads stdout until a line satisfies `done` and returns it; throws after `bound` or at EOF.
  std::string expect(const std::function<bool(const std::string&)>& done,
                     std::chrono::seconds bound, const std::string& what) {
    const auto end = std::chrono::steady_clock::now() + bound;
    for (;;) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          end - std::chrono::steady_clock::now());
      if (left.count() <= 0) break;
      const auto line = process_->read_line(left);
      if (!line) break;
      if (done(*line)) return *line;
    }
    throw std::runtime_error(fmt::format("{} did not print {} within {} s; its stderr ({}):\n{}",
                                         name_, what, bound.count(), log_.string(), tail(log_)));
  }
  void signal(int sig) const { process_->signal(sig); }
  // The wait status once it has exited (reaped), nullopt while it runs.
  std::optional<int> exited() {
    if (!status_) status_ = process_->wait_for(0ms);
    return status_;
  }
  // SIGTERM, then SIGKILL after `bound`; the wait status.
  int stop(std::chrono::milliseconds bound = 10s) {
    if (exited()) return *status_;
    signal(SIGTERM);
    status_ = process_->wait_for(bound);
    if (!status_) {
      signal(SIGKILL);
      status_ = process_->wait();
    }
    return *status_;
  }
  std::string stderr_tail() const { return tail(log_); }

 private:
  std::string name_;
  fs::path log_;
  std::unique_ptr<planet_test::ChildProcess> process_;
  std::optional<int> status_;
};

// --- The trace, as it is written -----------------------------------------------------------------

// The fields of a trace record this benchmark reads (docs/trace.md), and when it read it.
struct Record {
  Time t{0};                 // simulated time of the record
  std::int64_t seen_us = 0;  // wall clock (µs since 1970) when this program read it
  std::string kind, source, event, outcome, errand, stop, robot, waypoint, text;
  std::string line;  // as written, for the report of an odd night
};

std::string string_at(const nlohmann::json& j, const char* key) {
  const auto it = j.find(key);
  return it != j.end() && it->is_string() ? it->get<std::string>() : std::string();
}

Record parse_record(std::string line, std::int64_t seen_us) {
  const auto j = nlohmann::json::parse(line);
  Record r;
  r.t = Time(j.at("t").get<std::int64_t>());
  r.seen_us = seen_us;
  r.kind = string_at(j, "kind");
  r.source = string_at(j, "source");
  r.event = string_at(j, "event");
  r.outcome = string_at(j, "outcome");
  r.errand = string_at(j, "errand");
  r.stop = string_at(j, "stop");
  r.robot = string_at(j, "robot");
  r.text = string_at(j, "text");
  if (const auto p = j.find("properties"); p != j.end() && p->is_object()) {
    r.waypoint = string_at(*p, "waypoint");
    if (r.robot.empty()) r.robot = string_at(*p, "robot");
  }
  r.line = std::move(line);
  return r;
}

bool is_patrol(const Record& r) { return r.source.find("PatrolHome") != std::string::npos; }
bool patrol_auction(const Record& r) { return r.kind == "auction" && is_patrol(r); }
bool waypoint_reached(const Record& r) { return r.kind == "event" && r.event == "WaypointReached"; }
bool skip_note(const Record& r) {
  return r.kind == "note" && r.text.find("PatrolHome: skips ") != std::string::npos;
}
bool failure_transition(const Record& r) { return r.kind == "transition" && r.event == "failed"; }
bool patrol_over(const Record& r) {
  return r.kind == "behavior" && r.source.ends_with("/PatrolHome") && r.event != "start";
}
// The waypoint a skip note names: "...PatrolHome: skips <waypoint>: why".
std::string skipped_waypoint(const Record& r) {
  const std::string marker = "PatrolHome: skips ";
  const auto from = r.text.find(marker) + marker.size();
  return r.text.substr(from, r.text.find(':', from) - from);
}

// Follows a JSON-lines file as it grows: woken by inotify when it is written, so a record is
// read (and stamped) within microseconds of its write.
class TraceFollower {
 public:
  explicit TraceFollower(const fs::path& file) {
    notify_ = ::inotify_init1(IN_CLOEXEC | IN_NONBLOCK);
    if (notify_ < 0) icars::bench::throw_errno("inotify_init1");
    if (::inotify_add_watch(notify_, file.c_str(), IN_MODIFY) < 0)
      icars::bench::throw_errno(file.c_str());
    in_.open(file, std::ios::binary);
    if (!in_) throw std::runtime_error("cannot read " + file.string());
  }
  ~TraceFollower() { ::close(notify_); }
  TraceFollower(const TraceFollower&) = delete;
  TraceFollower& operator=(const TraceFollower&) = delete;

  // Waits up to `timeout` for the file to be written; appends its new complete records.
  void wait(std::chrono::milliseconds timeout, std::vector<Record>& out) {
    pollfd p{notify_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(timeout.count())) > 0) {
      char events[4096];
      while (::read(notify_, events, sizeof events) > 0) {
      }
    }
    read_new(out);
  }
  // Appends the complete records written so far and not yet read.
  void read_new(std::vector<Record>& out) {
    const auto seen = wall_us();
    char chunk[65536];
    for (;;) {
      in_.clear();
      in_.read(chunk, sizeof chunk);
      const auto n = in_.gcount();
      if (n <= 0) break;
      partial_.append(chunk, static_cast<std::size_t>(n));
    }
    std::size_t from = 0;
    for (auto nl = partial_.find('\n'); nl != std::string::npos; nl = partial_.find('\n', from)) {
      if (nl > from) out.push_back(parse_record(partial_.substr(from, nl - from), seen));
      from = nl + 1;
    }
    partial_.erase(0, from);
  }

 private:
  int notify_ = -1;
  std::ifstream in_;
  std::string partial_;
};

// --- One night -----------------------------------------------------------------------------------

struct Options {
  int nights = 100;
  std::uint64_t seed = 1;
  double speedup = 600;
  std::string until = "23:30";
  std::string keep;
};

// The house as this benchmark runs it: its start, the patrol, the devices of each manager.
struct HousePlan {
  Time start{0};                     // the house's start (day 0), 18:00
  std::vector<std::string> patrol;   // the waypoints the policy's PatrolHome visits each round
  std::vector<std::string> statics;  // the house manager's devices
  std::vector<std::pair<std::string, std::vector<std::string>>> robots;  // robot -> carried devices
};

HousePlan plan_house(const icars::sim::House& house) {
  HousePlan plan;
  plan.start = house.start_time;
  // The house tags the policy's round (two_robot_home.xml lists the same six, in this order).
  for (const auto* w : house.waypoints_tagged("patrol")) plan.patrol.push_back(w->name);
  for (const auto& r : house.robots) plan.robots.emplace_back(r.id, std::vector<std::string>{});
  for (const auto& d : house.devices) {
    if (d.carrier.empty()) {
      plan.statics.push_back(d.id);
      continue;
    }
    for (auto& [robot, devices] : plan.robots) {
      if (robot == d.carrier) devices.push_back(d.id);
    }
  }
  if (plan.robots.size() != 2 || plan.patrol.empty()) {
    throw std::runtime_error(kHouse + ": expected two robots and waypoints tagged patrol");
  }
  return plan;
}

// What night i does to its robots, drawn from seed + i.
struct KillPlan {
  std::string victim;
  int wins = 1;        // killed once it has won this many patrol waypoints
  double extra_s = 0;  // and this many simulated seconds later
};

KillPlan draw_kill(const HousePlan& house, std::uint64_t seed) {
  std::mt19937_64 random(seed);
  KillPlan k;
  k.victim = house.robots[std::uniform_int_distribution<std::size_t>(0, 1)(random)].first;
  k.wins = std::uniform_int_distribution<int>(1, 4)(random);
  k.extra_s = std::uniform_real_distribution<double>(0, 1)(random);
  return k;
}

// One errand of the killed robot, auctioned again after the kill.
struct Recovery {
  std::string stop;
  std::optional<double> award_s, award_ms;      // (a) re-awarded to another robot
  std::optional<double> reached_s, reached_ms;  // (b) that waypoint reached
};

struct NightResult {
  std::uint64_t seed = 0;
  KillPlan plan;
  bool killed = false;
  Time kill_sim{0};
  int awards = 0, reached = 0, skips = 0, reauctions = 0, unassigned = 0, failures = 0;
  // Re-auctions of an award the robot died before acknowledging (the trace has no "awarded").
  int unacknowledged = 0;
  int stuck = 0;       // waypoint visits of a round neither reached nor reported
  int duplicates = 0;  // visits reached or reported more than once a round
  bool ended = true;   // the run ended by itself at --until, exit status 0
  std::vector<Recovery> recoveries;
  std::vector<std::string> odd;  // what is wrong, with the trace lines that show it
  double wall_s = 0;
};

// Reads the night's trace: counts, stuck waypoints, and the recovery of each errand the victim
// lost after the kill.
void read_night(const std::vector<Record>& trace, const HousePlan& house,
                std::optional<std::int64_t> kill_us, NightResult& n) {
  std::map<std::string, int> done;            // waypoint -> reached or reported
  std::map<std::string, std::string> holder;  // errand -> the robot of its last "awarded"
  for (const auto& r : trace) {
    if (patrol_auction(r)) {
      if (r.outcome == "awarded") {
        ++n.awards;
        holder[r.errand] = r.robot;
      }
      if (r.outcome == "reauction") {
        ++n.reauctions;
        if (holder[r.errand] != r.robot) ++n.unacknowledged;
        holder.erase(r.errand);
      }
      if (r.outcome == "unassigned") {
        ++n.unassigned;
        n.odd.push_back("unassigned: " + r.line);
      }
      if (std::find(house.patrol.begin(), house.patrol.end(), r.stop) == house.patrol.end()) {
        n.odd.push_back("a patrol errand for a waypoint the house does not patrol: " + r.line);
      }
    } else if (waypoint_reached(r)) {
      ++n.reached;
      ++done[r.waypoint];
    } else if (skip_note(r)) {
      ++n.skips;
      ++done[skipped_waypoint(r)];
      n.odd.push_back("skip: " + r.line);
    } else if (failure_transition(r)) {
      ++n.failures;
      n.odd.push_back("failure transition: " + r.line);
    }
  }
  for (const auto& w : house.patrol) {
    n.stuck += std::max(0, kRounds - done[w]);
    n.duplicates += std::max(0, done[w] - kRounds);
  }
  if (n.stuck > 0)
    n.odd.push_back(fmt::format("{} waypoint visits neither reached nor reported", n.stuck));
  if (n.duplicates > 0)
    n.odd.push_back(fmt::format("{} waypoint visits reached or reported twice", n.duplicates));
  if (!kill_us) return;

  // Each errand the victim lost once it was dead: its next award, then its waypoint reached.
  for (std::size_t i = 0; i < trace.size(); ++i) {
    const auto& lost = trace[i];
    if (!patrol_auction(lost) || lost.outcome != "reauction" || lost.robot != n.plan.victim)
      continue;
    if (lost.seen_us < *kill_us) continue;  // lost before the kill (a stall): not this recovery
    Recovery rec;
    rec.stop = lost.stop;
    std::size_t j = i + 1;
    for (; j < trace.size(); ++j) {
      const auto& a = trace[j];
      if (patrol_auction(a) && a.errand == lost.errand && a.outcome == "awarded") break;
    }
    if (j < trace.size()) {
      const auto& award = trace[j];
      if (award.robot == n.plan.victim)
        n.odd.push_back("re-awarded to the dead robot: " + award.line);
      rec.award_s = std::chrono::duration<double>(award.t - n.kill_sim).count();
      rec.award_ms = static_cast<double>(award.seen_us - *kill_us) / 1000.0;
      for (std::size_t k = j + 1; k < trace.size(); ++k) {
        const auto& reached = trace[k];
        if (!waypoint_reached(reached) || reached.waypoint != lost.stop) continue;
        rec.reached_s = std::chrono::duration<double>(reached.t - n.kill_sim).count();
        rec.reached_ms = static_cast<double>(reached.seen_us - *kill_us) / 1000.0;
        break;
      }
      if (!rec.reached_s) n.odd.push_back("re-awarded, never reached: " + award.line);
    } else {
      n.odd.push_back("auctioned again, never re-awarded: " + lost.line);
    }
    n.recoveries.push_back(std::move(rec));
  }
}

NightResult run_night(const Options& o, const HousePlan& house, const fs::path& dir,
                      const fs::path& key_file, std::uint64_t seed) {
  NightResult n;
  n.seed = seed;
  n.plan = draw_kill(house, seed);
  const auto night_began = std::chrono::steady_clock::now();
  fs::create_directories(dir);
  const auto trace_file = dir / "trace.jsonl";
  const auto speed = fmt::format("{}", o.speedup);
  const auto port = std::to_string(icars::coros::free_udp_port());
  const std::vector<std::string> fleet = {"--fleet-port", port, "--fleet-key", key_file.string()};

  std::vector<std::string> mediator_argv = {
      kIcars,     "run",         kPolicy,   "--world", kHouse,    "--external",
      "--listen", "127.0.0.1:0", "--until", o.until,   "--trace", trace_file.string(),
      "--quiet"};
  mediator_argv.insert(mediator_argv.end(), fleet.begin(), fleet.end());
  Program mediator("icars", dir, mediator_argv);
  const auto announced =
      mediator.expect([](const std::string& l) { return !icars::app::announced_port(l).empty(); },
                      kStartBound, "its port");
  const auto server = "127.0.0.1:" + icars::app::announced_port(announced);
  TraceFollower follower(trace_file);

  // The house is at 22:40 now: epoch = now - (22:40 - 18:00) / speedup.
  const auto offset = time_of_day(kNightStart) - house.start;
  const auto epoch_ms =
      wall_us() / 1000 - static_cast<std::int64_t>(static_cast<double>(offset.count()) / o.speedup);
  auto manager_argv = [&](const std::vector<std::string>& devices) {
    return std::vector<std::string>{kDeviceManager, "--house",    kHouse,
                                    "--server",     server,       "--speedup",
                                    speed,          "--epoch",    std::to_string(epoch_ms),
                                    "--devices",    join(devices)};
  };
  std::map<std::string, std::unique_ptr<Program>> robots;
  for (const auto& [robot, devices] : house.robots) {
    auto argv = manager_argv(devices);
    argv.insert(argv.end(), {"--no-engines", "--no-simulator"});
    argv.insert(argv.end(), fleet.begin(), fleet.end());
    robots[robot] = std::make_unique<Program>(robot, dir, argv);
  }
  for (auto& [robot, process] : robots) {
    process->expect([](const std::string& l) { return l.starts_with("REGISTERED "); }, kStartBound,
                    "REGISTERED");
  }
  Program statics("house", dir, manager_argv(house.statics));

  // Until the kill: the victim's patrol awards, as they are written.
  std::vector<Record> trace;
  std::size_t read_up_to = 0;
  int wins = 0;
  bool patrol_done = false;
  std::optional<std::int64_t> trigger_us;
  while (!trigger_us && !patrol_done && !mediator.exited()) {
    follower.wait(50ms, trace);
    for (; read_up_to < trace.size(); ++read_up_to) {
      const auto& r = trace[read_up_to];
      if (patrol_over(r)) patrol_done = true;
      if (patrol_auction(r) && r.outcome == "awarded" && r.robot == n.plan.victim &&
          ++wins == n.plan.wins) {
        trigger_us = r.seen_us;
        break;
      }
    }
  }
  std::optional<std::int64_t> kill_us;
  if (trigger_us) {
    const auto at = *trigger_us + static_cast<std::int64_t>(n.plan.extra_s * 1e6 / o.speedup);
    std::this_thread::sleep_for(
        std::chrono::microseconds(std::max<std::int64_t>(0, at - wall_us())));
    robots.at(n.plan.victim)->signal(SIGKILL);
    kill_us = wall_us();
    n.killed = true;
    // The managers' clock: house start + (wall - epoch) x speedup.
    n.kill_sim =
        house.start + Time(static_cast<std::int64_t>(
                          static_cast<double>(*kill_us - epoch_ms * 1000) / 1000.0 * o.speedup));
    robots.at(n.plan.victim)->exited();
  }

  // Until the run ends by itself at --until (at most the whole night from 22:40 from now on).
  auto night = time_of_day(o.until) - time_of_day(kNightStart);
  if (night <= Time(0)) night += icars::kDay;
  const auto bound = std::chrono::steady_clock::now() + kEndSlack +
                     std::chrono::milliseconds(
                         static_cast<std::int64_t>(static_cast<double>(night.count()) / o.speedup));
  while (!mediator.exited() && std::chrono::steady_clock::now() < bound) follower.wait(50ms, trace);
  follower.read_new(trace);
  if (const auto status = mediator.exited(); !status || *status != 0) {
    n.ended = false;
    n.odd.push_back(status ? fmt::format("icars: {}; its stderr:\n{}", describe_status(*status),
                                         mediator.stderr_tail())
                           : fmt::format("icars did not end by itself at {}", o.until));
    mediator.stop();
    follower.read_new(trace);
  }
  for (auto& [robot, process] : robots) {
    if (n.killed && robot == n.plan.victim) continue;
    if (const auto status = process->stop(); !WIFEXITED(status) || WEXITSTATUS(status) != 0) {
      n.odd.push_back(fmt::format("{}'s device manager: {}; its stderr:\n{}", robot,
                                  describe_status(status), process->stderr_tail()));
    }
  }
  if (const auto status = statics.stop(); !WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    n.odd.push_back(fmt::format("the house's device manager: {}; its stderr:\n{}",
                                describe_status(status), statics.stderr_tail()));
  }
  read_night(trace, house, kill_us, n);
  n.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - night_began).count();
  return n;
}

// --- Report --------------------------------------------------------------------------------------

std::string seconds(std::optional<double> s) {
  return s ? fmt::format("{:.1f} s", *s) : std::string("-");
}
std::string millis(std::optional<double> ms) {
  return ms ? fmt::format("{:.1f} ms", *ms) : std::string("-");
}

std::optional<double> worst(const std::vector<Recovery>& rs,
                            std::optional<double> Recovery::*field) {
  std::optional<double> out;
  for (const auto& r : rs) {
    if (r.*field) out = std::max(out.value_or(*(r.*field)), *(r.*field));
  }
  return out;
}

void print_night(int i, const NightResult& n) {
  const auto kill = n.killed
                        ? fmt::format("{} killed after {} wins +{:.2f} s at {}", n.plan.victim,
                                      n.plan.wins, n.plan.extra_s, icars::format_time(n.kill_sim))
                        : fmt::format("no kill ({} never won {})", n.plan.victim, n.plan.wins);
  std::printf(
      "night %3d seed %-4llu %-52s awarded %2d reached %2d skipped %d re-auctions %d failures %d "
      "stuck %d%s"
      "  recover: award %s / %s, reached %s / %s  (%.1f s)\n",
      i, static_cast<unsigned long long>(n.seed), kill.c_str(), n.awards, n.reached, n.skips,
      n.reauctions, n.failures, n.stuck, n.ended ? "" : " NOT ENDED",
      seconds(worst(n.recoveries, &Recovery::award_s)).c_str(),
      millis(worst(n.recoveries, &Recovery::award_ms)).c_str(),
      seconds(worst(n.recoveries, &Recovery::reached_s)).c_str(),
      millis(worst(n.recoveries, &Recovery::reached_ms)).c_str(), n.wall_s);
  for (const auto& line : n.odd) std::printf("    %s\n", line.c_str());
  std::fflush(stdout);
}

void print_summary(const Options& o, const HousePlan& house, const std::vector<NightResult>& nights,
                   double wall_s) {
  int kills = 0, awards = 0, reached = 0, skips = 0, reauctions = 0, unacknowledged = 0,
      unassigned = 0, failures = 0, stuck = 0, duplicates = 0, not_ended = 0;
  std::vector<double> award_s, award_ms, reached_s, reached_ms;
  int unrecovered = 0;
  for (const auto& n : nights) {
    kills += n.killed;
    awards += n.awards;
    reached += n.reached;
    skips += n.skips;
    reauctions += n.reauctions;
    unacknowledged += n.unacknowledged;
    unassigned += n.unassigned;
    failures += n.failures;
    stuck += n.stuck;
    duplicates += n.duplicates;
    not_ended += !n.ended;
    for (const auto& r : n.recoveries) {
      if (r.award_s) {
        award_s.push_back(*r.award_s);
        award_ms.push_back(*r.award_ms);
      }
      if (r.reached_s) {
        reached_s.push_back(*r.reached_s);
        reached_ms.push_back(*r.reached_ms);
      } else {
        ++unrecovered;
      }
    }
  }
  const auto nights_run = static_cast<int>(nights.size());
  const auto visits = nights_run * kRounds * static_cast<int>(house.patrol.size());
  auto row = [](const char* what, const std::vector<double>& s, const std::vector<double>& ms) {
    if (s.empty()) {
      std::printf("  %-34s -\n", what);
      return;
    }
    const auto a = icars::bench::stats(s), b = icars::bench::stats(ms);
    std::printf(
        "  %-34s median %6.1f s sim %8.1f ms wall   max %6.1f s sim %8.1f ms wall   (min %.1f s, "
        "%.1f ms; n=%zu)\n",
        what, a.median, b.median, a.max, b.max, a.min, b.min, s.size());
  };
  std::printf("\n%d nights at %gx from %s to %s, seeds %llu..%llu, %.0f s wall\n", nights_run,
              o.speedup, kNightStart, o.until.c_str(), static_cast<unsigned long long>(o.seed),
              static_cast<unsigned long long>(
                  o.seed + static_cast<std::uint64_t>(std::max(0, nights_run - 1))),
              wall_s);
  std::printf(
      "  kills                              %d (%d nights without: the robot never won its k "
      "waypoints)\n",
      kills, nights_run - kills);
  std::printf("  patrol waypoints reached           %d of %d (%d reported skipped)\n", reached,
              visits, skips);
  std::printf("  patrol awards                      %d (re-awards included)\n", awards);
  std::printf(
      "  re-auctions                        %d (%d of an award not yet acknowledged; %d "
      "unassigned)\n",
      reauctions, unacknowledged, unassigned);
  std::printf("  time to recover, per errand the killed robot lost (from the kill):\n");
  row("(a) re-awarded to the other robot", award_s, award_ms);
  row("(b) its waypoint reached", reached_s, reached_ms);
  std::printf(
      "  (simulated: a record's time minus the kill's; the mediator reads the house's clock every "
      "5 ms, so\n"
      "   its records lag by up to %.1f s and (a) can come out negative. wall: the kill until the "
      "record was read)\n",
      0.005 * o.speedup);
  std::printf("  lost errands never reached         %d\n", unrecovered);
  std::printf(
      "  stuck waypoint visits              %d (+ %d nights that did not run or end by "
      "themselves)\n",
      stuck, not_ended);
  std::printf("  visits reached twice in a round    %d\n", duplicates);
  std::printf("  failure transitions                %d\n", failures);
}

int run(const Options& o) {
  const auto house = plan_house(icars::sim::load_house(kHouse));
  time_of_day(o.until);
  const fs::path root = o.keep.empty()
                            ? fs::temp_directory_path() / fmt::format("robot_nights-{}", ::getpid())
                            : fs::path(o.keep);
  fs::create_directories(root);
  const auto key_file = root / "fleet.key";
  {
    std::ofstream out(key_file);
    out << icars::coros::FleetKey::generate().to_hex() << "\n";
    if (!out) throw std::runtime_error("cannot write " + key_file.string());
  }
  ::chmod(key_file.c_str(), 0600);

  const auto began = std::chrono::steady_clock::now();
  std::vector<NightResult> nights;
  for (int i = 0; i < o.nights; ++i) {
    const auto seed = o.seed + static_cast<std::uint64_t>(i);
    const auto dir = root / fmt::format("night-{:03}-seed-{}", i, seed);
    try {
      nights.push_back(run_night(o, house, dir, key_file, seed));
    } catch (const std::exception& e) {  // a process did not start: the night counts as not ended
      NightResult n;
      n.seed = seed;
      n.plan = draw_kill(house, seed);
      n.ended = false;
      n.stuck = kRounds * static_cast<int>(house.patrol.size());
      n.odd.push_back(fmt::format("the night did not run: {}", e.what()));
      nights.push_back(std::move(n));
    }
    print_night(i, nights.back());
    if (o.keep.empty()) fs::remove_all(dir);
  }
  print_summary(o, house, nights,
                std::chrono::duration<double>(std::chrono::steady_clock::now() - began).count());
  if (o.keep.empty()) fs::remove_all(root);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Nights of the two-robot home with a robot killed mid-patrol: tasks done, re-auctions, "
      "recovery"};
  Options o;
  app.add_option("--nights", o.nights, "nights to run, one after another")
      ->check(CLI::Range(1, 100000));
  app.add_option("--seed", o.seed, "night i draws its kill from seed + i");
  app.add_option("--speedup", o.speedup, "simulated seconds per wall-clock second")
      ->check(CLI::Range(1.0, 10000.0));
  app.add_option("--until", o.until,
                 "the night ends at this time of day (HH:MM; the patrol is over by about 23:05)")
      ->check([](const std::string& t) {
        return icars::parse_time_of_day(t) ? std::string() : "not a time of day (HH:MM): " + t;
      });
  app.add_option("--keep", o.keep, "keep every night's trace and logs under this directory");
  CLI11_PARSE(app, argc, argv);
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "robot_nights_bench: %s\n", e.what());
    return 2;
  }
}
