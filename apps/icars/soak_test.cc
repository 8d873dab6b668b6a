// Soak test of the smart-home scenario: `icars run --external` and three icars-device-manager
// processes run the paper's policy on the paper's house for a simulated week at an accelerated
// speed, while device managers are SIGKILLed at random simulated times and restarted after a
// random pause. Afterwards it checks what a user would see:
//   - the server stopped by itself at the end of the last day, with exit status 0 and (in the
//     ASan build) no leak or sanitizer report in its stderr; the last incarnation of every
//     device manager stops on SIGTERM with status 0 too;
//   - every restarted device manager registered its devices again;
//   - every day the statechart entered Observation, RestMode and SleepMode;
//   - no task ran on after the occupancy change that should end it, and no behavior outlived
//     its task (stuck tasks, defined below from the trace);
//   - the server's memory is flat: VmRSS sampled every simulated day at 12:00, the last day's
//     within max(+10%, +4 MiB) of day 2's.
//
// Environment (for a longer soak by hand, or a release build):
//   ICARS_SOAK_SEED   the kill schedule's seed (default: random; printed either way)
//   ICARS_SOAK_DAYS   simulated days (default 7)
//   ICARS_SOAK_SPEED  simulated seconds per wall-clock second (default 3600: 7 days in 168 s)
//   ICARS_SOAK_KILLS  0: no kills (the same run and checks, for comparison)
//   ICARS_SOAK_KEEP   a directory to keep the trace, the stdout/stderr logs and soak.json in
// e.g. ICARS_SOAK_DAYS=30 ctest --test-dir build/release -L soak -V (README, "Soak test").
#include <gtest/gtest.h>

#include <fmt/format.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "child_process.h"
#include "icars/sim/house.h"
#include "icars/sim/time.h"

namespace {

namespace fs = std::filesystem;
namespace sim = icars::sim;
using nlohmann::json;
using sim::SimTime;
using namespace std::chrono_literals;

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kDeviceManager = ICARS_DEVICE_MANAGER_BINARY;
const std::string kPolicy = kSource + "/examples/smart_home/paper_home.xml";
const std::string kHouse = kSource + "/houses/paper_house.xml";

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAsan = true;
#else
constexpr bool kAsan = false;
#endif

// --- Settings ------------------------------------------------------------------------------------

struct Settings {
  int days = 7;
  double speed = 3600;
  std::uint64_t seed = 0;
  bool kills = true;
  std::string keep;  // directory for the artifacts, or ""
};

Settings settings_from_environment() {
  Settings s;
  s.seed = std::random_device{}();
  const auto var = [](const char* name) -> std::optional<std::string> {
    const char* v = std::getenv(name);
    if (v == nullptr || *v == '\0') return std::nullopt;
    return std::string(v);
  };
  try {
    if (auto v = var("ICARS_SOAK_SEED")) s.seed = std::stoull(*v);
    if (auto v = var("ICARS_SOAK_DAYS")) s.days = std::stoi(*v);
    if (auto v = var("ICARS_SOAK_SPEED")) s.speed = std::stod(*v);
  } catch (const std::exception&) {
    throw std::invalid_argument("ICARS_SOAK_SEED, ICARS_SOAK_DAYS and ICARS_SOAK_SPEED must be numbers");
  }
  if (s.days < 2) throw std::invalid_argument("ICARS_SOAK_DAYS must be at least 2 (day 2 is the memory baseline)");
  if (s.speed < 1 || s.speed > 20000) throw std::invalid_argument("ICARS_SOAK_SPEED must be 1 to 20000");
  if (auto v = var("ICARS_SOAK_KEEP")) s.keep = *v;
  if (auto v = var("ICARS_SOAK_KILLS")) s.kills = *v != "0";
  return s;
}

// --- Processes -----------------------------------------------------------------------------------

std::string read_file(const fs::path& path) {
  std::ifstream in(path);
  return {std::istreambuf_iterator<char>(in), {}};
}

std::string tail(const std::string& text, std::size_t lines = 30) {
  std::size_t at = text.size();
  for (std::size_t n = 0; n <= lines && at != std::string::npos && at > 0; ++n) at = text.rfind('\n', at - 1);
  return at == std::string::npos || at >= text.size() ? text : text.substr(at + 1);
}

// Whether a log holds a sanitizer report (leak, memory error, undefined behavior).
bool sanitizer_report(const std::string& log) {
  return log.find("ERROR: LeakSanitizer") != std::string::npos ||
         log.find("ERROR: AddressSanitizer") != std::string::npos ||
         log.find("runtime error:") != std::string::npos;
}

// A child process with its stderr in a log file and extra environment variables.
class Program {
 public:
  Program(fs::path log, const std::vector<std::string>& env, const std::vector<std::string>& argv)
      : log_(std::move(log)) {
    // `sh` and `env` replace themselves by the program (exec), so the pid is the program's.
    std::vector<std::string> all = {"/bin/sh", "-c", "log=$1; shift; exec \"$@\" 2>\"$log\"", "sh", log_.string(),
                                    "/usr/bin/env"};
    all.insert(all.end(), env.begin(), env.end());
    all.insert(all.end(), argv.begin(), argv.end());
    process_ = std::make_unique<planet_test::ChildProcess>(all);
  }

  pid_t pid() const { return process_->pid(); }
  const fs::path& log() const { return log_; }
  std::string stderr_text() const { return read_file(log_); }
  // Lines printed so far (waiting at most ~2 ms for more; read_line needs 2 ms to poll at all).
  std::vector<std::string> lines() {
    std::vector<std::string> out;
    while (auto line = process_->read_line(2ms)) out.push_back(std::move(*line));
    return out;
  }
  // True once the process has exited (a zombie, not yet reaped) or is gone.
  bool exited() const {
    std::ifstream stat("/proc/" + std::to_string(pid()) + "/stat");
    std::string text;
    if (!std::getline(stat, text)) return true;
    const auto paren = text.rfind(')');
    return paren == std::string::npos || paren + 2 >= text.size() || text[paren + 2] == 'Z';
  }
  void signal(int sig) const { process_->signal(sig); }
  int wait() { return process_->wait(); }

 private:
  fs::path log_;
  std::unique_ptr<planet_test::ChildProcess> process_;  // killed (SIGKILL) and reaped on destruction
};

std::string describe_status(int status) {
  if (WIFEXITED(status)) return fmt::format("exit status {}", WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return fmt::format("killed by signal {}", WTERMSIG(status));
  return fmt::format("wait status {}", status);
}

struct Memory {
  double rss_mib = 0, hwm_mib = 0;
};
Memory read_memory(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  Memory m;
  for (std::string line; std::getline(in, line);) {
    const auto kib = [&] { return std::stod(line.substr(line.find(':') + 1)) / 1024.0; };
    if (line.starts_with("VmRSS:")) m.rss_mib = kib();
    if (line.starts_with("VmHWM:")) m.hwm_mib = kib();
  }
  return m;
}

// --- The house: device managers, and when the users change what the sensors see ---------------

struct Manager {
  std::string name;
  std::vector<std::string> devices;
  bool simulation = false;          // hosts the engines and the Simulation device (the clock)
  std::set<std::string> furniture;  // watched by its occupancy sensors
  std::size_t expected_devices = 0;

  std::unique_ptr<Program> process;
  int incarnation = 0;
  bool registered = false;
  std::chrono::steady_clock::time_point started_wall;
  SimTime down_since{0};
  int kills = 0, registrations = 0;
  std::vector<double> reregistration_ms;            // wall time from restart to registration
  std::vector<std::pair<SimTime, SimTime>> outages;  // killed .. registered again
};

// The moments of a day when a user sits or lies down on, or gets up from, furniture that a
// sensor watches: the only inputs that move the paper policy's statechart.
struct Moment {
  std::string furniture;
  SimTime time_of_day;
};
std::vector<Moment> occupancy_moments(const sim::House& house, const std::set<std::string>& sensed) {
  std::vector<Moment> out;
  for (const auto& user : house.users) {
    const auto& entries = user.schedule;
    for (std::size_t i = 0; i < entries.size(); ++i) {
      const auto& e = entries[i];
      if ((e.activity != sim::Activity::sit && e.activity != sim::Activity::lie) || !sensed.contains(e.target)) continue;
      out.push_back({e.target, e.at});
      for (std::size_t j = 1; j <= entries.size(); ++j) {  // the next movement ends it (maybe tomorrow)
        const auto& next = entries[(i + j) % entries.size()];
        if (next.activity == sim::Activity::say) continue;
        out.push_back({e.target, next.at});
        break;
      }
    }
  }
  return out;
}

// The first moment strictly after `t` (in any day), of the given furniture or of any.
SimTime next_moment(const std::vector<Moment>& moments, SimTime t, const std::string& furniture = "") {
  SimTime best = SimTime::max();
  for (const auto& m : moments) {
    if (!furniture.empty() && m.furniture != furniture) continue;
    auto at = sim::kDay * (t / sim::kDay) + m.time_of_day;
    if (at <= t) at += sim::kDay;
    best = std::min(best, at);
  }
  return best;
}

// --- The kill schedule ---------------------------------------------------------------------------

struct Action {
  enum Kind { kill, restart, sample } kind;
  SimTime at;
  std::size_t manager = 0;  // kill, restart
  int day = 0;              // sample
};

// Kills every 2 to 8 simulated hours, a random manager each time, restarted after 1 to 20
// simulated minutes. A manager's outage (the pause plus `restart` for starting again and
// registering) must not cover a moment when one of its sensors sees the user sit, lie down or get
// up: a sensor that is down then misses the change for good (Sense reports a sensor's current
// state only when it binds), and the day's cycle would legitimately differ. The manager of the
// Simulation device avoids every moment: while it is down the mediator's clock stands still.
std::vector<Action> plan(std::mt19937_64& rng, std::vector<Manager>& managers, const std::vector<Moment>& moments,
                         SimTime start, SimTime end, SimTime restart, SimTime jitter) {
  const auto uniform = [&rng](SimTime lo, SimTime hi) {
    return SimTime(std::uniform_int_distribution<std::int64_t>(lo.count(), hi.count())(rng));
  };
  std::vector<Action> actions;
  const SimTime guard = jitter + 10min;
  SimTime t = start + uniform(1h, 4h);
  while (t < end - 2h) {
    const auto m = std::uniform_int_distribution<std::size_t>(0, managers.size() - 1)(rng);
    const auto pause = uniform(1min, 20min);
    bool clear = true;
    if (managers[m].simulation) clear = next_moment(moments, t - guard) > t + pause + restart + guard;
    for (const auto& f : managers[m].furniture) clear &= next_moment(moments, t - guard, f) > t + pause + restart + guard;
    if (clear) {
      actions.push_back({Action::kill, t, m, 0});
      actions.push_back({Action::restart, t + pause, m, 0});
      t += pause + restart + uniform(2h, 8h);
    } else {
      t += uniform(10min, 1h);  // try again a little later
    }
  }
  return actions;
}

// --- The trace ---------------------------------------------------------------------------------------

std::string str(const json& j, const char* key) {
  return j.contains(key) && j[key].is_string() ? j[key].get<std::string>() : "";
}

struct TaskRun {
  std::string task;
  SimTime started{0}, stopped = SimTime::max();  // max: still running at the end
};

}  // namespace

TEST(IcarsSoak, AWeekWithDeviceManagersKilledAndRestarted) {
  const auto s = settings_from_environment();
  std::printf("[soak] seed %llu (ICARS_SOAK_SEED=%llu to repeat), %d days at %.0fx, %s build\n",
              static_cast<unsigned long long>(s.seed), static_cast<unsigned long long>(s.seed), s.days, s.speed,
              kAsan ? "ASan" : "non-ASan");
  std::mt19937_64 rng(s.seed);
  const auto wall_start = std::chrono::steady_clock::now();

  const fs::path dir = s.keep.empty() ? fs::path(::testing::TempDir()) / fmt::format("icars_soak_{}", ::getpid())
                                      : fs::path(s.keep);
  fs::create_directories(dir);
  std::printf("[soak] logs and trace in %s (kept when the test fails)\n", dir.c_str());
  const auto trace_file = dir / "trace.jsonl";

  // The paper house's devices over three managers: the robot's four; the living room's; the
  // bedroom's with the speech and vision engines and the Simulation device (the house's clock).
  const auto house = sim::load_house(kHouse);
  std::vector<Manager> managers(3);
  managers[0].name = "robot";
  managers[1].name = "living";
  managers[2].name = "bedroom";
  managers[2].simulation = true;
  std::set<std::string> sensed;
  for (const auto& d : house.devices) {
    auto& m = !d.carrier.empty() ? managers[0] : d.room == "living_room" ? managers[1] : managers[2];
    m.devices.push_back(d.id);
    if (d.params.contains("furniture")) {
      m.furniture.insert(d.params.at("furniture"));
      sensed.insert(d.params.at("furniture"));
    }
  }
  for (auto& m : managers) m.expected_devices = m.devices.size() + (m.simulation ? 3 : 0);  // + 2 engines, Simulation
  const auto moments = occupancy_moments(house, sensed);
  ASSERT_FALSE(moments.empty());
  SimTime jitter{0};
  for (const auto& u : house.users) jitter = std::max(jitter, u.time_jitter);

  // ASan keeps freed memory in a quarantine (256 MiB by default) before reusing it, so the RSS of
  // a busy process climbs for hours before it levels off. A 16 MiB quarantine fills within the
  // first simulated day, which keeps use-after-free detection and makes RSS comparable later on.
  const char* inherited = std::getenv("ASAN_OPTIONS");
  const std::string asan = std::string("ASAN_OPTIONS=") + (inherited != nullptr ? std::string(inherited) + ":" : "") +
                           "detect_leaks=1:quarantine_size_mb=16";
  const std::vector<std::string> env = {asan};

  // --- The server: it stops by itself at 18:00 of the last day. ---
  const SimTime start = house.start_time;
  const SimTime end = start + sim::kDay * s.days;  // the house starts at 18:00: --until 18:00
  ASSERT_EQ(start % sim::kDay, 18h) << "the soak's days run 18:00 to 18:00";
  Program server(dir / "icars.stderr", env,
                 {kIcars, "run", kPolicy, "--world", kHouse, "--external", "--listen", "127.0.0.1:0", "--speed",
                  fmt::format("{}", s.speed), "--until", "18:00", "--days", std::to_string(s.days), "--quiet",
                  "--trace", trace_file.string()});
  std::vector<std::string> server_output;
  std::string port;
  const std::string prefix = "[icars] mediating server on 127.0.0.1:";
  ASSERT_TRUE(planet_test::wait_until([&] {
    for (auto& line : server.lines()) {
      if (line.starts_with(prefix)) port = line.substr(prefix.size(), line.find(';') - prefix.size());
      server_output.push_back(std::move(line));
    }
    return !port.empty() || server.exited();
  }, 60s)) << "the server did not start; its stderr:\n" << tail(server.stderr_text());
  ASSERT_FALSE(port.empty()) << "the server exited; its stderr:\n" << tail(server.stderr_text());

  // --- One simulated clock for all: every manager maps the wall clock to simulated time from the
  // same epoch, so a restarted manager resumes where the others are. ---
  const auto wall_ms = [] {
    return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
        .count();
  };
  const std::int64_t epoch = wall_ms() + 3000;  // time for every manager to start and register
  const auto sim_now = [&] {
    return start + SimTime(static_cast<std::int64_t>(static_cast<double>(wall_ms() - epoch) * s.speed));
  };
  const auto launch = [&](Manager& m) {
    std::string devices;
    for (const auto& d : m.devices) devices += (devices.empty() ? "" : ",") + d;
    std::vector<std::string> argv = {kDeviceManager, "--house", kHouse, "--server", "127.0.0.1:" + port, "--devices",
                                     devices, "--speedup", fmt::format("{}", s.speed), "--pun", m.name, "--epoch",
                                     std::to_string(epoch)};
    if (!m.simulation) argv.insert(argv.end(), {"--no-engines", "--no-simulator"});
    m.process = std::make_unique<Program>(dir / fmt::format("{}-{}.stderr", m.name, ++m.incarnation), env, argv);
    m.registered = false;
    m.started_wall = std::chrono::steady_clock::now();
  };
  for (auto& m : managers) launch(m);

  // Reads every process's output: registrations, and the server's summary.
  std::vector<std::string> failures;
  const auto pump = [&] {
    for (auto& line : server.lines()) server_output.push_back(std::move(line));
    for (auto& m : managers) {
      if (!m.process) continue;
      for (const auto& line : m.process->lines()) {
        if (!line.starts_with("REGISTERED ")) continue;
        const auto devices = std::stoul(line.substr(line.rfind(' ') + 1));
        if (devices != m.expected_devices) {
          failures.push_back(fmt::format("{} registered {} devices, expected {}", m.name, devices, m.expected_devices));
        }
        if (m.registered) continue;  // a later round: it reconnected by itself
        m.registered = true;
        ++m.registrations;
        if (m.incarnation > 1) {
          m.reregistration_ms.push_back(
              std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - m.started_wall).count());
          m.outages.emplace_back(m.down_since, sim_now());
        }
      }
    }
  };
  ASSERT_TRUE(planet_test::wait_until([&] {
    pump();
    return std::all_of(managers.begin(), managers.end(), [](const Manager& m) { return m.registered; });
  }, 60s)) << "the device managers did not register";

  // --- The plan: kills and restarts, and a memory sample every day at 12:00. ---
  const SimTime restart_allowance(static_cast<std::int64_t>(2000 * s.speed));  // 2 s of wall time
  auto actions = s.kills ? plan(rng, managers, moments, start, end, restart_allowance, jitter) : std::vector<Action>{};
  for (int day = 1; day <= s.days; ++day) actions.push_back({Action::sample, start + sim::kDay * day - 6h, 0, day});
  std::stable_sort(actions.begin(), actions.end(), [](const Action& a, const Action& b) { return a.at < b.at; });

  std::map<int, Memory> memory;
  bool server_gone = false;
  // A manager that dies by itself ends the run: it says why in its stderr.
  const auto crashed = [&]() -> const Manager* {
    for (const auto& m : managers) {
      if (m.process && m.process->exited()) return &m;
    }
    return nullptr;
  };
  for (const auto& action : actions) {
    while (sim_now() < action.at && !(server_gone = server.exited())) {
      pump();
      if (const auto* m = crashed()) {
        FAIL() << m->name << " (incarnation " << m->incarnation << ") died by itself at "
               << sim::format_time(sim_now()) << "; its stderr:\n" << tail(m->process->stderr_text(), 60);
      }
      std::this_thread::sleep_for(2ms);
    }
    if (server_gone) break;
    auto& m = managers[action.manager];
    switch (action.kind) {
      case Action::sample:
        memory[action.day] = read_memory(server.pid());
        break;
      case Action::kill:
        if (!m.registered) failures.push_back(fmt::format("{} had not registered again before the next kill", m.name));
        m.process->signal(SIGKILL);
        m.process.reset();  // reaps it
        m.down_since = sim_now();
        ++m.kills;
        break;
      case Action::restart:
        launch(m);
        break;
    }
  }

  // --- The end: the server stops by itself; then the managers, on SIGTERM. ---
  const auto end_wall_bound = std::chrono::steady_clock::now() + 120s +
      std::chrono::milliseconds(static_cast<std::int64_t>(static_cast<double>((end - sim_now()).count()) / s.speed));
  while (!server.exited() && std::chrono::steady_clock::now() < end_wall_bound) {
    pump();
    std::this_thread::sleep_for(5ms);
  }
  ASSERT_TRUE(server.exited()) << "the server did not stop at the end of day " << s.days;
  pump();
  const int server_status = server.wait();
  for (auto& line : server.lines()) server_output.push_back(std::move(line));
  for (auto& m : managers) {
    if (!m.registered) failures.push_back(fmt::format("{} did not register again after its last restart", m.name));
    m.process->signal(SIGTERM);
  }
  std::map<std::string, int> manager_status;
  for (auto& m : managers) {
    EXPECT_TRUE(planet_test::wait_until([&] { return m.process->exited(); }, 60s)) << m.name << " ignored SIGTERM";
    manager_status[m.name] = m.process->wait();
  }
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();

  // --- What the server did, from its trace. ---
  std::vector<json> trace;
  {
    std::ifstream in(trace_file);
    for (std::string line; std::getline(in, line);) {
      if (!line.empty()) trace.push_back(json::parse(line));
    }
  }
  const auto day_of = [&](SimTime t) { return static_cast<int>((t - start) / sim::kDay) + 1; };  // 18:00 to 18:00
  std::map<int, std::map<std::string, int>> tasks_per_day;   // day -> task -> runs started
  std::map<int, std::map<std::string, int>> states_per_day;  // day -> state -> times entered
  std::map<int, int> behaviors_per_day, failed_per_day, heard_per_day, waypoints_per_day;
  std::vector<TaskRun> runs;
  std::map<std::string, std::size_t> open_run;        // task -> index in runs
  std::map<std::string, std::vector<SimTime>> running;  // behavior path -> start times not yet ended
  std::vector<std::string> stuck;
  for (const auto& r : trace) {
    const SimTime t(r.value("t", std::int64_t{0}));
    const auto kind = str(r, "kind");
    const auto event = str(r, "event");
    if (kind == "state" && event == "enter") ++states_per_day[day_of(t)][str(r, "state")];
    if (kind == "speech") ++heard_per_day[day_of(t)];
    if (kind == "event" && event == "WaypointReached") ++waypoints_per_day[day_of(t)];
    if (kind == "task" && event == "start") {
      const auto task = str(r, "task");
      ++tasks_per_day[day_of(t)][task];
      open_run[task] = runs.size();
      runs.push_back({task, t});
    } else if (kind == "task" && event == "stop") {
      const auto task = str(r, "task");
      if (open_run.contains(task)) runs[open_run[task]].stopped = t;
      open_run.erase(task);
      // No behavior of the task runs on after it (a behavior's path starts with its task's root).
      for (const auto& [path, starts] : running) {
        if (!starts.empty() && path.starts_with(task + "/")) {
          stuck.push_back(fmt::format("behavior {} (started {}) still running when task {} stopped at {}", path,
                                      sim::format_time(starts.front()), task, sim::format_time(t)));
        }
      }
    } else if (kind == "behavior") {
      const auto path = str(r, "source");
      if (event == "start") {
        running[path].push_back(t);
        ++behaviors_per_day[day_of(t)];
      } else if ((event == "success" || event == "failure" || event == "halt") && !running[path].empty()) {
        failed_per_day[day_of(t)] += event == "failure";
        running[path].erase(running[path].begin());
      }
    }
  }
  for (const auto& [path, starts] : running) {
    for (const auto& at : starts) stuck.push_back(fmt::format("behavior {} started {} never ended", path, sim::format_time(at)));
  }
  // A task of this policy ends at the latest when a sensor next sees the user sit, lie down or get
  // up (RestMode and SleepMode on UserLeft, Observation on TimeToRest/Sleep, Standby on
  // SituationChanged). One still running 45 simulated minutes after that moment (plus the
  // schedule's jitter and the user's walk) is stuck. The moment that started a task lies within
  // 15 minutes of its start (jitter, the walk, the mediator's clock following the house's by a
  // poll), and the moments are at least 30 minutes apart. The run ends during Observation.
  const SimTime slack = jitter + 45min;
  for (const auto& run : runs) {
    const auto limit = next_moment(moments, run.started + 15min) + slack;
    if (run.stopped > limit && limit < end) {
      stuck.push_back(fmt::format("task {} started {} still running at {} (the user's situation changed at {})", run.task,
                                  sim::format_time(run.started),
                                  run.stopped == SimTime::max() ? std::string("the end") : sim::format_time(run.stopped),
                                  sim::format_time(limit - slack)));
    }
  }

  // --- The figures. ---
  int kills = 0, registrations = 0;
  std::vector<double> rereg;
  for (const auto& m : managers) {
    kills += m.kills;
    registrations += m.registrations - 1;
    rereg.insert(rereg.end(), m.reregistration_ms.begin(), m.reregistration_ms.end());
  }
  std::sort(rereg.begin(), rereg.end());
  std::printf("[soak] day  RSS MiB  HWM MiB  tasks started (Observation/RestMode/SleepMode/Standby)  behaviors "
              "(failed)  heard  waypoints\n");
  json report;
  for (int day = 1; day <= s.days; ++day) {
    auto& t = tasks_per_day[day];
    std::printf("[soak] %3d  %7.2f  %7.2f  %d/%d/%d/%d  %d (%d)  %d  %d\n", day, memory[day].rss_mib,
                memory[day].hwm_mib, t["Observation"], t["RestMode"], t["SleepMode"], t["Standby"],
                behaviors_per_day[day], failed_per_day[day], heard_per_day[day], waypoints_per_day[day]);
    report["days"].push_back({{"day", day}, {"rss_mib", memory[day].rss_mib}, {"hwm_mib", memory[day].hwm_mib},
                              {"tasks", t}, {"behaviors", behaviors_per_day[day]}, {"failed", failed_per_day[day]},
                              {"heard", heard_per_day[day]},
                              {"waypoints", waypoints_per_day[day]}});
  }
  for (const auto& m : managers) {
    std::printf("[soak] %-8s killed %d times, registered again %d times; outages (simulated):", m.name.c_str(), m.kills,
                m.registrations - 1);
    for (const auto& [from, to] : m.outages) std::printf(" %s-%s", sim::format_time(from).c_str(), sim::format_time(to).substr(3).c_str());
    std::printf("\n");
  }
  std::printf("[soak] %d kills, %d re-registrations (median %.0f ms, max %.0f ms after the restart), "
              "%zu trace records, wall time %.1f s\n",
              kills, registrations, rereg.empty() ? 0.0 : rereg[rereg.size() / 2], rereg.empty() ? 0.0 : rereg.back(),
              trace.size(), wall_s);
  report["seed"] = s.seed;
  report["speed"] = s.speed;
  report["kills"] = kills;
  report["reregistrations"] = registrations;
  report["wall_s"] = wall_s;
  std::ofstream(dir / "soak.json") << report.dump(2) << "\n";

  // --- The checks. ---
  for (const auto& f : failures) ADD_FAILURE() << f;
  const auto server_log = server.stderr_text();
  EXPECT_TRUE(WIFEXITED(server_status) && WEXITSTATUS(server_status) == 0)
      << "server: " << describe_status(server_status) << "; its stderr:\n" << tail(server_log);
  EXPECT_FALSE(sanitizer_report(server_log)) << "the server's stderr has a sanitizer report:\n" << tail(server_log, 60);
  EXPECT_TRUE(std::any_of(server_output.begin(), server_output.end(),
                          [](const std::string& l) { return l.starts_with("=== summary"); }))
      << "no summary from the server";
  for (const auto& m : managers) {
    const int status = manager_status[m.name];
    const auto log = m.process->stderr_text();
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0)
        << m.name << ": " << describe_status(status) << "; its stderr:\n" << tail(log);
    EXPECT_FALSE(sanitizer_report(log)) << m.name << "'s stderr has a sanitizer report:\n" << tail(log, 60);
  }
  if (s.kills) {
    EXPECT_GE(kills, s.days / 2) << "too few kills to call this a soak";
  }
  EXPECT_EQ(registrations, kills) << "every restarted device manager registers again";
  for (int day = 1; day <= s.days; ++day) {
    for (const char* state : {"Observation", "RestMode", "SleepMode"}) {
      EXPECT_GE(states_per_day[day][state], 1) << "day " << day << " never entered " << state;
    }
  }
  for (const auto& line : stuck) ADD_FAILURE() << "stuck: " << line;
  // Memory is flat when day 7's RSS is within max(+10%, +4 MiB) of day 2's. Day 1 still warms
  // up (first connections, caches, ASan's quarantine filling); after that, ASan's allocator keeps
  // freed chunks in per-size-class free lists that it does not give back to the system, so RSS
  // steps by up to a few MiB with the mix of allocations; a leak of the trace's size (a few
  // hundred bytes per record, thousands of records a day) grows it steadily past this bound.
  ASSERT_TRUE(memory.contains(2) && memory.contains(s.days)) << "memory was not sampled every day";
  const double base = memory[2].rss_mib, last = memory[s.days].rss_mib;
  EXPECT_GT(base, 0);
  EXPECT_LE(last, std::max(base * 1.10, base + 4.0))
      << fmt::format("the server's RSS grew from {:.2f} MiB on day 2 to {:.2f} MiB on day {}", base, last, s.days);
  if (s.keep.empty() && !::testing::Test::HasFailure()) fs::remove_all(dir);
}
