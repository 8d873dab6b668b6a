// `icars run`: a MediatingServer (icars/server/) around a house — simulated device managers in
// this process, or elsewhere — running a policy, with the report observers (icars/report/) for
// the timeline, the JSON-lines trace, the summary and the plot.
#include "mediator.h"
#include "registries.h"
#include "robot_market_host.h"
#include "run_outputs.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <csignal>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "announcement.h"
#include "embedded_mqtt.h"
#include "icars/coros/authentication.h"
#include "icars/clock/lock_step.h"
#include "icars/control/policy_check.h"
#include "icars/home/behaviors.h"
#include "icars/home/clock_follower.h"
#include "icars/home/mqtt/home_assistant.h"
#include "icars/home/sim/house_vocabulary.h"
#include "icars/home/sim/simulated_house.h"
#include "icars/report/recorders.h"
#include "icars/report/run_summary.h"
#include "icars/server/mediating_server.h"
#include "icars/server/plugin.h"
#include "icars/sim/svg_plot.h"

namespace icars::app {

namespace b = icars::behavior;
namespace c = icars::control;
namespace p = icars::planet;
using namespace std::chrono_literals;

namespace {

b::TraceRecord note(Time t, std::string text) {
  b::TraceRecord r;
  r.time = t;
  r.kind = "note";
  r.source = "icars";
  r.text = std::move(text);
  return r;
}

// SIGHUP: reads the access file again and puts it in force; principals removed or changed lose
// their links, and those removed their devices. A broken file changes nothing.
void reload_access(const RunOptions& options, server::MediatingServer& server, Time now,
                   const std::string& house_token) {
  const auto current = server.access();
  if (options.access_file.empty() || !current) {
    server.trace().record(note(now, "SIGHUP: no access file to reload"));
    return;
  }
  std::shared_ptr<p::AccessPolicy> next;
  try {
    next = std::make_shared<p::AccessPolicy>(p::AccessPolicy::load(options.access_file));
    if (const auto* house = current->find("house-devices"); house && !house_token.empty()) next->add(*house);
  } catch (const std::exception& e) {
    server.trace().record(note(now, fmt::format("access file not reloaded, the old one stays in force: {}", e.what())));
    return;
  }
  const auto reload = server.reload_access(next);
  server.trace().record(note(
      now, fmt::format("access file reloaded: {} principals; revoked or changed: {}; {} devices forgotten",
                       reload.principals,
                       reload.changed.empty() ? "none" : fmt::format("{}", fmt::join(reload.changed, ", ")),
                       reload.forgotten_devices)));
}

// What the embedded house's world does, in the trace: effects on devices, robots and users.
home::SimulatedHouseOptions embedded_house(const RunOptions& options, b::Trace& trace, const std::string& token) {
  home::SimulatedHouseOptions house_options;
  house_options.speedup = options.speed;
  house_options.pun = "house-devices";
  house_options.tls = options.tls;
  house_options.token = token;
  house_options.logger = spdlog::default_logger();
  house_options.effects = [&trace](const home::DeviceEffect& e) {
    b::TraceRecord r;
    r.time = e.time;
    r.kind = "effect";
    r.source = e.device;
    r.text = fmt::format("{}: {}{}", e.device, e.what, e.value.empty() ? "" : " " + e.value);
    r.with("device", e.device).with("what", e.what).with("value", e.value)
        .with("request", static_cast<std::int64_t>(e.request_id));
    trace.record(std::move(r));
  };
  return house_options;
}

std::vector<std::uint64_t> trace_world(sim::World& world, b::Trace& trace) {
  std::vector<std::uint64_t> listeners;
  listeners.push_back(world.on_robot_pose([&trace, &world](const std::string& robot, const sim::Pose& pose, bool moving) {
    b::TraceRecord r;
    r.time = world.clock().now();
    r.kind = "robot";
    r.source = robot;
    r.text = fmt::format("{} at ({:.2f}, {:.2f}){}", robot, pose.x, pose.y, moving ? " moving" : "");
    r.with("robot", robot).with("x", pose.x).with("y", pose.y).with("moving", moving);
    trace.record(std::move(r));
  }, sim::World::Listening::observing));
  listeners.push_back(world.on_user([&trace, &world](const sim::UserState& u) {
    const auto posture = std::string(sim::to_string(u.posture));
    b::TraceRecord r;
    r.time = world.clock().now();
    r.kind = "user";
    r.source = u.user;
    r.text = fmt::format("{} {}{} in the {}", u.user, posture, u.furniture.empty() ? "" : " on the " + u.furniture,
                         u.room.empty() ? "house" : u.room);
    r.with("user", u.user).with("x", u.at.x).with("y", u.at.y).with("room", u.room).with("posture", posture)
        .with("furniture", u.furniture);
    trace.record(std::move(r));
  }, sim::World::Listening::observing));
  return listeners;
}

}  // namespace

int run(const RunOptions& options) {
  // Signals are taken by sigtimedwait below: block them before any thread starts.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGHUP);  // reload the access file
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  spdlog::set_level(spdlog::level::warn);
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // the timeline is read live, also through pipes
  auto fail = [](int code, const std::string& what) {
    std::fprintf(stderr, "icars: %s\n", what.c_str());
    return code;
  };

  // --- Inputs: every mistake here is reported before anything starts. ---------------------------
  // Lock-step: the embedded house's clock moves only when the mediator and the devices have
  // done what its last event started, so the run is the same at any speed.
  const bool lock_step = !options.external && !options.free_running;
  if (!options.wait_for.empty() && !options.external) {
    return fail(2, "--wait-for is for --external runs (the embedded house registers before the policy starts)");
  }
  if (options.speed <= 0 && !lock_step) {
    return fail(2, "--speed max needs the lock-step clock of the embedded house (not --external or --free-running)");
  }
  sim::House house;
  try {
    house = sim::load_house(options.world);
  } catch (const std::exception& e) {
    return fail(2, e.what());
  }
  // The house's MQTT devices: simulated on --mqtt and bridged in, or (--external) brought by
  // an icars-mqtt-bridge of a real home.
  const bool mqtt_house = std::any_of(house.devices.begin(), house.devices.end(),
                                      [](const sim::DeviceSpec& d) { return !d.mqtt.empty(); });
  std::optional<bridge::mqtt::ClientOptions> broker;
  try {
    if (!options.mqtt.empty()) {
      const auto uri = bridge::mqtt::parse_broker_uri(options.mqtt);
      if (uri.tls != !options.mqtt_ca_file.empty()) {
        throw std::invalid_argument(uri.tls ? "--mqtt " + options.mqtt + " needs --mqtt-ca-file"
                                            : std::string("--mqtt-ca-file needs an mqtts:// broker"));
      }
      broker.emplace();
      broker->host = uri.host;
      broker->port = uri.port;
      broker->ca_file = options.mqtt_ca_file;
      broker->validate();
    }
    if (options.home_assistant && !broker) {
      throw std::invalid_argument("--publish-to-home-assistant needs --mqtt mqtt://BROKER[:PORT]");
    }
    if (mqtt_house && !options.external) {
      home::mqtt_devices(house);  // types that cannot be simulated over MQTT, at their line
      if (!broker) {
        throw std::invalid_argument(fmt::format(
            "{}: the house has MQTT devices (<device mqtt=\"...\">): give --mqtt mqtt://BROKER[:PORT] to "
            "simulate them on a broker, or run --external with icars-mqtt-bridge for a real home's",
            house.source));
      }
    }
  } catch (const std::exception& e) {
    return fail(2, e.what());
  }
  // The robot market, and the fleet its robots bid on.
  const bool market = options.market || options.fleet.enabled() || house.robots.size() >= 2;
  std::optional<coros::AgentConfiguration> fleet;
  if (market) {
    try {
      if (options.fleet.enabled()) {
        fleet = fleet_agent(options.fleet, "icars");
      } else if (options.external) {
        throw std::invalid_argument(
            "the robot market of an --external run needs the fleet its robots' device managers joined: "
            "--fleet-port PORT --fleet-key FILE");
      } else {
        fleet.emplace();
        fleet->transport.broadcast_port = coros::free_udp_port();
        fleet->transport.key = coros::FleetKey::generate();
      }
    } catch (const std::exception& e) {
      return fail(2, e.what());
    }
  }
  server::ServerOptions server_options;
  server_options.listen = options.listen;
  server_options.policy_dir = options.policy_dir;
  std::optional<Registries> registries;
  try {
    registries.emplace(options.plugins);
  } catch (const server::PluginError& e) {
    return fail(2, e.what());
  }
  // The house first: a device no type can make stops the run at its line.
  if (!options.external) {
    try {
      registries->sim_devices.check(house);
    } catch (const sim::HouseError& e) {
      return fail(2, e.what());
    }
  }
  server_options.behaviors = registries->behaviors;
  server_options.adaptors = registries->adaptors;
  server_options.composers = registries->composers;
  server_options.planet.logger = spdlog::default_logger();
  server_options.planet.tls = options.tls;
  const auto activity = lock_step ? Activity::create() : nullptr;
  server_options.planet.connection.activity = activity;
  const c::PolicyRepository repository(options.policy_dir);
  std::string policy_name;
  try {
    const auto parsed = c::parse_policy_file(repository.path_of(options.policy), server_options.behaviors);
    for (const auto& w : parsed.warnings) std::fprintf(stderr, "%s\n", w.to_string().c_str());
    policy_name = parsed.policy.name;
    // What would go wrong only while running (or never): names the house does not have,
    // conditions on events that cannot reach them.
    const auto problems = c::check_policy(parsed.policy, server_options.behaviors, home::house_vocabulary(house));
    for (const auto& d : problems) std::fprintf(stderr, "%s\n", d.to_string().c_str());
    if (!problems.empty()) return 2;
  } catch (const c::PolicyError& e) {
    for (const auto& d : e.diagnostics()) std::fprintf(stderr, "%s\n", d.to_string().c_str());
    return 2;
  }
  const auto until = parse_time_of_day(options.until);
  if (!until) return fail(2, fmt::format("--until {} is not a time of day (HH:MM)", options.until));
  const auto stop_at = stop_time(house.start_time, *until, options.days);
  // The embedded house authenticates with a token made for this run.
  const std::string house_token = options.access_file.empty() ? "" : p::random_token();
  const std::string bridge_token = options.access_file.empty() ? "" : p::random_token();
  if (!options.access_file.empty()) {
    try {
      auto access = std::make_shared<p::AccessPolicy>(p::AccessPolicy::load(options.access_file));
      if (!options.external) {
        access->add({"house-devices", p::sha256_hex(house_token), "",
                     {std::string(device::kRegistryPath), "/sf/listeners/*"}, {"*"}, house.devices.size() + 16});
        if (mqtt_house) {
          access->add({"mqtt-bridge", p::sha256_hex(bridge_token), "",
                       {std::string(device::kRegistryPath), "/sf/listeners/*"}, {"*"}, house.devices.size() + 16});
        }
      }
      server_options.planet.access = std::move(access);
    } catch (const std::exception& e) {
      return fail(2, e.what());
    }
  }

  // --- The mediating server, and what reports on it. ----------------------------------------------
  // The summary and the stamp clock outlive the server: its trace may record until it is gone.
  report::RunSummary summary(!options.plot_file.empty());
  report::TraceClock stamp;
  std::optional<server::MediatingServer> server;
  try {
    server.emplace(std::move(server_options));
  } catch (const std::invalid_argument& e) {
    return fail(2, fmt::format("--listen {}", e.what()));
  } catch (const std::exception& e) {  // unreadable TLS files, a key that does not match
    return fail(2, e.what());
  }
  auto& trace = server->trace();
  trace.add_sink(summary.sink());
  try {
    add_trace_outputs(trace, options.quiet, options.trace_file);
  } catch (const std::exception& e) {
    return fail(2, e.what());
  }
  // Records are stamped with the house's time once a clock runs.
  server->services().registry().set_call_observer(
      std::make_shared<report::CommandRecorder>(trace, stamp, report::CommandRecorder::house_commands()));
  // Outages of device managers and what came back, in the timeline.
  report::DeviceEventRecorder device_events(server->container(), trace, stamp);
  std::uint16_t bound = 0;
  try {
    bound = server->listen();
  } catch (const std::exception& e) {
    return fail(2, fmt::format("cannot listen on {}: {}", options.listen, e.what()));
  }
  const auto host = server->endpoint().host;
  std::printf("%s\n", app::server_announcement(host, bound, repository.path_of(options.policy), house.name).c_str());
  // The live dashboard, from now on: it sees the house register and the policy start.
  DriverControl driver_control;
  std::shared_ptr<dashboard::Dashboard> board;
  if (!options.dashboard.listen.empty()) {
    try {
      board = start_run_dashboard(options.dashboard, house, *server, driver_control);
    } catch (const std::exception& e) {
      return fail(2, fmt::format("--http {}: {}", options.dashboard.listen, e.what()));
    }
  }

  // --- The house: simulated device managers in this process, or elsewhere. -------------------
  std::unique_ptr<home::SimulatedHouse> simulated;
  std::unique_ptr<EmbeddedMqttBridge> mqtt_bridge;  // goes before the house whose clock it reads
  std::unique_ptr<SimClock> own_clock;
  std::vector<std::uint64_t> world_listeners;
  SimClock* clock = nullptr;
  if (!options.external) {
    auto house_options = embedded_house(options, trace, house_token);
    house_options.device_types = registries->sim_devices;
    house_options.activity = activity;
    house_options.fleet = fleet;
    if (mqtt_house) {
      house_options.mqtt.emplace();
      house_options.mqtt->broker = *broker;
    }
    try {
      simulated = std::make_unique<home::SimulatedHouse>(house, std::move(house_options));
    } catch (const sim::HouseError& e) {  // a device's parameters its type cannot use
      return fail(2, e.what());
    }
    world_listeners = trace_world(simulated->world(), trace);
    try {
      simulated->start("127.0.0.1", bound);
    } catch (const std::exception& e) {  // the broker of the MQTT devices cannot be reached
      return fail(1, e.what());
    }
    if (!simulated->manager().wait_registered(1, 30s)) {
      return fail(1, fmt::format("the house's devices did not register: {}", simulated->manager().last_error()));
    }
    if (mqtt_house) {
      EmbeddedMqttOptions bridge_options;
      bridge_options.broker = *broker;
      bridge_options.token = bridge_token;
      bridge_options.tls = options.tls;
      bridge_options.activity = activity;
      bridge_options.logger = spdlog::default_logger();
      mqtt_bridge = std::make_unique<EmbeddedMqttBridge>(house, simulated->clock(), std::move(bridge_options));
      mqtt_bridge->start("127.0.0.1", bound, simulated->mqtt());
      std::string why;
      if (!mqtt_bridge->wait_registered(server->services().registry(), 30s, why)) return fail(1, why);
    }
    clock = &simulated->clock();
    std::printf("[icars] %zu devices registered, %zu services\n", simulated->manager().devices().size(),
                server->container().all().size());
  } else {
    own_clock = std::make_unique<SimClock>(house.start_time);
    clock = own_clock.get();
    std::printf("[icars] waiting for device managers (icars-device-manager --server %s:%u)\n", host.c_str(), bound);
  }
  stamp.set(clock);
  // Before the clock goes: the behaviors stop, and the server's io thread, which may still end
  // calls, no longer stamps records with it.
  struct ClockRelease {
    server::MediatingServer& server;
    report::TraceClock& stamp;
    ~ClockRelease() {
      server.stop();
      stamp.set(nullptr);
    }
  } release_clock{*server, stamp};
  std::unique_ptr<home::ClockFollower> follower;
  if (own_clock) follower = std::make_unique<home::ClockFollower>(*own_clock, server->container());
  report::ServiceRecorder heard(server->container(), trace, options.external);
  server->use_clock(*clock);
  // Home Assistant's view, from the policy's start on.
  std::unique_ptr<home::mqtt::HomeAssistantPublisher> home_assistant;
  if (options.home_assistant) {
    home::mqtt::HomeAssistantOptions ha;
    ha.node_id = options.ha_node_id.empty() ? home::mqtt::name_of("icars_" + house.name) : options.ha_node_id;
    ha.name = "ICARS " + house.name;
    for (const auto& d : house.devices) ha.devices.push_back({d.id, d.type, d.room, d.carrier});
    for (const auto& r : house.robots) ha.robots.push_back({r.id, r.start.x, r.start.y});
    ha.room_at = [&house](double x, double y) {
      const auto* room = house.room_at({x, y});
      return room ? room->name : std::string();
    };
    ha.logger = spdlog::default_logger();
    try {
      home_assistant = std::make_unique<home::mqtt::HomeAssistantPublisher>(*server, *broker, std::move(ha));
      home_assistant->start();
    } catch (const std::invalid_argument& e) {  // --ha-node-id
      return fail(2, e.what());
    } catch (const std::exception& e) {  // the broker cannot be reached
      return fail(1, e.what());
    }
  }

  // --- Behaviors, tasks and the Coordinator. -------------------------------------------------------
  if (follower) {
    // Start once the simulation's time is known, so timers count from the house's clock.
    while (!follower->following()) {
      const timespec wait{0, 50'000'000};
      const int signal = sigtimedwait(&signals, nullptr, &wait);
      if (signal == SIGHUP) {
        reload_access(options, *server, clock->now(), house_token);
      } else if (signal > 0) {
        return 0;
      }
    }
  }
  if (!options.wait_for.empty()) {
    const auto has_devices = [&] {
      for (const auto& id : options.wait_for) {
        if (server->container().find(service::ServiceQuery{}.on_device(id).available()).empty()) return false;
      }
      return true;
    };
    const auto give_up = std::chrono::steady_clock::now() + 60s;
    while (!has_devices() && std::chrono::steady_clock::now() < give_up) {
      const timespec wait{0, 50'000'000};
      if (sigtimedwait(&signals, nullptr, &wait) > 0) return 0;
    }
    if (!has_devices()) {
      trace.record(note(clock->now(), fmt::format("not every device of --wait-for is here after 60 s ({}); the policy "
                                                  "starts without them",
                                                  fmt::join(options.wait_for, ", "))));
    }
  }
  std::unique_ptr<RobotMarketHost> robot_market;
  if (fleet) {
    home::RobotMarketOptions market_options;
    market_options.agent = *fleet;
    market_options.agent.id = "icars";
    if (lock_step) market_options.activity = activity;
    try {
      robot_market = std::make_unique<RobotMarketHost>(*server, std::move(market_options));
    } catch (const std::exception& e) {
      return fail(2, fmt::format("the robot market: {}", e.what()));
    }
  }
  const auto started_at = clock->now();
  const auto wall_start = std::chrono::steady_clock::now();
  try {
    server->run_policy(options.policy);
  } catch (const c::PolicyError& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 2;
  }

  std::optional<LockStepDriver> driver;
  if (lock_step) {
    LockStepOptions pace;
    pace.speedup = options.speed;
    pace.until = stop_at;
    pace.warn = [&trace](Time t, const std::string& what) { trace.record(note(t, what)); };
    driver.emplace(simulated->clock(), *activity, std::move(pace));
    driver->start();
    driver_control.attach(&*driver);
  }
  bool interrupted = false;
  while (driver ? !driver->finished() : clock->now() < stop_at) {
    const timespec wait{0, 20'000'000};
    const int signal = sigtimedwait(&signals, nullptr, &wait);
    if (signal == SIGHUP) {
      reload_access(options, *server, clock->now(), house_token);
    } else if (signal > 0) {
      interrupted = true;
      break;
    }
  }
  driver_control.attach(nullptr);
  if (driver) driver->stop();
  const auto ended_at = clock->now();
  server->stop_policy(5s);
  // The run is over: the house's devices going away with it are no outage to report.
  device_events.stop();
  spdlog::set_level(spdlog::level::err);
  if (mqtt_bridge) mqtt_bridge->stop();
  if (home_assistant) home_assistant->stop();
  if (simulated) {
    for (const auto id : world_listeners) simulated->world().remove_listener(id);
  }
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();

  const auto pace = options.speed > 0 ? fmt::format("at {:g}x", options.speed) : std::string("as fast as possible");
  summary.print(stdout, policy_name, started_at, ended_at, wall,
                lock_step ? "lock-step " + pace : (options.external ? "following the house's clock " : "free-running ") + pace);
  if (interrupted) std::printf("(interrupted)\n");
  if (!options.plot_file.empty()) {
    try {
      const auto title = fmt::format("{} on {}", policy_name, house.name);
      sim::write_svg(options.plot_file, house, summary.plot(title, house, started_at, ended_at));
      std::printf("plot: %s\n", options.plot_file.c_str());
    } catch (const std::exception& e) {
      return fail(1, e.what());
    }
  }
  if (!options.trace_file.empty()) std::printf("trace: %s\n", options.trace_file.c_str());
  return 0;
}

}  // namespace icars::app
