// icars-device-manager: runs the simulated house of a house file and hosts its devices as a
// device manager (ICARS paper 3.2, 5.1): it serves every device's capabilities over PLANET,
// registers them with the mediating server, and registers them again whenever the link to the
// server comes back.
//
//   icars-device-manager --house houses/paper_house.xml --server 127.0.0.1:7000 [--speedup 60]
//                        [--server HOST:PORT --failover-after SECONDS]
//                        [--effects FILE] [--epoch UNIX_MS] [--state FILE]
//                        [--fleet-port PORT --fleet-key FILE]
//
// Prints "REGISTERED <round> <devices>" after each complete registration round (tests wait on
// it), "SERVER <host:port>" when it moved to another of several --server, and "LINK DOWN <reason>" whenever the server cannot be reached or denies the connection. With --effects, writes one JSON line per command a device executed (its effect, with the
// request id of the call), the device side of the record `icars run --trace` keeps of the
// commands it sent. With --epoch, device managers of one simulation started (or restarted) at
// different times run on the same simulated time. With --state, the simulated actuators and
// robots keep their state in FILE and come back from it when the manager restarts, even after
// SIGKILL (docs/house.md, "State file"); it prints "STATE restored|new|rejected FILE" first.
// With --mqtt, the house's MQTT devices are simulated on that broker (docs/house.md, "MQTT
// devices") for an icars-mqtt-bridge to bring in. With --fleet-port, every robot whose wheels it
// hosts is a COROS agent of that fleet bidding for a robot market's errands (docs/distribution.md,
// "Robots"); it prints "FLEET <robots>" once they run.
// Stops on SIGINT/SIGTERM.
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <iostream>
#include <memory>
#include <mutex>
#include <set>
#include <thread>

#include "icars/home/sim/simulated_house.h"
#include "icars/planet/endpoint.h"
#include "fleet_options.h"
#include "security_options.h"

namespace home = icars::home;

int main(int argc, char** argv) {
  CLI::App app{"ICARS device manager for a simulated house"};
  std::string house_file;
  std::vector<std::string> servers;
  double failover_after_s = 10;
  double speedup = 1.0;
  std::vector<std::string> only;
  bool engines = true;
  bool simulator = true;
  std::string pun;
  std::string effects_file;
  app.add_option("--house", house_file, "house file (docs/house.md)")->required()->check(CLI::ExistingFile);
  app.add_option("--server", servers,
                 "the mediating server, host:port (default 127.0.0.1:7000); several: servers of one logical "
                 "mediating server, moved to in turn when the current one is unreachable (docs/distribution.md)")
      ->allow_extra_args(false);
  app.add_option("--failover-after", failover_after_s,
                 "with several --server: seconds the current one may be unreachable before moving to the next")
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  app.add_option("--speedup", speedup, "simulated seconds per wall-clock second")->check(CLI::PositiveNumber);
  app.add_option("--devices", only, "host only these device ids (default: all)")->delimiter(',');
  app.add_flag("!--no-engines", engines, "do not host the speech and vision engines");
  std::string speech_model = icars::home::sim_speech_model_dir();
  app.add_option("--speech-model", speech_model,
                 "the speech engine's PocketSphinx model directory (with en-us/ and cmudict-en-us.dict); "
                 "\"stock\": Debian's en-us model; default: the one adapted to the simulated voices "
                 "(docs/speech.md), when it was built");
  app.add_flag("!--no-simulator", simulator, "do not host the Simulation control device");
  app.add_option("--pun", pun, "this endpoint's PLANET name");
  app.add_option("--effects", effects_file, "write what the devices executed to this file (JSON lines)");
  std::int64_t epoch_ms = 0;
  app.add_option("--epoch", epoch_ms,
                 "wall-clock time (ms since 1970, UTC) at which the simulation is at the house's start: "
                 "before it the clock holds, after it a (re)started manager first runs its house forward "
                 "to the simulated time of now, in step with the other managers given the same epoch")
      ->check(CLI::PositiveNumber);
  icars::app::FleetSettings fleet;
  icars::app::add_fleet_options(app, fleet, "each robot whose wheels this manager hosts bids for errands");
  std::string state_file;
  app.add_option("--state", state_file,
                 "keep the simulated devices' and robots' state in this file (JSON, written atomically "
                 "on every change) and start from it when it exists and matches the house "
                 "(docs/house.md); use the same --epoch when restarting");
  std::string mqtt;
  app.add_option("--mqtt", mqtt,
                 "MQTT broker, mqtt://HOST[:PORT]: the house's MQTT devices (<device mqtt=...>) are simulated "
                 "there as zigbee2mqtt serves real ones, for icars-mqtt-bridge --house to bring in (without "
                 "it they are not hosted)");
  std::string mqtt_ca_file;
  app.add_option("--mqtt-ca-file", mqtt_ca_file, "CA the mqtts:// broker's certificate is checked against")
      ->check(CLI::ExistingFile);
  icars::app::DeviceManagerSecurity security;
  icars::app::add_device_manager_options(app, security);
  CLI11_PARSE(app, argc, argv);
  const auto signals = icars::app::block_stop_signals();

  icars::sim::House house;
  try {
    house = icars::sim::load_house(house_file);
  } catch (const std::exception& e) {
    std::cerr << "icars-device-manager: " << e.what() << "\n";
    return 2;
  }
  if (servers.empty()) servers.push_back("127.0.0.1:7000");
  std::vector<icars::device::DeviceManager::ServerAddress> addresses;
  for (const auto& server : servers) {
    try {
      const auto endpoint = icars::planet::parse_endpoint(server);
      addresses.push_back({endpoint.host, endpoint.port});
    } catch (const std::invalid_argument& e) {
      std::cerr << "icars-device-manager: --server " << e.what() << "\n";
      return 2;
    }
  }

  // Every line is flushed at once: the file is complete whenever the process stops.
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> effects(nullptr, &std::fclose);
  if (!effects_file.empty()) {
    effects.reset(std::fopen(effects_file.c_str(), "w"));
    if (!effects) {
      std::cerr << "icars-device-manager: cannot write --effects " << effects_file << "\n";
      return 2;
    }
  }
  std::mutex effects_mutex;

  home::SimulatedHouseOptions options;
  options.speedup = speedup;
  options.devices = std::set<std::string>(only.begin(), only.end());
  options.engines = engines;
  options.speech_model_dir = speech_model == "stock" ? std::string() : speech_model;
  options.simulator = simulator;
  options.pun = pun;
  options.tls = security.tls;
  options.state_file = state_file;
  if (fleet.enabled()) {
    try {
      options.fleet = icars::app::fleet_agent(fleet, "robot");
    } catch (const std::exception& e) {
      std::cerr << "icars-device-manager: " << e.what() << "\n";
      return 2;
    }
  }
  if (!mqtt.empty()) {
    try {
      const auto uri = icars::bridge::mqtt::parse_broker_uri(mqtt);
      if (uri.tls != !mqtt_ca_file.empty()) {
        throw std::invalid_argument(uri.tls ? "--mqtt " + mqtt + " needs --mqtt-ca-file"
                                            : std::string("--mqtt-ca-file needs an mqtts:// broker"));
      }
      options.mqtt.emplace();
      options.mqtt->broker.host = uri.host;
      options.mqtt->broker.port = uri.port;
      options.mqtt->broker.ca_file = mqtt_ca_file;
      options.mqtt->broker.validate();
    } catch (const std::exception& e) {
      std::cerr << "icars-device-manager: --mqtt " << e.what() << "\n";
      return 2;
    }
  }
  if (!security.token_file.empty()) {
    try {
      options.token = icars::app::read_token_file(security.token_file);
    } catch (const std::exception& e) {
      std::cerr << "icars-device-manager: " << e.what() << "\n";
      return 2;
    }
  }
  if (effects) {
    options.effects = [&effects, &effects_mutex](const home::DeviceEffect& e) {
      nlohmann::ordered_json j;
      j["t"] = e.time.count();
      j["time"] = icars::format_time(e.time);
      j["kind"] = "effect";
      j["device"] = e.device;
      j["what"] = e.what;
      j["value"] = e.value;
      j["request"] = e.request_id;
      const auto line = j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
      std::lock_guard lock(effects_mutex);
      std::fputs(line.c_str(), effects.get());
      std::fflush(effects.get());
    };
  }
  std::unique_ptr<home::SimulatedHouse> simulation;
  try {
    simulation = std::make_unique<home::SimulatedHouse>(std::move(house), options);
  } catch (const std::exception& e) {
    std::cerr << "icars-device-manager: " << e.what() << "\n";
    return 2;
  }
  auto& manager = simulation->manager();
  if (auto* agents = simulation->robot_agents(); agents && agents->agents().empty()) {
    std::cerr << "icars-device-manager: --fleet-port: this manager hosts no robot's Wheels\n";
    return 2;
  }
  if (epoch_ms > 0) {
    // The simulated time the wall clock stands for: house start + (now - epoch) * speedup.
    const auto start = simulation->clock().now();
    const auto simulated_now = [&] {
      const auto wall = std::chrono::duration_cast<std::chrono::milliseconds>(
          std::chrono::system_clock::now().time_since_epoch());
      return start + icars::Time(static_cast<std::int64_t>(static_cast<double>(wall.count() - epoch_ms) * speedup));
    };
    while (simulated_now() < start) {
      const timespec wait{0, 10'000'000};
      if (sigtimedwait(&signals, nullptr, &wait) > 0) return 0;
    }
    // Twice: the second advance covers the simulated time that passed during the first.
    simulation->clock().advance_to(simulated_now());
    simulation->clock().advance_to(simulated_now());
  }
  if (auto* state = simulation->state_file()) {
    using Loaded = home::SimStateFile::Loaded;
    const auto loaded = state->loaded();
    std::cout << "STATE "
              << (loaded == Loaded::restored ? "restored" : loaded == Loaded::rejected ? "rejected" : "new")
              << ' ' << state->path().string() << std::endl;
  }
  try {
    if (addresses.size() == 1) {
      simulation->start(addresses.front().host, addresses.front().port);
    } else {
      simulation->start(addresses, std::chrono::milliseconds(static_cast<std::int64_t>(failover_after_s * 1000)));
    }
    if (auto* agents = simulation->robot_agents()) {
      std::string ids;
      for (auto* a : agents->agents()) ids += (ids.empty() ? "" : ",") + a->id();
      std::cout << "FLEET " << ids << std::endl;
    }
  } catch (const std::exception& e) {
    std::cerr << "icars-device-manager: " << e.what() << "\n";
    return 2;
  }
  std::cout << "STARTED " << manager.devices().size() << " devices, simulated time "
            << icars::format_time(simulation->clock().now()) << std::endl;

  // Report registration rounds until a stop signal arrives.
  std::atomic<bool> stopping{false};
  std::thread reporter([&] {
    std::uint64_t reported = 0;
    std::uint64_t failovers = 0;
    std::string link_error;
    while (!stopping) {
      if (manager.wait_registered(reported + 1, std::chrono::milliseconds(200))) {
        reported = manager.registration_rounds();
        std::cout << "REGISTERED " << reported << ' ' << manager.devices().size() << std::endl;
      }
      // The server it moved to (several --server), once per move.
      if (const auto moves = manager.failovers(); moves != failovers) {
        failovers = moves;
        std::cout << "SERVER " << manager.current_server() << std::endl;
      }
      // Why the link to the server is down (denied, TLS failure, unreachable), once per change.
      if (const auto& peer = manager.peer(); peer && !peer->is_connected()) {
        if (auto error = peer->last_error(); !error.empty() && error != link_error) {
          link_error = std::move(error);
          std::cout << "LINK DOWN " << link_error << std::endl;
        }
      }
    }
  });
  int sig = 0;
  sigwait(&signals, &sig);
  stopping = true;
  reporter.join();
  return 0;
}
