// The smart home when the network misbehaves: `icars run --external` and an
// `icars-device-manager` as real processes, with a fault-injecting proxy on the device
// manager's link to the mediating server. While the simulated evening runs, the proxy delays,
// drops, truncates, cuts and blackholes that link. The run must go on (it completes, the
// statechart reaches its later states), nothing may hang, and the two sides' records must
// agree: every command the server saw acknowledged was executed exactly once by a device,
// every command reported failed was executed at most once, and no command ran twice.
//
// The server's record is the "command" lines of its --trace (sent / acknowledged / failed,
// with the PLANET request id); the devices' record is the device manager's --effects file
// (one line per executed command, with the request id of the call).
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "announcement.h"
#include "child_process.h"
#include "fault_proxy.h"
#include "house_processes.h"

using nlohmann::json;
using namespace std::chrono_literals;
using planet_test::Direction;
using planet_test::FaultProxy;
using Clock = std::chrono::steady_clock;
using icars_test::read_json_lines;

namespace {

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kDeviceManager = ICARS_DEVICE_MANAGER_BINARY;
constexpr double kSpeedup = 600;        // simulated seconds per wall-clock second
constexpr int kHouseStartMinute = 18 * 60;  // paper_house.xml starts at 18:00

std::string temp(const std::string& name) {
  return ::testing::TempDir() + "icars_faults_" + std::to_string(::getpid()) + "_" + name;
}

std::string str(const json& j, const char* key) {
  return j.contains(key) && j[key].is_string() ? j[key].get<std::string>() : "";
}
std::uint32_t request_of(const json& j) {
  return j.contains("request") && j["request"].is_number() ? j["request"].get<std::uint32_t>() : 0;
}

// One fault step at a simulated time of the first evening ("HH:MM" or "HH:MM:SS").
struct Step {
  std::string at;
  std::string what;  // for the log
  std::function<void(FaultProxy&)> act;
  // For faults of the processes themselves (SIGSTOP).
  std::function<void(planet_test::ChildProcess& mediator, planet_test::ChildProcess& devices)> on_processes = {};
};

int minutes_of(const std::string& hhmm) {
  return std::stoi(hhmm.substr(0, 2)) * 60 + std::stoi(hhmm.substr(3, 2));
}
double seconds_of(const std::string& at) {
  return minutes_of(at) * 60.0 + (at.size() > 5 ? std::stod(at.substr(6, 2)) : 0.0);
}

struct Outcome {
  int mediator_status = -1;
  bool mediator_exited = false;
  std::string mediator_output;
  std::vector<json> trace;
  std::vector<json> effects;
  std::uint64_t connections = 0;   // accepted by the proxy
  std::uint64_t registrations = 0;  // the last registration round the device manager reported
  std::vector<std::string> log;     // what was injected when
};

// Runs the paper home until `until` with the device manager behind a FaultProxy, applying
// `steps` at their simulated times (by the device manager's clock, which runs at kSpeedup).
Outcome run_with_faults(const std::string& until, const std::vector<Step>& steps) {
  Outcome out;
  const auto trace_file = temp("trace.jsonl");
  const auto effects_file = temp("effects.jsonl");
  planet_test::ChildProcess mediator({kIcars, "run", kSource + "/examples/smart_home/paper_home.xml", "--world",
                                      kSource + "/houses/paper_house.xml", "--external", "--listen", "127.0.0.1:0",
                                      "--until", until, "--quiet", "--trace", trace_file});
  std::string port;
  while (auto line = mediator.read_line(60s)) {
    out.mediator_output += *line + "\n";
    if (port = icars::app::announced_port(*line); !port.empty()) break;
  }
  if (port.empty()) {
    ADD_FAILURE() << "the mediator reported no port:\n" << out.mediator_output;
    return out;
  }
  FaultProxy proxy("127.0.0.1", static_cast<std::uint16_t>(std::stoi(port)));
  planet_test::ChildProcess devices({kDeviceManager, "--house", kSource + "/houses/paper_house.xml", "--server",
                                     "127.0.0.1:" + std::to_string(proxy.port()), "--speedup",
                                     std::to_string(kSpeedup), "--effects", effects_file});
  // The device manager's clock starts at 18:00 when it prints STARTED.
  const auto started = devices.read_line(60s);
  const auto t0 = Clock::now();
  if (!started || !started->starts_with("STARTED")) {
    ADD_FAILURE() << "the device manager did not start: " << started.value_or("EOF");
    return out;
  }
  auto drain_devices = [&](Clock::time_point until_wall) {
    do {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(until_wall - Clock::now());
      if (auto line = devices.read_line(std::clamp(left, 1ms, 50ms))) {
        if (line->starts_with("REGISTERED ")) out.registrations = std::stoull(line->substr(11));
      }
    } while (Clock::now() < until_wall);
  };
  for (const auto& step : steps) {
    const double sim_seconds = seconds_of(step.at) - kHouseStartMinute * 60.0;
    const auto due = t0 + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(sim_seconds / kSpeedup));
    drain_devices(due);
    if (step.act) step.act(proxy);
    if (step.on_processes) step.on_processes(mediator, devices);
    out.log.push_back(step.at + " " + step.what);
  }
  // The mediator stops by itself at `until`; it must exit within a bound.
  const double run_seconds = (seconds_of(until) - kHouseStartMinute * 60.0) / kSpeedup;
  const auto deadline = t0 + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(run_seconds)) + 60s;
  while (Clock::now() < deadline) {
    drain_devices(Clock::now() + 20ms);
    auto line = mediator.read_line(20ms);
    if (line) out.mediator_output += *line + "\n";
    if (auto status = mediator.wait_for(0ms)) {
      out.mediator_exited = true;
      out.mediator_status = *status;
      break;
    }
  }
  while (auto line = mediator.read_line(1s)) out.mediator_output += *line + "\n";
  devices.signal(SIGTERM);
  const auto devices_status = devices.wait_for(20s);
  EXPECT_TRUE(devices_status.has_value()) << "the device manager did not stop on SIGTERM";
  if (devices_status) {
    EXPECT_TRUE(WIFEXITED(*devices_status) && WEXITSTATUS(*devices_status) == 0) << *devices_status;
  }
  out.connections = proxy.connections_accepted();
  out.trace = read_json_lines(trace_file);
  out.effects = read_json_lines(effects_file);
  std::remove(trace_file.c_str());
  std::remove(effects_file.c_str());
  return out;
}

struct Ledger {
  int sent = 0, acknowledged = 0, failed = 0, failed_unsent = 0, executed = 0;
  int failed_but_executed = 0;
};

// Checks the two records against each other; returns the figures.
Ledger check_exactly_once(const Outcome& o) {
  Ledger l;
  struct Command {
    std::string device, method;
    int sent = 0, acknowledged = 0, failed = 0;
  };
  std::map<std::uint32_t, Command> commands;
  for (const auto& r : o.trace) {
    if (str(r, "kind") != "command") continue;
    const auto id = request_of(r);
    const auto event = str(r, "event");
    if (id == 0) {
      EXPECT_EQ(event, "failed") << "only a call that was never sent has no request id: " << r.dump();
      ++l.failed_unsent;
      continue;
    }
    auto& c = commands[id];
    c.device = str(r, "device");
    c.method = str(r, "method");
    c.sent += event == "sent";
    c.acknowledged += event == "acknowledged";
    c.failed += event == "failed";
  }
  std::map<std::uint32_t, int> executed;
  for (const auto& e : o.effects) {
    const auto id = request_of(e);
    EXPECT_NE(id, 0u) << "an effect no command caused: " << e.dump();
    ++executed[id];
    ++l.executed;
    auto it = commands.find(id);
    EXPECT_NE(it, commands.end()) << "the device executed a command the server never sent: " << e.dump();
    if (it != commands.end()) {
      EXPECT_EQ(str(e, "device"), it->second.device) << e.dump();
    }
  }
  for (const auto& [id, runs] : executed) EXPECT_LE(runs, 1) << "command " << id << " was executed " << runs << " times";
  for (const auto& [id, c] : commands) {
    l.sent += c.sent;
    l.acknowledged += c.acknowledged;
    l.failed += c.failed;
    EXPECT_EQ(c.sent, 1) << "command " << id << " (" << c.device << "." << c.method << ")";
    EXPECT_EQ(c.acknowledged + c.failed, 1)
        << "command " << id << " (" << c.device << "." << c.method << ") must end exactly once";
    const int runs = executed.contains(id) ? executed.at(id) : 0;
    if (c.acknowledged == 1) {
      EXPECT_EQ(runs, 1) << "acknowledged command " << id << " (" << c.device << "." << c.method
                         << ") was executed " << runs << " times";
    }
    if (c.failed == 1) {
      EXPECT_LE(runs, 1) << "failed command " << id;
      l.failed_but_executed += runs;
    }
  }
  // The mediator's summary says the same.
  const auto summary = o.mediator_output.find("device commands: ");
  EXPECT_NE(summary, std::string::npos) << o.mediator_output;
  if (summary != std::string::npos) {
    const auto expected = "device commands: " + std::to_string(l.sent) + " sent, " + std::to_string(l.acknowledged) +
                          " acknowledged, " + std::to_string(l.failed + l.failed_unsent) + " failed";
    EXPECT_EQ(o.mediator_output.substr(summary, expected.size()), expected) << o.mediator_output;
  }
  return l;
}

std::size_t find(const std::vector<json>& t, std::size_t from, const std::function<bool(const json&)>& pred) {
  for (std::size_t i = from; i < t.size(); ++i) {
    if (pred(t[i])) return i;
  }
  return t.size();
}
auto transition_to(const std::string& state) {
  return [state](const json& j) { return str(j, "kind") == "transition" && str(j, "to") == state; };
}
// A command of `method` on `device` sent at or after simulated minute `from_minute`.
auto command(const std::string& device, const std::string& method, const std::string& event) {
  return [=](const json& j) {
    return str(j, "kind") == "command" && str(j, "device") == device && str(j, "method") == method &&
           str(j, "event") == event;
  };
}

void report(const char* name, const Outcome& o, const Ledger& l) {
  std::printf("[%s] faults:", name);
  for (const auto& s : o.log) std::printf(" [%s]", s.c_str());
  std::printf("\n[%s] proxy connections %llu, registration rounds %llu; commands: %d sent, %d acknowledged, "
              "%d failed (+%d never sent), %d executed (%d of them reported failed)\n",
              name, static_cast<unsigned long long>(o.connections), static_cast<unsigned long long>(o.registrations),
              l.sent, l.acknowledged, l.failed, l.failed_unsent, l.executed, l.failed_but_executed);
}

void expect_clean_exit(const Outcome& o) {
  ASSERT_TRUE(o.mediator_exited) << "the mediator did not finish its run:\n" << o.mediator_output;
  ASSERT_TRUE(WIFEXITED(o.mediator_status) && WEXITSTATUS(o.mediator_status) == 0)
      << o.mediator_status << "\n" << o.mediator_output;
  EXPECT_NE(o.mediator_output.find("=== summary"), std::string::npos) << o.mediator_output;
}

}  // namespace

// The evening in the living room: a delayed link while the TV is switched on, a corrupted
// stream (a moment of dropped bytes), a truncated message and a cut while the music is
// controlled, and a silent link (blackhole) until the heartbeat timeout notices it. The
// statechart still goes to SleepMode at night and the robot serves it.
TEST(IcarsFaults, TheEveningSurvivesDelaysDropsTruncationsCutsAndABlackhole) {
  const std::vector<Step> steps = {
      {"18:11", "delay 150 ms both ways", [](FaultProxy& p) { p.delay(150ms); }},
      {"18:17", "pass", [](FaultProxy& p) { p.pass(); }},
      {"18:19:50", "drop server->devices", [](FaultProxy& p) { p.drop(Direction::server_to_client); }},
      {"18:20:20", "pass", [](FaultProxy& p) { p.pass(); }},
      {"18:59:50", "truncate 300 bytes server->devices", [](FaultProxy& p) { p.truncate(300, Direction::server_to_client); }},
      {"19:00:40", "pass", [](FaultProxy& p) { p.pass(); }},
      {"19:29:50", "drop devices->server", [](FaultProxy& p) { p.drop(Direction::client_to_server); }},
      {"19:30:20", "pass", [](FaultProxy& p) { p.pass(); }},
      {"19:31", "cut (RST)", [](FaultProxy& p) { p.cut(true); }},
      {"20:40", "blackhole both ways", [](FaultProxy& p) { p.blackhole(); }},
      {"21:50", "pass", [](FaultProxy& p) { p.pass(); }},
  };
  const auto o = run_with_faults("23:15", steps);
  expect_clean_exit(o);
  const auto l = check_exactly_once(o);
  report("evening", o, l);
  const auto& t = o.trace;
  const auto n = t.size();
  const auto rest = find(t, 0, transition_to("RestMode"));
  ASSERT_LT(rest, n) << "no RestMode";
  const auto sleep = find(t, rest, transition_to("SleepMode"));
  ASSERT_LT(sleep, n) << "no SleepMode after the faults";
  // After the faults the night is served: both lights go off, acknowledged and executed.
  EXPECT_LT(find(t, sleep, command("living_light", "set_power", "acknowledged")), n);
  EXPECT_LT(find(t, sleep, command("bedroom_light", "set_power", "acknowledged")), n);
  EXPECT_GE(o.connections, 5u) << "every link-breaking fault ends in a reconnection";
  EXPECT_GE(o.registrations, 4u) << "the devices register again after each reconnection";
  EXPECT_GT(l.acknowledged, 10);
}

// The night: the robot comes to the bed, the lights go off and the patrol runs while the link
// is cut again and again (FIN and RST) and truncated in both directions. (The faults start
// after the user lies down: a sensor event lost with a broken link is not sent again, and
// without it there is no SleepMode to test.)
TEST(IcarsFaults, TheNightSurvivesRepeatedCutsAndTruncations) {
  std::vector<Step> steps = {
      {"22:20", "delay 100 ms devices->server", [](FaultProxy& p) { p.delay(100ms, Direction::client_to_server); }},
      {"22:27", "pass", [](FaultProxy& p) { p.pass(); }},
  };
  for (int i = 0; i < 8; ++i) {
    const int minute = 22 * 60 + 32 + 3 * i;
    char at[32];
    std::snprintf(at, sizeof at, "%02d:%02d", minute / 60, minute % 60);
    if (i % 3 == 0) {
      steps.push_back({at, "truncate 500 bytes both ways", [](FaultProxy& p) { p.truncate(500); }});
    } else {
      steps.push_back({at, i % 3 == 1 ? "cut (RST)" : "cut", [i](FaultProxy& p) { p.cut(i % 3 == 1); }});
    }
    std::snprintf(at, sizeof at, "%02d:%02d:30", minute / 60, minute % 60);
    steps.push_back({at, "pass", [](FaultProxy& p) { p.pass(); }});
  }
  const auto o = run_with_faults("23:15", steps);
  expect_clean_exit(o);
  const auto l = check_exactly_once(o);
  report("night", o, l);
  const auto& t = o.trace;
  const auto n = t.size();
  const auto sleep = find(t, 0, transition_to("SleepMode"));
  ASSERT_LT(sleep, n) << "no SleepMode";
  EXPECT_LT(find(t, sleep, command("robot1_wheels", "go_to_waypoint", "acknowledged")), n)
      << "the patrol never got going";
  EXPECT_GE(o.connections, 8u);
  EXPECT_GT(l.acknowledged, 5);
}

// A voice command while a process is stopped (SIGSTOP) for 15 s, longer than the heartbeat
// timeout, so the link is dropped and made again: stopped device manager (the microphone's
// sounds are published when it runs again, into a link the mediator has closed) or stopped
// mediator (the manager's side drops the link; what it publishes meanwhile is held for the
// mediator's re-subscription). Each of the five sentences the user says is heard, once.
TEST(IcarsFaults, EveryVoiceCommandIsHeardAcrossAFifteenSecondStop) {
  for (const bool stop_mediator : {false, true}) {
    const std::string who = stop_mediator ? "mediator" : "device manager";
    SCOPED_TRACE("stopped: " + who);
    const std::vector<Step> steps = {
        {"18:13:30", "SIGSTOP the " + who + " for 15 s", nullptr,
         [stop_mediator](planet_test::ChildProcess& mediator, planet_test::ChildProcess& devices) {
           auto& stopped = stop_mediator ? mediator : devices;
           stopped.freeze();
           std::this_thread::sleep_for(15s);  // the fault itself: 150 simulated minutes
           stopped.thaw();
         }},
    };
    const auto o = run_with_faults("21:30", steps);
    expect_clean_exit(o);
    const auto l = check_exactly_once(o);
    report(stop_mediator ? "stopped mediator" : "stopped device manager", o, l);
    std::vector<std::string> heard;
    std::string records;
    for (const auto& j : o.trace) {
      // Each sound once: the phrase, or "?" for speech heard but not recognized (a recognizer's
      // mistake is not a lost sentence).
      if (str(j, "kind") == "speech") heard.push_back(str(j, "words").empty() ? "?" : str(j, "words"));
      if (str(j, "kind") == "speech" || str(j, "kind") == "device") records += j.dump() + "\n";
    }
    // As the voice behaviors declare them (the recognizer reports the phrase, not the sentence).
    const std::vector<std::string> said = {"turn on the tv", "channel 5", "volume up", "play music", "stop"};
    // Once each: five sounds, in order, also those said while the link was down (the microphone
    // sends them again when its capture resumes). What the recognizer made of each is another
    // matter: a sentence said while no voice behavior listened (the policy waiting out the
    // fault in Standby) is decoded as free speech ("volume of"); the first, before the fault,
    // is the phrase.
    ASSERT_EQ(heard.size(), said.size()) << "every sentence heard once, in order:\n" << records;
    // The first, said before the fault, is decoded against the phrases: the phrase, or not
    // recognized (the recognizer misses about one command in eight in this room: docs/speech.md),
    // never free speech or another command.
    EXPECT_TRUE(heard.front() == said.front() || heard.front() == "?") << records;
    EXPECT_GE(o.registrations, 2u) << "the link was dropped and the devices registered again";
  }
}
