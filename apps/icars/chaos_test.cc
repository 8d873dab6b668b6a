// Chaos test of the smart home: `icars run --external` runs the paper's policy on the paper's
// house for a simulated week at an accelerated speed with three icars-device-manager processes
// (robot, living room, bedroom with the house's clock), each behind its own fault proxy and
// keeping its devices' state in a --state file. At random simulated times (seeded), one fault at
// a time hits a random manager:
//   kill       SIGKILL, restarted after a short pause with the same --state and --epoch
//   stop       SIGSTOP for 0.3-2.5 s (the link survives) or 7-9 s (longer than the heartbeat
//              timeout: the mediator drops the link), then SIGCONT
//   cut        the proxy closes the link with FIN or with RST
//   blackhole  the proxy forwards nothing for 0.3-2.5 s or 7-9 s
//   delay      the proxy delays every byte by 20-300 ms for 2-8 s
// A fault that drops the link is followed by waiting for the manager to register again; the
// next comes 20 minutes to 2 simulated hours later, or (30% of the time) at a random time of
// the next evening between 18:05 and 23:05, when the policy sends its commands. Afterwards, from the mediator's trace (--trace),
// the managers' effect logs (--effects, one per incarnation) and their state files:
//   1. every device's final state (TV, lights, speaker: what the mediator restores) equals the
//      state its last acknowledged command left, or a DeviceRestored record after that command
//      reported the difference (with the value the device has);
//   2. no acknowledged command was lost: each one ran on its device (same request id), and a
//      command ran more than once only if its operation is idempotent;
//   3. every failed command was reported: a behavior's command by a "call" record with ok=false
//      from that behavior (unless the behavior had been halted or had failed before: nobody is
//      left to tell; one that had succeeded is not excused), the mediator's own re-applied state
//      by the DeviceRestored record that says it failed;
//   4. no stuck task or behavior (testing/house_processes.h), where a change a sensor saw while
//      its manager was down counts from its return (if it still reads so), and a task the
//      mediator stamped while the clock's manager was down started at the latest at its return;
//   5. the mediator stops by itself with exit status 0 and no sanitizer report; so does the
//      last incarnation of every manager on SIGTERM, and every restarted one restored its state.
//
// Environment (for a longer run by hand, or a release build):
//   ICARS_CHAOS_SEED    the fault schedule's seed (default: random; printed either way)
//   ICARS_CHAOS_DAYS    simulated days (default 7)
//   ICARS_CHAOS_SPEED   simulated seconds per wall-clock second (default 3600: 7 days in 168 s)
//   ICARS_CHAOS_FAULTS  0: no faults (the same run and checks, for comparison)
//   ICARS_CHAOS_KEEP    a directory to keep the trace, logs, effects and state files in
#include <gtest/gtest.h>

#include <fmt/format.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "fault_proxy.h"
#include "house_processes.h"
#include "icars/home/sim/sim_state_file.h"

namespace {

using namespace icars_test;
using namespace std::chrono_literals;
namespace home = icars::home;
using std::chrono::milliseconds;

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kDeviceManager = ICARS_DEVICE_MANAGER_BINARY;
const std::string kPolicy = kSource + "/examples/smart_home/paper_home.xml";
const std::string kHouse = kSource + "/houses/paper_house.xml";
constexpr std::size_t kNone = static_cast<std::size_t>(-1);

// --- The faults ----------------------------------------------------------------------------------

enum class FaultKind { kill, stop, cut_fin, cut_rst, blackhole, delay };
constexpr FaultKind kFaultKinds[] = {FaultKind::kill,    FaultKind::stop,      FaultKind::cut_fin,
                                     FaultKind::cut_rst, FaultKind::blackhole, FaultKind::delay};
const char* name(FaultKind kind) {
  switch (kind) {
    case FaultKind::kill: return "kill";
    case FaultKind::stop: return "stop";
    case FaultKind::cut_fin: return "cut-FIN";
    case FaultKind::cut_rst: return "cut-RST";
    case FaultKind::blackhole: return "blackhole";
    case FaultKind::delay: return "delay";
  }
  return "?";
}

struct Fault {
  FaultKind kind = FaultKind::kill;
  std::size_t manager = 0;
  milliseconds length{0};    // wall time: the pause before the restart, the stop, blackhole or delay
  milliseconds delay_by{0};  // delay
  bool breaks_link = false;  // the mediator loses the link: the manager registers again

  std::string describe() const {
    const double s = static_cast<double>(length.count()) / 1000.0;
    switch (kind) {
      case FaultKind::kill: return fmt::format("SIGKILL, restart after {:.2f} s", s);
      case FaultKind::stop: return fmt::format("SIGSTOP for {:.1f} s", s);
      case FaultKind::cut_fin: return "link cut (FIN)";
      case FaultKind::cut_rst: return "link cut (RST)";
      case FaultKind::blackhole: return fmt::format("link blackholed for {:.1f} s", s);
      case FaultKind::delay: return fmt::format("link delayed by {} ms for {:.1f} s", delay_by.count(), s);
    }
    return "?";
  }
};

// Lengths stay clear of the heartbeat timeout (5 s, checked every second): a short silence
// (at most 2.5 s) keeps the link, a long one (7 s or more) loses it for sure.
Fault draw_fault(std::mt19937_64& rng, std::size_t managers) {
  const auto ms = [&rng](std::int64_t lo, std::int64_t hi) {
    return milliseconds(std::uniform_int_distribution<std::int64_t>(lo, hi)(rng));
  };
  Fault f;
  f.kind = kFaultKinds[std::uniform_int_distribution<std::size_t>(0, std::size(kFaultKinds) - 1)(rng)];
  f.manager = std::uniform_int_distribution<std::size_t>(0, managers - 1)(rng);
  const bool long_silence = std::bernoulli_distribution(0.5)(rng);
  switch (f.kind) {
    case FaultKind::kill:
      f.length = ms(50, 400);
      f.breaks_link = true;
      break;
    case FaultKind::stop:
    case FaultKind::blackhole:
      f.length = long_silence ? ms(7000, 9000) : ms(300, 2500);
      f.breaks_link = long_silence;
      break;
    case FaultKind::cut_fin:
    case FaultKind::cut_rst:
      f.breaks_link = true;
      break;
    case FaultKind::delay:
      f.length = ms(2000, 8000);
      f.delay_by = ms(20, 300);
      break;
  }
  return f;
}

// A fault's time on the shared simulated clock: from when it hit to when its manager was fully
// back (registered again, or the fault lifted when the link survived).
struct Outage {
  std::size_t manager = 0;
  icars::Time from{0}, to{0};
};

// A change of what an occupancy sensor sees: when it happened, and when the mediator could see it.
struct Change {
  icars::Time happened{0}, visible{0};
};

// The changes the mediator could see, in the order they happened, from the day before `from`
// to the day after `to`. A change while the sensor's manager was down (or up to `guard` before:
// the schedule's jitter, an event in flight lost with its link) is seen when it is back, by Sense
// re-reading the sensor, and only if the sensor then reads otherwise than before the outage: a
// user who got up and sat down again meanwhile changed nothing the mediator can see.
std::vector<Change> visible_changes(const std::vector<Moment>& moments, const std::vector<Outage>& outages,
                                    const std::vector<Manager>& managers, icars::Time from, icars::Time to, icars::Time guard) {
  std::vector<Change> out;
  std::set<std::string> furniture;
  for (const auto& m : moments) furniture.insert(m.furniture);
  for (const auto& f : furniture) {
    std::vector<std::pair<icars::Time, bool>> transitions;  // when, occupied
    for (icars::Time day = icars::kDay * (from / icars::kDay) - icars::kDay; day <= to + icars::kDay; day += icars::kDay) {
      for (const auto& m : moments) {
        if (m.furniture == f) transitions.emplace_back(day + m.time_of_day, m.occupied);
      }
    }
    std::sort(transitions.begin(), transitions.end());
    const auto occupied_at = [&](icars::Time t) {
      bool occupied = false;
      for (const auto& [at, o] : transitions) {
        if (at <= t) occupied = o;
      }
      return occupied;
    };
    // The outages of the manager of f's sensor, overlapping ones merged.
    std::vector<std::pair<icars::Time, icars::Time>> windows;
    for (const auto& o : outages) {
      if (managers[o.manager].furniture.contains(f)) windows.emplace_back(o.from - guard, o.to);
    }
    std::sort(windows.begin(), windows.end());
    std::vector<std::pair<icars::Time, icars::Time>> merged;
    for (const auto& w : windows) {
      if (!merged.empty() && w.first <= merged.back().second) {
        merged.back().second = std::max(merged.back().second, w.second);
      } else {
        merged.push_back(w);
      }
    }
    std::map<std::size_t, icars::Time> last_hidden;  // window -> the last change in it
    for (const auto& [at, o] : transitions) {
      const auto w = std::find_if(merged.begin(), merged.end(), [at = at](const auto& win) {
        return win.first <= at && at < win.second;
      });
      if (w == merged.end()) {
        out.push_back({at, at});
      } else {
        last_hidden[static_cast<std::size_t>(w - merged.begin())] = at;
      }
    }
    for (const auto& [w, at] : last_hidden) {
      if (occupied_at(merged[w].second) != occupied_at(merged[w].first)) out.push_back({at, merged[w].second});
    }
  }
  std::sort(out.begin(), out.end(), [](const Change& a, const Change& b) { return a.happened < b.happened; });
  return out;
}

// --- What the devices did and kept ---------------------------------------------------------------

std::uint32_t request_of(const json& j) {
  return j.contains("request") && j["request"].is_number() ? j["request"].get<std::uint32_t>() : 0;
}

// The commands idl/home.idl declares idempotent (running one twice leaves what running it once
// does): PLANET may send them again over a new link.
bool idempotent(const std::string& method) {
  return method == "set_power" || method == "set_channel" || method == "set_volume" || method == "set_intensity" ||
         method == "stop" || method == "turn_to";
}

// The state the mediator restores when a device comes back (service::Adaptor::restore), as the
// DeviceRestored differences show values: true, 5, "calm music".
using KeptState = std::map<std::string, std::string>;

std::string quoted(const std::string& s) { return fmt::format("\"{}\"", s); }

// What a device of `type` keeps when no command has changed it (the simulated devices' defaults).
KeptState initial_state(const std::string& type) {
  if (type == "TV") {
    const home::SimTVState s;
    return {{"on", s.on ? "true" : "false"}, {"channel", std::to_string(s.channel)}, {"volume", std::to_string(s.volume)}};
  }
  if (type == "Light") {
    const home::SimLightState s;
    return {{"on", s.on ? "true" : "false"}, {"intensity", std::to_string(s.intensity)}};
  }
  if (type == "Speaker") {
    const home::SimSpeakerState s;
    return {{"playing", quoted(s.playing)}, {"volume", std::to_string(s.volume)}};
  }
  return {};
}

// Applies an effect ("power" "on", "channel" "5", "playing" "calm music", "stopped" "").
void apply_effect(KeptState& state, const std::string& what, const std::string& value) {
  if (what == "power") state["on"] = value == "on" ? "true" : "false";
  if ((what == "channel" || what == "volume" || what == "intensity") && state.contains(what)) state[what] = value;
  if (what == "playing" && state.contains("playing")) state["playing"] = quoted(value);
  if (what == "stopped" && state.contains("playing")) state["playing"] = quoted("");
}

// A device's entry in a state file, as KeptState.
KeptState kept_in_file(const json& entry, const KeptState& shape) {
  KeptState out;
  for (const auto& [field, unused] : shape) {
    if (!entry.contains(field)) continue;
    const auto& v = entry[field];
    out[field] = v.is_boolean() ? (v.get<bool>() ? "true" : "false")
                 : v.is_string() ? quoted(v.get<std::string>())
                                 : v.dump();
  }
  return out;
}

// Whether DeviceRestored's differences ("channel 5 -> 1, on true -> false") report `field`
// found with `value`.
bool reports(const std::string& differences, const std::string& field, const std::string& value) {
  std::size_t at = 0;
  while (at <= differences.size()) {
    auto comma = differences.find(", ", at);
    if (comma == std::string::npos) comma = differences.size();
    const auto item = differences.substr(at, comma - at);
    const auto suffix = " -> " + value;
    if (item.starts_with(field + " ") && item.ends_with(suffix)) return true;
    at = comma + 2;
  }
  return false;
}

// --- The mediator's record of its commands ------------------------------------------------------

struct Command {
  std::uint32_t request = 0;  // 0: never sent (the link was down)
  std::string device, capability, method;
  std::string behavior;          // the path of the behavior whose call it is; "": the mediator's own
  std::size_t call = kNone;      // trace index of the behavior's "call" record
  std::size_t sent = kNone, acknowledged = kNone, failed = kNone;  // trace indexes
  std::string key() const { return device + "." + capability + "." + method; }
};

// Every command of the trace, each attributed to the behavior whose "call" record came just
// before it for the same operation (a behavior records its call, then sends it on the same
// thread); a command with no such call is the mediator's own (a re-applied state).
std::vector<Command> read_commands(const std::vector<json>& trace) {
  std::vector<Command> commands;
  std::map<std::uint32_t, std::size_t> by_request;
  std::map<std::string, std::vector<std::size_t>> calls;  // "device.capability.method" -> call records
  for (std::size_t i = 0; i < trace.size(); ++i) {
    const auto& r = trace[i];
    const auto kind = str(r, "kind");
    if (kind == "call" && !r.contains("ok")) {
      auto call = str(r, "call");
      calls[call.substr(0, call.find('('))].push_back(i);
      continue;
    }
    if (kind != "command") continue;
    const auto event = str(r, "event");
    const auto request = request_of(r);
    if (event == "sent" || (event == "failed" && request == 0)) {
      Command c;
      c.request = request;
      c.device = str(r, "device");
      c.capability = str(r, "capability");
      c.method = str(r, "method");
      if (auto& pending = calls[c.key()]; !pending.empty()) {
        c.call = pending.front();
        c.behavior = str(trace[c.call], "source");
        pending.erase(pending.begin());
      }
      (event == "sent" ? c.sent : c.failed) = i;
      if (request != 0) by_request[request] = commands.size();
      commands.push_back(std::move(c));
    } else if (auto it = by_request.find(request); it != by_request.end()) {
      (event == "acknowledged" ? commands[it->second].acknowledged : commands[it->second].failed) = i;
    }
  }
  return commands;
}

icars::Time time_of(const json& r) { return icars::Time(r.value("t", std::int64_t{0})); }

}  // namespace

TEST(IcarsChaos, AWeekOfKilledStoppedAndCutDeviceManagers) {
  const auto s = run_settings("ICARS_CHAOS", "FAULTS", 1);
  std::printf("[chaos] seed %llu (ICARS_CHAOS_SEED=%llu to repeat), %d days at %.0fx\n",
              static_cast<unsigned long long>(s.seed), static_cast<unsigned long long>(s.seed), s.days, s.speed);
  std::mt19937_64 rng(s.seed);
  const auto wall_start = std::chrono::steady_clock::now();

  const fs::path dir = run_directory(s.keep, "icars_chaos");
  std::printf("[chaos] logs, trace, effects and state files in %s (kept when the test fails)\n", dir.c_str());
  const auto trace_file = dir / "trace.jsonl";

  auto paper = load_paper_house(kHouse);
  const auto& house = paper.house;
  auto& managers = paper.managers;
  const auto& moments = paper.moments;
  ASSERT_FALSE(moments.empty());
  const auto env = child_environment();

  // --- The mediator: it stops by itself at 18:00 of the last day. ---
  const icars::Time start = house.start_time;
  const icars::Time end = start + icars::kDay * s.days;
  ASSERT_EQ(start % icars::kDay, 18h) << "the chaos test's days run 18:00 to 18:00";
  Program server(dir / "icars.stderr", env, mediator_command(kIcars, kPolicy, kHouse, s.speed, s.days, trace_file));
  std::vector<std::string> server_output;
  const std::string port = start_mediator(server, server_output);
  ASSERT_FALSE(port.empty()) << "the mediator did not start; its stderr:\n" << tail(server.stderr_text());

  // --- The managers, each behind its own fault proxy, on one simulated clock. ---
  std::vector<std::unique_ptr<planet_test::FaultProxy>> proxies;
  for (std::size_t i = 0; i < managers.size(); ++i) {
    proxies.push_back(std::make_unique<planet_test::FaultProxy>("127.0.0.1", static_cast<std::uint16_t>(std::stoi(port))));
  }
  const SharedClock clock{start, SharedClock::wall_ms() + 3000, s.speed};  // time for every manager to register
  const auto state_file = [&](const Manager& m) { return dir / (m.name + ".state.json"); };
  const auto effects_file = [&](const Manager& m, int incarnation) {
    return dir / fmt::format("{}-{}.effects.jsonl", m.name, incarnation);
  };
  const auto launch = [&](std::size_t i) {
    auto& m = managers[i];
    auto argv = m.command(kDeviceManager, kHouse, fmt::format("127.0.0.1:{}", proxies[i]->port()), clock);
    argv.insert(argv.end(), {"--state", state_file(m).string(), "--effects", effects_file(m, m.incarnation + 1).string()});
    m.launch(dir, env, argv);
  };
  for (std::size_t i = 0; i < managers.size(); ++i) launch(i);

  std::vector<std::string> failures;
  const auto pump = [&] {
    for (auto& line : server.lines()) server_output.push_back(std::move(line));
    for (auto& m : managers) m.read_output(clock.now(), failures);
  };
  ASSERT_TRUE(planet_test::wait_until([&] {
    pump();
    return std::all_of(managers.begin(), managers.end(), [](const Manager& m) { return m.registered; });
  }, 60s)) << "the device managers did not register";

  // Pumps the output until `done` holds or `deadline` passes; false when a manager died by itself
  // (the run is over: `died` says why) or the mediator stopped.
  std::string died;
  const auto run_until = [&](std::chrono::steady_clock::time_point deadline, const std::function<bool()>& done) {
    while (std::chrono::steady_clock::now() < deadline && !done()) {
      pump();
      if (server.exited()) return false;
      for (const auto& m : managers) {
        if (m.process && m.process->exited()) {
          died = fmt::format("{} (incarnation {}) died by itself at {}; its stderr:\n{}", m.name, m.incarnation,
                             icars::format_time(clock.now()), tail(m.process->stderr_text(), 60));
          return false;
        }
      }
      std::this_thread::sleep_for(2ms);
    }
    return true;
  };
  const auto after = [](milliseconds wall) { return std::chrono::steady_clock::now() + wall; };
  const auto never = [] { return false; };

  // --- The faults, one at a time. ---
  std::vector<Outage> outages;
  std::map<FaultKind, int> fault_counts;
  int faults = 0;
  const auto uniform = [&rng](icars::Time lo, icars::Time hi) {
    return icars::Time(std::uniform_int_distribution<std::int64_t>(lo.count(), hi.count())(rng));
  };
  icars::Time next = start + uniform(1h, 3h);
  bool running = true;
  while (s.enabled && running) {
    const auto fault = draw_fault(rng, managers.size());
    const icars::Time span((fault.length.count() + 5000) * static_cast<std::int64_t>(s.speed));  // + time to recover
    if (next + span > end - 3h) break;
    running = run_until(after(clock.wall(next - clock.now()) + 1s), [&] { return clock.now() >= next; });
    if (!running) break;
    auto& m = managers[fault.manager];
    auto& proxy = *proxies[fault.manager];
    const auto rounds_before = m.rounds;
    const icars::Time from = clock.now();
    switch (fault.kind) {
      case FaultKind::kill:
        m.process->signal(SIGKILL);
        m.process.reset();  // reaps it
        m.down_since = from;
        ++m.kills;
        std::this_thread::sleep_for(fault.length);
        launch(fault.manager);
        break;
      case FaultKind::stop:
        m.process->freeze();
        running = run_until(after(fault.length), never);
        m.process->thaw();
        break;
      case FaultKind::cut_fin:
      case FaultKind::cut_rst:
        proxy.cut(fault.kind == FaultKind::cut_rst);
        break;
      case FaultKind::blackhole:
        proxy.blackhole();
        running = run_until(after(fault.length), never);
        proxy.pass();
        break;
      case FaultKind::delay:
        proxy.delay(fault.delay_by);
        running = run_until(after(fault.length), never);
        proxy.pass();
        break;
    }
    if (!running) break;
    // Back: registered again when the link was lost; else a moment for a reconnection nobody
    // expected (it then counts as part of the outage).
    const auto back = [&] { return fault.kind == FaultKind::kill ? m.registered : m.rounds > rounds_before; };
    running = run_until(after(fault.breaks_link ? 60s : 300ms), fault.breaks_link ? std::function<bool()>(back) : never);
    if (running && fault.breaks_link && !back()) {
      failures.push_back(fmt::format("{} did not register again within 60 s after: {} at {}", m.name, fault.describe(),
                                     icars::format_time(from)));
    }
    const icars::Time to = clock.now();
    outages.push_back({fault.manager, from, to});
    ++fault_counts[fault.kind];
    ++faults;
    std::printf("[chaos] %s %-7s %s: %s at %s\n", icars::format_time(from).c_str(), m.name.c_str(),
                fault.describe().c_str(), m.rounds > rounds_before ? "registered again" : "link kept",
                icars::format_time(to).c_str());
    next = to + uniform(20min, 2h);
    if (std::bernoulli_distribution(0.3)(rng)) {  // into the evening, when the policy sends commands
      next = icars::kDay * (to / icars::kDay) + 18h + uniform(5min, 5h);
      while (next < to + 10min) next += icars::kDay;
    }
  }
  if (!died.empty()) FAIL() << died;

  // --- The end: the mediator stops by itself; then the managers, on SIGTERM. ---
  wait_for_end(server, clock, end, pump);
  ASSERT_TRUE(server.exited()) << "the mediator did not stop at the end of day " << s.days;
  pump();
  const int server_status = server.wait();
  for (auto& m : managers) {
    if (!m.registered) failures.push_back(fmt::format("{} did not register again after its last restart", m.name));
  }
  auto manager_status = stop_managers(managers, failures);
  for (auto& line : server.lines()) server_output.push_back(std::move(line));
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();

  // --- The records: the trace, every incarnation's effects, the state files. ---
  const auto trace = read_json_lines(trace_file);
  std::vector<json> effects;  // per manager, its incarnations in order: each device's execution order
  for (const auto& m : managers) {
    for (int i = 1; i <= m.incarnation; ++i) {
      std::ifstream in(effects_file(m, i));
      for (std::string line; std::getline(in, line);) {
        if (line.empty()) continue;
        try {
          effects.push_back(json::parse(line));
        } catch (const json::exception&) {
          // Only a SIGKILL may tear a line, the last of an incarnation that was not the last; its
          // command was not answered (a device reports its effect before it replies).
          EXPECT_TRUE(i < m.incarnation && in.peek() == std::char_traits<char>::eof())
              << "a torn line in " << effects_file(m, i) << ": " << line;
        }
      }
    }
  }
  const auto commands = read_commands(trace);
  std::map<std::uint32_t, const Command*> by_request;
  for (const auto& c : commands) {
    if (c.request != 0) by_request[c.request] = &c;
  }

  // 2. No acknowledged command lost; only idempotent ones ran twice.
  std::map<std::uint32_t, int> runs;
  for (const auto& e : effects) {
    const auto request = request_of(e);
    ++runs[request];
    const auto it = by_request.find(request);
    if (it == by_request.end()) {
      ADD_FAILURE() << "a device executed a command the mediator never sent: " << e.dump();
    } else if (str(e, "device") != it->second->device) {
      ADD_FAILURE() << "command " << request << " for " << it->second->device << " ran on another device: " << e.dump();
    }
  }
  int acknowledged = 0, failed = 0, unsent = 0, ran_twice = 0, failed_but_ran = 0;
  for (const auto& c : commands) {
    const int n = runs.contains(c.request) ? runs.at(c.request) : 0;
    acknowledged += c.acknowledged != kNone;
    failed += c.failed != kNone;
    unsent += c.request == 0;
    ran_twice += n > 1;
    failed_but_ran += c.failed != kNone && n > 0;
    if (c.acknowledged != kNone && n == 0) {
      ADD_FAILURE() << "acknowledged command " << c.request << " (" << c.key() << ", acknowledged at "
                    << icars::format_time(time_of(trace[c.acknowledged])) << ") never ran on " << c.device;
    }
    if (n > 1 && !idempotent(c.method)) {
      ADD_FAILURE() << "command " << c.request << " (" << c.key() << ") is not idempotent but ran " << n << " times";
    }
  }

  // 1. Every device's final state is what its last acknowledged command left, or reported.
  int restored_records = 0, reapplied = 0, lost = 0, back = 0;
  for (const auto& r : trace) {
    if (str(r, "kind") != "device") continue;
    const auto event = str(r, "event");
    lost += event == "DeviceLost";
    back += event == "DeviceBack";
    restored_records += event == "DeviceRestored";
    reapplied += event == "DeviceRestored" && r.value("reapplied", false);
  }
  for (const auto& m : managers) {
    const auto file = read_file(state_file(m));
    ASSERT_FALSE(file.empty()) << "no state file " << state_file(m);
    const auto kept = json::parse(file);
    for (const auto& id : m.devices) {
      const auto* spec = house.device(id);
      ASSERT_NE(spec, nullptr);
      auto state = initial_state(spec->type);
      if (state.empty()) continue;
      // The state after each effect, in the order the device ran them; the last one of a
      // behavior's acknowledged command is what the mediator holds as acknowledged.
      const Command* last = nullptr;
      KeptState expected;
      for (const auto& e : effects) {
        if (str(e, "device") != id) continue;
        apply_effect(state, str(e, "what"), str(e, "value"));
        const auto it = by_request.find(request_of(e));
        if (it != by_request.end() && it->second->acknowledged != kNone && !it->second->behavior.empty()) {
          last = it->second;
          expected = state;
        }
      }
      if (last == nullptr) continue;  // no acknowledged state to keep
      const auto final_state = kept_in_file(kept["devices"][id], state);
      for (const auto& [field, wanted] : expected) {
        const auto found = final_state.contains(field) ? final_state.at(field) : std::string("(none)");
        if (found == wanted) continue;
        const bool reported = std::any_of(trace.begin() + static_cast<std::ptrdiff_t>(last->acknowledged), trace.end(),
                                          [&](const json& r) {
                                            return str(r, "kind") == "device" && str(r, "event") == "DeviceRestored" &&
                                                   str(r, "device") == id && reports(str(r, "differences"), field, found);
                                          });
        EXPECT_TRUE(reported) << id << " ends with " << field << " " << found << ", but its last acknowledged command ("
                              << last->request << ", " << last->key() << " by " << last->behavior << ", acknowledged at "
                              << icars::format_time(time_of(trace[last->acknowledged])) << ") left " << wanted
                              << ", and no DeviceRestored after it reported the difference";
      }
    }
  }

  // 3. Every failed command was reported to whoever sent it.
  int reported_to_behaviors = 0, behavior_gone = 0;
  std::set<std::size_t> used;  // call failure records already matched
  for (const auto& c : commands) {
    if (c.failed == kNone) continue;
    const auto& failure = trace[c.failed];
    if (c.behavior.empty()) {
      const bool reported = std::any_of(trace.begin() + static_cast<std::ptrdiff_t>(c.failed), trace.end(), [&](const json& r) {
        return str(r, "kind") == "device" && str(r, "event") == "DeviceRestored" && str(r, "device") == c.device &&
               str(r, "text").find("failed:") != std::string::npos;
      });
      EXPECT_TRUE(reported) << "the mediator's own command " << c.request << " (" << c.key() << ") failed at "
                            << icars::format_time(time_of(failure)) << " (" << str(failure, "error")
                            << "), and no DeviceRestored record after it says so";
      continue;
    }
    std::size_t match = kNone;
    for (std::size_t i = c.call + 1; i < trace.size() && match == kNone; ++i) {
      const auto& r = trace[i];
      if (str(r, "kind") == "call" && r.contains("ok") && !r.value("ok", true) && str(r, "source") == c.behavior &&
          str(r, "call").starts_with(c.key()) && !used.contains(i)) {
        match = i;
      }
    }
    if (match != kNone) {
      used.insert(match);
      ++reported_to_behaviors;
      continue;
    }
    // Nobody to tell: the activation that made the call had been halted (its task stopped) or had
    // failed before the failure reached it. One that had succeeded claimed success too early.
    std::size_t started = kNone, ended = kNone;
    for (std::size_t i = c.call; i-- > 0 && started == kNone;) {
      if (str(trace[i], "kind") == "behavior" && str(trace[i], "source") == c.behavior &&
          str(trace[i], "event") == "start") {
        started = i;
      }
    }
    for (std::size_t i = started == kNone ? c.call : started + 1; i < trace.size() && ended == kNone; ++i) {
      const auto& r = trace[i];
      const auto event = str(r, "event");
      if (str(r, "kind") == "behavior" && str(r, "source") == c.behavior &&
          (event == "success" || event == "failure" || event == "halt")) {
        ended = i;
      }
    }
    const bool gone = ended != kNone && (ended < c.failed || time_of(trace[ended]) <= time_of(failure) + 5min);
    if (gone && str(trace[ended], "event") != "success") {
      ++behavior_gone;
      continue;
    }
    ADD_FAILURE() << "command " << c.request << " (" << c.key() << ") of behavior " << c.behavior << " (called at "
                  << icars::format_time(time_of(trace[c.call])) << ") failed at " << icars::format_time(time_of(failure))
                  << " (" << str(failure, "error") << "), and no \"call\" record with ok=false reported it to the "
                  << "behavior"
                  << (gone ? fmt::format(": the behavior had succeeded at {} with the command still unanswered",
                                         icars::format_time(time_of(trace[ended])))
                           : std::string());
  }

  // 4. No stuck task: the change that should end a task counts from when the mediator could see
  // it; whether a change just before an outage was seen or not, the later of the two. While the
  // clock's manager was down the mediator's clock stood still (and then ran through the time
  // missed): a task stamped within such an outage started at the latest when it was back.
  const std::vector<std::vector<Change>> variants = {
      visible_changes(moments, outages, managers, start, end, icars::Time(0)),
      visible_changes(moments, outages, managers, start, end, paper.jitter + 10min)};
  // The mediator's clock follows the clock manager's by polls (every 5 ms of wall time) and, on a
  // loaded machine, tens of milliseconds behind: at 3600x its time may stand still minutes of
  // simulated time before the outage the test started. 200 ms of wall time at the run's speed.
  const auto clock_lag = icars::Time(static_cast<std::int64_t>(200.0 * s.speed));
  const auto next_change = [&](icars::Time t) {  // t: a task's start + 15 min (find_overdue_tasks)
    for (const auto& o : outages) {
      if (managers[o.manager].simulation && o.from - clock_lag <= t - 15min && t - 15min <= o.to) {
        t = std::max(t, o.to + 15min);
      }
    }
    icars::Time latest{0};
    for (const auto& changes : variants) {
      const auto it = std::find_if(changes.begin(), changes.end(), [t](const Change& c) { return c.happened > t; });
      latest = std::max(latest, it == changes.end() ? icars::Time::max() : it->visible);
    }
    // The clock's manager down between the task's start and that change being seen: the
    // mediator's time stood still, and what it did then is stamped when it was back.
    for (const auto& o : outages) {
      if (managers[o.manager].simulation && o.from - clock_lag <= latest && t - 15min <= o.to) {
        latest = std::max(latest, o.to);
      }
    }
    return latest;
  };
  auto tasks = follow_tasks(trace);
  find_overdue_tasks(tasks, next_change, paper.jitter + 45min, end);

  // --- The figures. ---
  std::printf("[chaos] %d faults:", faults);
  for (const auto& [kind, n] : fault_counts) std::printf(" %s %d", name(kind), n);
  std::printf("\n[chaos] commands: %zu, %d acknowledged, %d failed (%d never sent, %d ran anyway), %zu effects, %d ran "
              "more than once; failures reported to behaviors %d, to behaviors already gone %d\n",
              commands.size(), acknowledged, failed, unsent, failed_but_ran, effects.size(), ran_twice,
              reported_to_behaviors, behavior_gone);
  std::printf("[chaos] devices: %d lost, %d back, %d restored (%d re-applied); %zu task runs; %zu trace records; "
              "wall time %.1f s\n",
              lost, back, restored_records, reapplied, tasks.runs.size(), trace.size(), wall_s);

  // --- The other checks. ---
  for (const auto& f : failures) ADD_FAILURE() << f;
  for (const auto& line : tasks.stuck) ADD_FAILURE() << "stuck: " << line;
  for (const auto& p : exit_problems("the mediator", server_status, server.stderr_text())) ADD_FAILURE() << p;
  EXPECT_TRUE(std::any_of(server_output.begin(), server_output.end(),
                          [](const std::string& l) { return l.starts_with("=== summary"); }))
      << "no summary from the mediator";
  for (const auto& m : managers) {
    for (const auto& p : exit_problems(m.name, manager_status[m.name], m.process->stderr_text())) ADD_FAILURE() << p;
    EXPECT_EQ(static_cast<int>(m.state_lines.size()), m.incarnation) << m.name << ": a STATE line per incarnation";
    for (std::size_t i = 1; i < m.state_lines.size(); ++i) {
      EXPECT_TRUE(m.state_lines[i].starts_with("STATE restored")) << m.name << " incarnation " << i + 1 << ": "
                                                                   << m.state_lines[i];
    }
  }
  if (s.enabled) {
    EXPECT_GE(faults, s.days) << "too few faults to call this chaos";
  }
  EXPECT_GT(acknowledged, 0);
  if (s.keep.empty() && !::testing::Test::HasFailure()) fs::remove_all(dir);
}
