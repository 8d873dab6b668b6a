#include "house_processes.h"

#include "announcement.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <random>
#include <thread>

namespace icars_test {

namespace sim = icars::sim;
using namespace std::chrono_literals;

std::string read_file(const fs::path& path) {
  std::ifstream in(path);
  return {std::istreambuf_iterator<char>(in), {}};
}

std::string tail(const std::string& text, std::size_t lines) {
  std::size_t at = text.size();
  for (std::size_t n = 0; n <= lines && at != std::string::npos && at > 0; ++n) at = text.rfind('\n', at - 1);
  return at == std::string::npos || at >= text.size() ? text : text.substr(at + 1);
}

bool sanitizer_report(const std::string& log) {
  return log.find("ERROR: LeakSanitizer") != std::string::npos ||
         log.find("ERROR: AddressSanitizer") != std::string::npos ||
         log.find("runtime error:") != std::string::npos;
}

std::string describe_status(int status) {
  if (WIFEXITED(status)) return fmt::format("exit status {}", WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return fmt::format("killed by signal {}", WTERMSIG(status));
  return fmt::format("wait status {}", status);
}

std::vector<std::string> exit_problems(const std::string& who, int status, const std::string& log) {
  std::vector<std::string> out;
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    out.push_back(fmt::format("{}: {}; its stderr:\n{}", who, describe_status(status), tail(log)));
  }
  if (sanitizer_report(log)) out.push_back(fmt::format("{}'s stderr has a sanitizer report:\n{}", who, tail(log, 60)));
  return out;
}

fs::path run_directory(const std::string& keep, const std::string& name) {
  const fs::path dir = keep.empty() ? fs::path(::testing::TempDir()) / fmt::format("{}_{}", name, ::getpid()) : fs::path(keep);
  fs::create_directories(dir);
  return dir;
}

std::vector<std::string> mediator_command(const std::string& icars, const std::string& policy,
                                          const std::string& house, double speed, int days, const fs::path& trace) {
  return {icars,     "run",     policy,  "--world", house,    "--external", "--listen", "127.0.0.1:0",
          "--speed", fmt::format("{}", speed), "--until", "18:00", "--days", std::to_string(days), "--quiet",
          "--trace", trace.string()};
}

std::optional<std::string> environment_variable(const char* name) {
  const char* v = std::getenv(name);
  if (v == nullptr || *v == '\0') return std::nullopt;
  return std::string(v);
}

RunSettings run_settings(const std::string& prefix, const std::string& toggle, int min_days,
                         const std::string& why_min_days) {
  RunSettings s;
  s.seed = std::random_device{}();
  const auto var = [&prefix](const char* name) { return environment_variable((prefix + "_" + name).c_str()); };
  try {
    if (auto v = var("SEED")) s.seed = std::stoull(*v);
    if (auto v = var("DAYS")) s.days = std::stoi(*v);
    if (auto v = var("SPEED")) s.speed = std::stod(*v);
  } catch (const std::exception&) {
    throw std::invalid_argument(fmt::format("{0}_SEED, {0}_DAYS and {0}_SPEED must be numbers", prefix));
  }
  if (s.days < min_days) {
    throw std::invalid_argument(fmt::format("{}_DAYS must be at least {}{}", prefix, min_days, why_min_days));
  }
  if (s.speed < 1 || s.speed > 20000) throw std::invalid_argument(prefix + "_SPEED must be 1 to 20000");
  if (auto v = var("KEEP")) s.keep = *v;
  if (auto v = var(toggle.c_str())) s.enabled = *v != "0";
  return s;
}

std::vector<std::string> child_environment() {
  const char* inherited = std::getenv("ASAN_OPTIONS");
  return {std::string("ASAN_OPTIONS=") + (inherited != nullptr ? std::string(inherited) + ":" : "") +
          "detect_leaks=1:quarantine_size_mb=16"};
}

// --- Program ---------------------------------------------------------------------------------------

Program::Program(fs::path log, const std::vector<std::string>& env, const std::vector<std::string>& argv)
    : log_(std::move(log)) {
  // `bash` and `env` replace themselves by the program (exec), so the pid is the program's. bash
  // first closes every descriptor above stderr (posix_spawn passes on those without O_CLOEXEC).
  std::vector<std::string> all = {
      "/bin/bash", "-c",
      "log=$1; shift; for fd in /proc/self/fd/*; do fd=${fd##*/}; if [ \"$fd\" -gt 2 ]; then eval \"exec $fd>&-\"; "
      "fi; done 2>/dev/null; exec \"$@\" 2>\"$log\"",
      "bash", log_.string(), "/usr/bin/env"};
  all.insert(all.end(), env.begin(), env.end());
  all.insert(all.end(), argv.begin(), argv.end());
  process_ = std::make_unique<planet_test::ChildProcess>(all);
}

std::vector<std::string> Program::lines() {
  std::vector<std::string> out;
  while (auto line = process_->read_line(2ms)) out.push_back(std::move(*line));
  return out;
}

bool Program::exited() const {
  std::ifstream stat("/proc/" + std::to_string(pid()) + "/stat");
  std::string text;
  if (!std::getline(stat, text)) return true;
  const auto paren = text.rfind(')');
  return paren == std::string::npos || paren + 2 >= text.size() || text[paren + 2] == 'Z';
}

std::string start_mediator(Program& server, std::vector<std::string>& output) {
  std::string port;
  planet_test::wait_until([&] {
    for (auto& line : server.lines()) {
      if (port.empty()) port = icars::app::announced_port(line);
      output.push_back(std::move(line));
    }
    return !port.empty() || server.exited();
  }, 60s);
  return port;
}

// --- The house on a shared clock -----------------------------------------------------------------

std::int64_t SharedClock::wall_ms() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

icars::Time SharedClock::now() const {
  return start + icars::Time(static_cast<std::int64_t>(static_cast<double>(wall_ms() - epoch_ms) * speed));
}

std::chrono::milliseconds SharedClock::wall(icars::Time simulated) const {
  return std::chrono::milliseconds(static_cast<std::int64_t>(static_cast<double>(simulated.count()) / speed));
}

std::vector<std::string> Manager::command(const std::string& device_manager, const std::string& house_file,
                                          const std::string& server, const SharedClock& clock) const {
  std::string list;
  for (const auto& d : devices) list += (list.empty() ? "" : ",") + d;
  std::vector<std::string> argv = {device_manager, "--house", house_file, "--server", server, "--devices", list,
                                   "--speedup", fmt::format("{}", clock.speed), "--pun", name, "--epoch",
                                   std::to_string(clock.epoch_ms)};
  if (!simulation) argv.insert(argv.end(), {"--no-engines", "--no-simulator"});
  return argv;
}

void Manager::launch(const fs::path& dir, const std::vector<std::string>& env, const std::vector<std::string>& argv) {
  process = std::make_unique<Program>(dir / fmt::format("{}-{}.stderr", name, ++incarnation), env, argv);
  registered = false;
  started_wall = std::chrono::steady_clock::now();
}

void Manager::read_output(icars::Time now, std::vector<std::string>& failures) {
  if (!process) return;
  for (const auto& line : process->lines()) {
    if (line.starts_with("STATE ")) state_lines.push_back(line);
    if (!line.starts_with("REGISTERED ")) continue;
    ++rounds;
    const auto count = std::stoul(line.substr(line.rfind(' ') + 1));
    if (count != expected_devices) {
      failures.push_back(fmt::format("{} registered {} devices, expected {}", name, count, expected_devices));
    }
    if (registered) continue;  // a later round: it reconnected by itself
    registered = true;
    ++registrations;
    if (incarnation > 1) {
      reregistration_ms.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - started_wall).count());
      outages.emplace_back(down_since, now);
    }
  }
}

void wait_for_end(Program& mediator, const SharedClock& clock, icars::Time end, const std::function<void()>& pump) {
  const auto bound = std::chrono::steady_clock::now() + 120s + clock.wall(std::max(end - clock.now(), icars::Time(0)));
  while (!mediator.exited() && std::chrono::steady_clock::now() < bound) {
    pump();
    std::this_thread::sleep_for(5ms);
  }
}

std::map<std::string, int> stop_managers(std::vector<Manager>& managers, std::vector<std::string>& failures) {
  for (auto& m : managers) m.process->signal(SIGTERM);
  std::map<std::string, int> status;
  for (auto& m : managers) {
    if (!planet_test::wait_until([&] { return m.process->exited(); }, 60s)) {
      failures.push_back(m.name + " ignored SIGTERM");
    }
    status[m.name] = m.process->wait();
  }
  return status;
}

std::vector<Manager> split_paper_house(const sim::House& house) {
  std::vector<Manager> managers(3);
  managers[0].name = "robot";
  managers[1].name = "living";
  managers[2].name = "bedroom";
  managers[2].simulation = true;
  for (const auto& d : house.devices) {
    auto& m = !d.carrier.empty() ? managers[0] : d.room == "living_room" ? managers[1] : managers[2];
    m.devices.push_back(d.id);
    if (d.params.contains("furniture")) m.furniture.insert(d.params.at("furniture"));
  }
  for (auto& m : managers) m.expected_devices = m.devices.size() + (m.simulation ? 3 : 0);  // + 2 engines, Simulation
  return managers;
}

std::set<std::string> sensed_furniture(const std::vector<Manager>& managers) {
  std::set<std::string> out;
  for (const auto& m : managers) out.insert(m.furniture.begin(), m.furniture.end());
  return out;
}

std::vector<Moment> occupancy_moments(const sim::House& house, const std::set<std::string>& sensed) {
  std::vector<Moment> out;
  for (const auto& user : house.users) {
    const auto& entries = user.schedule;
    for (std::size_t i = 0; i < entries.size(); ++i) {
      const auto& e = entries[i];
      if ((e.activity != sim::Activity::sit && e.activity != sim::Activity::lie) || !sensed.contains(e.target)) continue;
      out.push_back({e.target, e.at, true});
      for (std::size_t j = 1; j <= entries.size(); ++j) {  // the next movement ends it (maybe tomorrow)
        const auto& next = entries[(i + j) % entries.size()];
        if (next.activity == sim::Activity::say) continue;
        out.push_back({e.target, next.at, false});
        break;
      }
    }
  }
  return out;
}

icars::Time next_moment(const std::vector<Moment>& moments, icars::Time t, const std::string& furniture) {
  icars::Time best = icars::Time::max();
  for (const auto& m : moments) {
    if (!furniture.empty() && m.furniture != furniture) continue;
    auto at = icars::kDay * (t / icars::kDay) + m.time_of_day;
    if (at <= t) at += icars::kDay;
    best = std::min(best, at);
  }
  return best;
}

icars::Time schedule_jitter(const sim::House& house) {
  icars::Time jitter{0};
  for (const auto& u : house.users) jitter = std::max(jitter, u.time_jitter);
  return jitter;
}

PaperHouse load_paper_house(const std::string& house_file) {
  PaperHouse out;
  out.house = sim::load_house(house_file);
  out.managers = split_paper_house(out.house);
  out.moments = occupancy_moments(out.house, sensed_furniture(out.managers));
  out.jitter = schedule_jitter(out.house);
  return out;
}

// --- The trace -------------------------------------------------------------------------------------

std::vector<json> read_json_lines(const fs::path& path) {
  std::vector<json> out;
  std::ifstream in(path);
  for (std::string line; std::getline(in, line);) {
    if (!line.empty()) out.push_back(json::parse(line));
  }
  return out;
}

std::vector<json> JsonLinesTail::read() {
  std::vector<json> out;
  std::ifstream in(path_, std::ios::binary);
  if (!in) return out;
  in.seekg(offset_);
  std::string added((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  offset_ += static_cast<std::streamoff>(added.size());
  partial_ += added;
  std::size_t begin = 0;
  for (auto end = partial_.find('\n'); end != std::string::npos; end = partial_.find('\n', begin)) {
    if (end > begin) out.push_back(json::parse(partial_.begin() + static_cast<std::ptrdiff_t>(begin),
                                               partial_.begin() + static_cast<std::ptrdiff_t>(end)));
    begin = end + 1;
  }
  partial_.erase(0, begin);
  return out;
}

std::string str(const json& j, const char* key) {
  return j.contains(key) && j[key].is_string() ? j[key].get<std::string>() : "";
}

TaskTimeline follow_tasks(const std::vector<json>& trace) {
  TaskTimeline out;
  std::map<std::string, std::size_t> open_run;          // task -> index in runs
  std::map<std::string, std::vector<icars::Time>> running;  // behavior path -> start times not yet ended
  for (const auto& r : trace) {
    const icars::Time t(r.value("t", std::int64_t{0}));
    const auto kind = str(r, "kind");
    const auto event = str(r, "event");
    if (kind == "task" && event == "start") {
      const auto task = str(r, "task");
      open_run[task] = out.runs.size();
      out.runs.push_back({task, t});
    } else if (kind == "task" && event == "stop") {
      const auto task = str(r, "task");
      if (open_run.contains(task)) out.runs[open_run[task]].stopped = t;
      open_run.erase(task);
      for (const auto& [path, starts] : running) {
        if (!starts.empty() && path.starts_with(task + "/")) {
          out.stuck.push_back(fmt::format("behavior {} (started {}) still running when task {} stopped at {}", path,
                                          icars::format_time(starts.front()), task, icars::format_time(t)));
        }
      }
    } else if (kind == "behavior") {
      const auto path = str(r, "source");
      if (event == "start") {
        running[path].push_back(t);
      } else if ((event == "success" || event == "failure" || event == "halt") && !running[path].empty()) {
        running[path].erase(running[path].begin());
      }
    }
  }
  for (const auto& [path, starts] : running) {
    for (const auto& at : starts) {
      out.stuck.push_back(fmt::format("behavior {} started {} never ended", path, icars::format_time(at)));
    }
  }
  return out;
}

void find_overdue_tasks(TaskTimeline& timeline, const std::function<icars::Time(icars::Time)>& next_change, icars::Time slack,
                        icars::Time end) {
  for (const auto& run : timeline.runs) {
    const auto limit = next_change(run.started + 15min) + slack;
    if (run.stopped > limit && limit < end) {
      timeline.stuck.push_back(fmt::format(
          "task {} started {} still running at {} (the user's situation changed at {})", run.task,
          icars::format_time(run.started),
          run.stopped == icars::Time::max() ? std::string("the end") : icars::format_time(run.stopped),
          icars::format_time(limit - slack)));
    }
  }
}

}  // namespace icars_test
