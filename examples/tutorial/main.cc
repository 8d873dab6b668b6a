// Tutorial, step 6: the whole application in one process (docs/tutorial.md).
//
//   tutorial [POLICY]     (default: cooling.xml beside this file)
//
// The three roles meet here: the mediating server (icars::server::MediatingServer, taught the new
// behavior and adaptors), a device manager hosting the fan over loopback PLANET, and the policy
// running on the server's behavior runtime. Time is simulated and advanced by hand through a hot afternoon.
// It prints the timeline and exits 0 only if the fan ran while it was hot, the statechart went
// Normal -> Cooling -> Normal, and the fan stopped again (the ctest tutorial_runs runs it).
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <functional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "cool_down.h"
#include "devices.h"
#include "icars/clock/sim_clock.h"
#include "icars/device/device_manager.h"
#include "icars/server/mediating_server.h"
#include "services.h"

namespace b = icars::behavior;
namespace c = icars::control;
namespace p = icars::planet;
using namespace std::chrono_literals;

namespace {

constexpr auto kPatience = 20s;  // generous: the checks wait for outcomes, never for time

void expect(bool ok, const std::string& what) {
  if (!ok) throw std::runtime_error(what);
}

template <class Pred>
bool eventually(Pred pred) {
  const auto deadline = std::chrono::steady_clock::now() + kPatience;
  while (!pred()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(5ms);
  }
  return true;
}

p::CommunicatorOptions quiet(std::string name) {
  p::CommunicatorOptions options;
  options.name = std::move(name);
  options.logger = spdlog::default_logger();
  return options;
}

int run(const std::string& policy_file) {
  spdlog::set_level(spdlog::level::warn);

  icars::SimClock clock(icars::at_time(0, 12, 0));  // day 0, noon

  // --- The mediating server, taught the new behavior and adaptors. ---
  icars::server::ServerOptions options;
  options.planet = quiet("icars");
  b::register_generic_behaviors(options.behaviors);  // Wait, Emit
  tutorial::register_tutorial_behaviors(options.behaviors);
  tutorial::add_adaptors(options.adaptors);
  // The policy, checked before anything starts.
  const auto parsed = c::parse_policy_file(policy_file, options.behaviors);  // throws PolicyError
  for (const auto& warning : parsed.warnings)
    std::fprintf(stderr, "%s\n", warning.to_string().c_str());
  icars::server::MediatingServer server(std::move(options));
  const std::uint16_t port = server.listen();

  // The timeline: printed, and kept for the checks.
  b::Trace& trace = server.trace();
  b::TraceLog log;
  trace.add_sink(b::timeline_printer(stdout));
  trace.add_sink(log.sink());

  // --- The device provider: a smart fan in the living room, hosted by a device manager. ---
  p::Communicator devices(quiet("devices"));
  auto fan = std::make_shared<tutorial::SimFan>([&trace, &clock](std::int32_t percent) {
    b::TraceRecord r;
    r.time = clock.now();
    r.kind = "effect";
    r.source = "living_fan";
    r.text = fmt::format("living_fan: speed {}%", percent);
    trace.record(std::move(r));
  });
  auto thermometer =
      std::make_shared<tutorial::SimThermometer>("living_fan", "living_room", clock, 22.0);
  auto smart_fan = std::make_shared<icars::device::Device>("living_fan", "SmartFan", "living_room");
  smart_fan->add("fan", fan).add("thermometer", thermometer);
  icars::device::DeviceManager manager(devices);
  manager.add(smart_fan);
  manager.connect("127.0.0.1", port);
  expect(manager.wait_registered(1, kPatience),
         "the fan did not register: " + manager.last_error());
  // The thermometer's adaptor subscribes asynchronously once the device registered.
  expect(eventually([&] { return thermometer->subscribers() == 1; }),
         "the thermometer adaptor did not subscribe");
  for (const auto& service : server.container().all()) {
    std::printf("[tutorial] service %s (%s) in the %s\n", service->id().c_str(),
                service->type().c_str(), service->attributes().room.c_str());
  }

  // --- The application: the policy's Coordinator, on the server's behavior runtime. ---
  server.use_clock(clock);
  server.run_policy(policy_file);
  auto* coordinator = server.coordinator();
  auto& runtime = *server.runtime();

  // Waits until the timeline shows `what`, then until the runtime has nothing left to do.
  auto wait_for = [&](const std::string& what, std::function<bool(const b::TraceRecord&)> pred) {
    expect(log.wait_for(pred, kPatience), "timed out waiting for " + what);
    expect(runtime.drain(kPatience), "the behavior runtime did not settle");
  };
  auto task_event = [](std::string task, std::string event, std::string celsius) {
    return [=](const b::TraceRecord& r) {
      return r.kind == "event" && r.source == task && r.field("event") == event &&
             r.field("celsius") == celsius;
    };
  };
  // The weather: the room reaches `celsius` at `at`; the thermometer reads it a minute later.
  auto weather = [&](icars::Time at, double celsius) {
    clock.advance_to(at);
    thermometer->set_room_temperature(celsius);
    clock.advance_by(1min);
  };

  // 12:00, 22 C: Normal; CoolDown's first reading makes sure the fan is off.
  wait_for("the fan to be off at noon", task_event("Watch", "Comfortable", "22"));
  expect(coordinator->current() == "Normal",
         "at noon the state is " + coordinator->current() + ", not Normal");
  expect(fan->current_speed() == 0, "the fan runs at noon");

  // 14:00, the afternoon sun: 28.5 C. The fan starts and the statechart moves to Cooling, whose
  // CoolDown (hot=24) takes over the running fan.
  weather(icars::at_time(0, 14, 0), 28.5);
  wait_for("Cooling to take over the fan", task_event("Cool", "TooHot", "28.5"));
  expect(coordinator->current() == "Cooling",
         "at 14:01 the state is " + coordinator->current() + ", not Cooling");
  expect(fan->current_speed() == 100,
         fmt::format("at 14:01 the fan runs at {}%, not 100%", fan->current_speed()));

  // 16:00, 25 C: below Watch's 26 but above Cooling's 24, so the fan keeps running.
  weather(icars::at_time(0, 16, 0), 25.0);
  wait_for("the fan to stay on at 25 C", [](const b::TraceRecord& r) {
    return r.kind == "note" && r.source == "Cool/CoolDown" &&
           r.text.ends_with("25.0 C: the fan stays on");
  });
  expect(coordinator->current() == "Cooling",
         "at 16:01 the state is " + coordinator->current() + ", not Cooling");
  expect(fan->current_speed() == 100, "the fan stopped at 25 C");

  // 18:00, evening: 23.5 C. The fan stops and the statechart returns to Normal.
  weather(icars::at_time(0, 18, 0), 23.5);
  wait_for("Normal to watch again", task_event("Watch", "Comfortable", "23.5"));
  expect(coordinator->current() == "Normal",
         "at 18:01 the state is " + coordinator->current() + ", not Normal");
  expect(fan->current_speed() == 0,
         fmt::format("at 18:01 the fan runs at {}%", fan->current_speed()));

  server.stop();
  std::vector<std::string> transitions;
  for (const auto& r : log.of_kind("transition")) transitions.push_back(r.text);
  expect(transitions == std::vector<std::string>{"Normal -> Cooling on TooHot",
                                                 "Cooling -> Normal on Comfortable"},
         fmt::format("unexpected transitions: {}", fmt::join(transitions, "; ")));
  std::printf("[tutorial] ok: the fan ran from 14:01 to 18:01; %zu transitions\n",
              transitions.size());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string policy = argc > 1 ? argv[1] : ICARS_TUTORIAL_POLICY;
  try {
    return run(policy);
  } catch (const c::PolicyError& e) {
    std::fprintf(stderr, "%s\n", e.what());  // every problem, as file:line: error: ...
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "[tutorial] FAILED: %s\n", e.what());
    return 1;
  }
}
