// Memory footprint of the real programs: the peak resident set (VmHWM) of a device-side process
// hosting a robot's four devices (target < 8 MiB), and of the mediating server with 100
// registered devices (target < 64 MiB).
//
//   icars-footprint [--runs 3] [--settle 19:00] [--speedup 600] [--devices 100] [--spread 25]
//                   [--json FILE]
//
// Each run starts `icars run paper_home --external` and device managers (icars-device-manager)
// as child processes on loopback, in three scenarios:
//   paper house  the paper's house: one device manager for the robot's four devices (--devices
//                robot1_wheels,... --no-engines --no-simulator; the measured device side) and
//                one for the rest (static devices, speech and vision engines, Simulation), plus
//                a minimal PLANET process (this program's --planet-client mode: one Communicator
//                connected to the server, no devices);
//   100 devices  the same house with extra static devices (Light, MotionSensor, Speaker, TV,
//                Clock, Microphone, Camera) generated into a temporary directory, registered by
//                the same two device managers: --devices devices in all;
//   spread       those devices over --spread device managers (the robot's, then four each), so
//                the server holds one connection per manager.
// Each scenario waits until every device manager printed "REGISTERED 1 N" (the server accepted
// its devices), the minimal process printed "CONNECTED", and the server's timeline shows a
// record at or after --settle (simulated time of day; by 19:00 the policy has run for an hour
// from 18:00: the user sat down, RestMode, the robot drove to the user, voice commands turned
// the TV on and started music). Then it reads VmHWM, VmRSS, RssAnon, RssFile and Threads from
// /proc/PID/status of the processes, back to back, and kills them.
// Prints the median, minimum and maximum over the runs; --json also writes
// {"rows":[{"layer":"footprint","workload":...,"value":median MiB,"unit":"MiB","min":...,
// "max":...,"runs":N,"target":MiB}, ...]} (context rows have no "target"). Children's stderr
// goes to log files in a temporary directory, quoted when a child does not print what is
// awaited.
#include <fmt/format.h>
#include <signal.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <numeric>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "announcement.h"
#include "child_process.h"
#include "icars/clock/time.h"
#include "icars/planet/communicator.h"
#include "icars/planet/endpoint.h"
#include "icars/sim/house.h"

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

const std::string kIcars = ICARS_BINARY;
const std::string kDeviceManager = ICARS_DEVICE_MANAGER_BINARY;
const std::string kHouse = std::string(ICARS_HOUSES_DIR) + "/paper_house.xml";
const std::string kPolicy = std::string(ICARS_POLICIES_DIR) + "/paper_home.xml";

// Generous bounds: a loaded 2-core machine; every wait ends on a printed line.
constexpr auto kStartBound = 60s;
constexpr auto kSettleBound = 180s;

// --planet-client: the smallest PLANET process, a Communicator connected to a server.
int planet_client(const std::string& endpoint) {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  const auto [host, port] = icars::planet::parse_endpoint(endpoint);
  icars::planet::CommunicatorOptions options;
  options.name = "footprint";
  icars::planet::Communicator communicator(options);
  const auto peer = communicator.connect(host, port);
  if (!peer->wait_connected(kStartBound)) {
    std::fprintf(stderr, "icars-footprint: cannot connect to %s: %s\n", endpoint.c_str(), peer->last_error().c_str());
    return 1;
  }
  std::printf("CONNECTED\n");
  std::fflush(stdout);
  int sig = 0;
  sigwait(&signals, &sig);
  return 0;
}

// --- Reading /proc ------------------------------------------------------------------------------

struct Sample {
  double hwm = 0, rss = 0, anon = 0, file = 0, threads = 0;  // MiB, MiB, MiB, MiB, count
};

Sample read_status(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  if (!in) throw std::runtime_error("cannot read /proc/" + std::to_string(pid) + "/status");
  Sample s;
  const std::map<std::string, double*> fields = {
      {"VmHWM:", &s.hwm}, {"VmRSS:", &s.rss}, {"RssAnon:", &s.anon}, {"RssFile:", &s.file}, {"Threads:", &s.threads}};
  for (std::string line; std::getline(in, line);) {
    std::istringstream words(line);
    std::string key;
    double value = 0;
    words >> key >> value;
    if (const auto f = fields.find(key); f != fields.end()) *f->second = key == "Threads:" ? value : value / 1024.0;
  }
  if (s.hwm == 0) throw std::runtime_error("no VmHWM in /proc/" + std::to_string(pid) + "/status (process gone?)");
  return s;
}

// --- Child processes ------------------------------------------------------------------------------

// A program started with its stderr in a log file (shown when it does not do what we wait for).
class Program {
 public:
  Program(std::string name, const fs::path& dir, std::vector<std::string> argv) : name_(std::move(name)) {
    log_ = dir / (name_ + ".log");
    // `sh` replaces itself by the program (exec), so the pid is the program's.
    std::vector<std::string> shell = {"/bin/sh", "-c", "log=$1; shift; exec \"$@\" 2>\"$log\"", "sh", log_.string()};
    shell.insert(shell.end(), argv.begin(), argv.end());
    process_ = std::make_unique<planet_test::ChildProcess>(shell);
  }

  // Reads stdout until a line satisfies `done`; throws naming `what` after `bound`.
  std::string expect(const std::function<bool(const std::string&)>& done, std::chrono::seconds bound,
                     const std::string& what) {
    const auto end = std::chrono::steady_clock::now() + bound;
    for (;;) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(end - std::chrono::steady_clock::now());
      if (left.count() <= 0) break;
      const auto line = process_->read_line(left);
      if (!line) break;  // EOF (it exited) or timeout
      if (done(*line)) return *line;
    }
    throw std::runtime_error(fmt::format("{} did not print {} within {} s; its stderr ({}):\n{}", name_, what,
                                         bound.count(), log_.string(), tail(log_)));
  }

  Sample sample() const { return read_status(process_->pid()); }

 private:
  static std::string tail(const fs::path& file) {
    std::ifstream in(file);
    std::vector<std::string> lines;
    for (std::string line; std::getline(in, line);) lines.push_back(line);
    std::string out;
    for (auto i = lines.size() > 20 ? lines.size() - 20 : 0; i < lines.size(); ++i) out += "  " + lines[i] + "\n";
    return out;
  }

  std::string name_;
  fs::path log_;
  std::unique_ptr<planet_test::ChildProcess> process_;  // killed (SIGKILL) and reaped on destruction
};

// --- The houses -----------------------------------------------------------------------------------

std::string read_text(const fs::path& file) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error("cannot read " + file.string());
  return {std::istreambuf_iterator<char>(in), {}};
}

// The paper house with `extra` more static devices, spread over its rooms, written to `out`.
void write_bigger_house(const icars::sim::House& house, std::size_t extra, const fs::path& out) {
  static const std::vector<std::string> kTypes = {"Light", "MotionSensor", "Speaker", "TV", "Clock", "Microphone", "Camera"};
  std::string devices = "\n  <!-- Generated by icars-footprint: extra static devices. -->\n";
  for (std::size_t i = 0; i < extra; ++i) {
    const auto& room = house.rooms[i % house.rooms.size()];
    const auto k = i / house.rooms.size();  // the k-th device in this room, on a 9 x 9 lattice
    const double fx = 0.1 + 0.1 * static_cast<double>(k % 9), fy = 0.1 + 0.1 * static_cast<double>((k / 9) % 9);
    const auto& type = kTypes[i % kTypes.size()];
    devices += fmt::format("  <device id=\"extra_{:03}\" type=\"{}\" room=\"{}\" x=\"{:.2f}\" y=\"{:.2f}\"/>\n", i,
                           type, room.name, room.area.min.x + fx * room.area.width(),
                           room.area.min.y + fy * room.area.height());
  }
  auto text = read_text(kHouse);
  const auto end = text.rfind("</house>");
  if (end == std::string::npos) throw std::runtime_error(kHouse + ": no </house>");
  text.insert(end, devices);
  std::ofstream(out) << text;
  icars::sim::load_house(out);  // validate now rather than in the device managers
}

std::string join(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& item : items) out += (out.empty() ? "" : ",") + item;
  return out;
}

// --- One scenario ---------------------------------------------------------------------------------

struct Options {
  int runs = 3;
  std::string settle = "19:00";
  double speedup = 600;
  std::size_t server_devices = 100;
  std::size_t spread = 25;  // device managers of the spread scenario; 0: skip it
  std::string json_file;
};

// One process's sample in one run, under the row it reports to.
struct Measured {
  std::string workload;
  std::optional<double> target;  // MiB; none for context rows
  Sample sample;
};

enum class Scenario {
  paper,   // the paper house; robot + house device managers and a minimal PLANET process
  big,     // --devices devices: robot + house device managers
  spread,  // --devices devices over --spread device managers (one connection each)
};

// The devices each device manager hosts: the first robot's devices alone, then the other
// devices and the engines and Simulation (three devices, hosted by the last manager) shared
// evenly by managers - 1 managers.
struct ManagerPlan {
  std::vector<std::string> devices;
  bool engines_and_simulator = false;
};
std::vector<ManagerPlan> plan_managers(const icars::sim::House& house, std::size_t managers) {
  std::vector<ManagerPlan> plan(managers);
  std::vector<std::string> others;
  for (const auto& d : house.devices) {
    (d.carrier == house.robots.at(0).id ? plan[0].devices : others).push_back(d.id);
  }
  const auto rest = managers - 1, slots = others.size() + 3;
  if (managers < 2 || slots / rest < 4) {  // the last has at least one house device
    throw std::invalid_argument(fmt::format("{} device managers cannot share {} devices that way", managers, slots));
  }
  for (std::size_t j = 0; j < rest; ++j) {
    for (auto i = j * slots / rest; i < std::min((j + 1) * slots / rest, others.size()); ++i) {
      plan[1 + j].devices.push_back(others[i]);
    }
  }
  plan.back().engines_and_simulator = true;
  return plan;
}

// The server and device managers on `house_file` (and in the paper scenario a minimal PLANET
// client); samples every process once the policy has run to the settle time.
void run_scenario(const fs::path& dir, const std::string& house_file, const Options& o, Scenario scenario,
                  std::vector<Measured>& out) {
  const auto house = icars::sim::load_house(house_file);
  const auto plan = plan_managers(house, scenario == Scenario::spread ? o.spread : 2);

  Program server("icars", dir, {kIcars, "run", kPolicy, "--world", house_file, "--external", "--listen",
                                "127.0.0.1:0", "--speed", fmt::format("{}", o.speedup), "--until", "07:30"});
  const auto listening = server.expect([&](const std::string& l) { return !icars::app::announced_port(l).empty(); },
                                       kStartBound, fmt::format("'{}HOST:PORT'", icars::app::kServerAnnouncement));
  const auto endpoint = "127.0.0.1:" + icars::app::announced_port(listening);

  std::vector<std::unique_ptr<Program>> managers;
  for (std::size_t i = 0; i < plan.size(); ++i) {
    const auto name = i == 0 ? std::string("robot") : fmt::format("house{}", i);
    std::vector<std::string> argv = {kDeviceManager, "--house", house_file, "--server", endpoint, "--devices",
                                     join(plan[i].devices), "--speedup", fmt::format("{}", o.speedup), "--pun", name};
    if (!plan[i].engines_and_simulator) argv.insert(argv.end(), {"--no-engines", "--no-simulator"});
    managers.push_back(std::make_unique<Program>(name + "-device-manager", dir, argv));
  }
  std::unique_ptr<Program> client;
  if (scenario == Scenario::paper) {
    client = std::make_unique<Program>("planet-client", dir,
                                       std::vector<std::string>{fs::read_symlink("/proc/self/exe").string(),
                                                                "--planet-client", endpoint});
  }
  const std::string registered_prefix = "REGISTERED 1 ";
  std::vector<std::size_t> registered;
  for (auto& manager : managers) {
    const auto line = manager->expect([&](const std::string& l) { return l.starts_with(registered_prefix); },
                                      kStartBound, "'REGISTERED 1 N'");
    registered.push_back(std::stoul(line.substr(registered_prefix.size())));
  }
  const auto total = std::accumulate(registered.begin(), registered.end(), std::size_t{0});
  if (scenario != Scenario::paper && total != o.server_devices) {
    throw std::logic_error(fmt::format("{} devices registered, expected {}", total, o.server_devices));
  }
  if (client) client->expect([](const std::string& l) { return l == "CONNECTED"; }, kStartBound, "CONNECTED");

  // The server's timeline lines start with "[dD HH:MM:SS"; wait for one at or after --settle,
  // the first such time of day after the house's start (as `icars run --until` counts).
  const auto day = icars::kDay * (house.start_time / icars::kDay);
  auto settle = day + *icars::parse_time_of_day(o.settle);
  if (settle <= house.start_time) settle += icars::kDay;
  const auto settle_s = settle.count() / 1000;
  server.expect(
      [&](const std::string& l) {
        int d = 0, h = 0, m = 0, s = 0;
        if (std::sscanf(l.c_str(), "[d%d %d:%d:%d", &d, &h, &m, &s) != 4) return false;
        return ((static_cast<std::int64_t>(d) * 24 + h) * 60 + m) * 60 + s >= settle_s;
      },
      kSettleBound, "a timeline record at or after " + o.settle);

  // Sampled back to back, before anything is stopped.
  switch (scenario) {
    case Scenario::paper:
      out.push_back({fmt::format("device manager, {} devices", registered[0]), 8.0, managers[0]->sample()});
      out.push_back({fmt::format("mediating server, {} devices", total), std::nullopt, server.sample()});
      out.push_back({fmt::format("device manager, {} devices (static, engines, Simulation)", registered[1]),
                     std::nullopt, managers[1]->sample()});
      out.push_back({"PLANET communicator, no devices", std::nullopt, client->sample()});
      break;
    case Scenario::big:
      out.push_back({fmt::format("mediating server, {} devices", total), 64.0, server.sample()});
      out.push_back({fmt::format("device manager, {} devices, {}-device house", registered[0], total), std::nullopt,
                     managers[0]->sample()});
      out.push_back({fmt::format("device manager, {} devices (static, engines, Simulation)", registered[1]),
                     std::nullopt, managers[1]->sample()});
      break;
    case Scenario::spread:
      out.push_back({fmt::format("mediating server, {} devices over {} device managers", total, managers.size()),
                     std::nullopt, server.sample()});
      break;
  }
}

// --- Report ---------------------------------------------------------------------------------------

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const auto n = v.size();
  return n % 2 == 1 ? v[n / 2] : (v[n / 2 - 1] + v[n / 2]) / 2;
}

int run(const Options& o) {
  const auto house = icars::sim::load_house(kHouse);
  const std::size_t base = house.devices.size() + 3;  // + speech and vision engines, Simulation
  if (o.server_devices < base) throw std::invalid_argument(fmt::format("--devices must be at least {}", base));

  const auto dir = fs::temp_directory_path() / fmt::format("icars-footprint-{}", ::getpid());
  fs::create_directories(dir);
  const auto big_house = dir / fmt::format("house_{}.xml", o.server_devices);
  write_bigger_house(house, o.server_devices - base, big_house);

  // Rows in the order of the first run: the two with a target first.
  std::vector<std::string> order;
  std::map<std::string, std::pair<std::optional<double>, std::vector<Sample>>> rows;
  for (int r = 0; r < o.runs; ++r) {
    std::vector<Measured> measured;
    run_scenario(dir, kHouse, o, Scenario::paper, measured);
    run_scenario(dir, big_house.string(), o, Scenario::big, measured);
    if (o.spread > 0) run_scenario(dir, big_house.string(), o, Scenario::spread, measured);
    for (auto& m : measured) {
      auto& row = rows[m.workload];
      if (row.second.empty() && r == 0) order.push_back(m.workload);
      row.first = m.target;
      row.second.push_back(m.sample);
    }
    std::fprintf(stderr, "run %d/%d done\n", r + 1, o.runs);
  }
  std::stable_partition(order.begin(), order.end(), [&](const std::string& w) { return rows[w].first.has_value(); });

  std::printf("Peak resident set (VmHWM) once the policy has run from the house's start to %s at %gx; median of %d runs, MiB\n",
              o.settle.c_str(), o.speedup, o.runs);
  std::printf("%-58s %7s %15s %7s %7s %7s %7s  %s\n", "workload", "VmHWM", "(min-max)", "VmRSS", "anon", "file",
              "threads", "target");
  nlohmann::ordered_json json_rows = nlohmann::ordered_json::array();
  for (const auto& workload : order) {
    const auto& [target, s] = rows[workload];
    auto field = [&s](double Sample::*member) {
      std::vector<double> v;
      for (const auto& x : s) v.push_back(x.*member);
      return v;
    };
    const auto hwm = field(&Sample::hwm);
    const double value = median(hwm);
    const double lo = *std::min_element(hwm.begin(), hwm.end()), hi = *std::max_element(hwm.begin(), hwm.end());
    const auto verdict = target ? fmt::format("< {:g} {}", *target, value < *target ? "ok" : "MISSED") : std::string();
    std::printf("%-58s %7.2f %15s %7.2f %7.2f %7.2f %7.0f  %s\n", workload.c_str(), value,
                fmt::format("({:.2f}-{:.2f})", lo, hi).c_str(), median(field(&Sample::rss)),
                median(field(&Sample::anon)), median(field(&Sample::file)), median(field(&Sample::threads)),
                verdict.c_str());
    nlohmann::ordered_json j = {{"layer", "footprint"}, {"workload", workload}, {"value", value}, {"unit", "MiB"},
                        {"min", lo},           {"max", hi},           {"runs", o.runs}};
    if (target) j["target"] = *target;
    json_rows.push_back(std::move(j));
  }
  std::printf("VmRSS, anon (RssAnon: heap, stacks) and file (RssFile: binary, shared libraries) at sampling time\n");
  if (!o.json_file.empty()) {
    std::ofstream out(o.json_file);
    out << nlohmann::ordered_json{{"rows", json_rows}}.dump(2) << '\n';
    if (!out) throw std::runtime_error("cannot write " + o.json_file);
  }
  fs::remove_all(dir);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Peak memory of the ICARS device manager and mediating server, as real processes"};
  Options o;
  std::string planet_client_endpoint;
  app.add_option("--runs", o.runs, "repetitions (medians are reported)")->check(CLI::Range(1, 100));
  app.add_option("--settle", o.settle, "sample once the server's simulated time reaches this time of day (HH:MM)")
      ->check([](const std::string& t) {
        return icars::parse_time_of_day(t) ? std::string() : "not a time of day (HH:MM): " + t;
      });
  app.add_option("--speedup", o.speedup, "simulated seconds per wall-clock second")->check(CLI::Range(1.0, 10000.0));
  app.add_option("--devices", o.server_devices, "devices registered with the server in the second scenario");
  app.add_option("--spread", o.spread, "device managers sharing the --devices devices in the third scenario (0: skip)")
      ->check([](const std::string& v) { return v == "1" ? "at least 2 (the robot's, and the others)" : ""; });
  app.add_option("--json", o.json_file, "also write the rows to FILE as JSON");
  app.add_option("--planet-client", planet_client_endpoint,
                 "internal: be the minimal PLANET process, connected to host:port until SIGTERM");
  CLI11_PARSE(app, argc, argv);
  try {
    if (!planet_client_endpoint.empty()) return planet_client(planet_client_endpoint);
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "icars-footprint: %s\n", e.what());
    return 2;
  }
}
