// icars-mqtt-bridge: a device manager for a real home's MQTT devices. It reads the Home
// Assistant discovery configs that zigbee2mqtt, Tasmota, ESPHome and Shelly publish, turns each
// supported entity into an ICARS device (home::mqtt::MqttDevices) and registers them with the
// mediating server, like icars-device-manager does for the simulated house (docs/mqtt.md).
//
//   icars-mqtt-bridge --broker mqtt://127.0.0.1:1883 --server 127.0.0.1:7000
//                     [--placements FILE] [--house HOUSE] [--username U --password-file F] [--ca-file CA]
//
// Prints "BROKER CONNECTED" and "BROKER DOWN <reason>" as the broker link comes and goes,
// "DEVICE <id> <type> <room> online|offline" as devices are discovered and change, and
// "REGISTERED <round> <devices>" after each registration round with the server. A broker that
// refuses the bridge (wrong password, unknown client) ends it with "BROKER REFUSED <reason>" and
// exit code 3; bad options or files end it with 2. Stops on SIGINT/SIGTERM.
#include <CLI/CLI.hpp>

#include <atomic>
#include <chrono>
#include <csignal>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <string>
#include <thread>

#include "icars/bridge/mqtt/client.h"
#include "icars/device/device_manager.h"
#include "icars/home/mqtt/entity_devices.h"
#include "icars/home/mqtt/placements.h"
#include "icars/home/sim/sim_mqtt_devices.h"
#include "icars/planet/communicator.h"
#include "icars/planet/endpoint.h"
#include "security_options.h"

namespace mqtt = icars::bridge::mqtt;
namespace hm = icars::home::mqtt;

namespace {

std::string first_line(const std::string& file) {
  std::ifstream in(file);
  std::string line;
  if (!in || !std::getline(in, line)) throw std::runtime_error("cannot read " + file);
  while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
  return line;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"ICARS bridge: a home's MQTT devices (Home Assistant discovery) as ICARS devices"};
  std::string broker = "mqtt://127.0.0.1:1883";
  std::string server = "127.0.0.1:7000";
  std::string client_id = "icars-mqtt-bridge";
  std::string username;
  std::string password_file;
  std::string ca_file;
  std::string placements_file;
  std::string prefix = "homeassistant";
  int timeout_ms = 5000;
  app.add_option("--broker", broker, "the MQTT broker, mqtt://HOST[:PORT] or mqtts://HOST[:PORT]");
  app.add_option("--client-id", client_id, "this bridge's MQTT client id");
  app.add_option("--username", username, "user name at the broker");
  app.add_option("--password-file", password_file, "file holding the broker password (its first line)")
      ->check(CLI::ExistingFile);
  app.add_option("--ca-file", ca_file, "CA certificate the broker's TLS certificate is checked against")
      ->check(CLI::ExistingFile);
  app.add_option("--placements", placements_file, "where the entities stand and their device names (docs/mqtt.md)")
      ->check(CLI::ExistingFile);
  std::string house_file;
  app.add_option("--house", house_file,
                 "a house file whose <device mqtt=UNIQUE_ID> elements place those entities (docs/house.md)")
      ->check(CLI::ExistingFile);
  app.add_option("--discovery-prefix", prefix, "the discovery topic prefix");
  app.add_option("--command-timeout", timeout_ms, "ms a command waits for the device's state to confirm it")
      ->check(CLI::Range(100, 600'000));
  app.add_option("--server", server, "the mediating server, host:port");
  std::string pun;
  app.add_option("--pun", pun, "this endpoint's PLANET name");
  icars::app::DeviceManagerSecurity security;
  icars::app::add_device_manager_options(app, security);
  CLI11_PARSE(app, argc, argv);
  const auto signals = icars::app::block_stop_signals();

  mqtt::ClientOptions client_options;
  icars::planet::Endpoint endpoint;
  hm::MqttDevicesOptions device_options;
  icars::planet::CommunicatorOptions comm;
  try {
    const auto b = mqtt::parse_broker_uri(broker);
    client_options.host = b.host;
    client_options.port = b.port;
    client_options.client_id = client_id;
    client_options.username = username;
    if (!password_file.empty()) client_options.password = first_line(password_file);
    client_options.ca_file = ca_file;
    if (b.tls && ca_file.empty()) throw std::invalid_argument("--broker " + broker + " needs --ca-file");
    if (!b.tls && !ca_file.empty()) throw std::invalid_argument("--ca-file needs an mqtts:// broker");
    client_options.validate();
    endpoint = icars::planet::parse_endpoint(server);
    device_options.discovery_prefix = prefix;
    device_options.command_timeout = std::chrono::milliseconds(timeout_ms);
    if (!placements_file.empty()) device_options.placements = hm::load_placements(placements_file);
    if (!house_file.empty()) {
      for (auto& [unique_id, placement] : icars::home::mqtt_placements(icars::sim::load_house(house_file))) {
        if (!device_options.placements.emplace(unique_id, placement).second) {
          throw std::invalid_argument("unique_id " + unique_id + " is placed by both --placements and --house");
        }
      }
    }
    comm.name = "mqtt-bridge";
    comm.pun = pun;
    comm.tls = security.tls;
    if (!security.token_file.empty()) comm.token = icars::app::read_token_file(security.token_file);
  } catch (const std::exception& e) {
    std::cerr << "icars-mqtt-bridge: " << e.what() << "\n";
    return 2;
  }

  std::unique_ptr<mqtt::Client> client;
  try {
    client = std::make_unique<mqtt::Client>(client_options);
  } catch (const std::exception& e) {
    std::cerr << "icars-mqtt-bridge: " << e.what() << "\n";
    return 2;
  }
  std::atomic<bool> broker_up{false};
  std::atomic<bool> refused{false};
  std::mutex out_mutex;
  const auto say = [&out_mutex](const std::string& line) {
    std::lock_guard lock(out_mutex);
    std::cout << line << std::endl;
  };
  client->on_connection([&](bool connected, const std::string& reason) {
    broker_up = connected;
    say(connected ? "BROKER CONNECTED" : "BROKER DOWN " + reason);
  });

  icars::planet::Communicator communicator(comm);
  icars::device::DeviceManager manager(communicator);
  hm::MqttDevices devices(*client, manager, device_options);
  client->start();
  manager.connect(endpoint.host, endpoint.port);

  std::atomic<bool> stopping{false};
  std::thread reporter([&] {
    std::uint64_t reported = 0;
    std::map<std::string, bool> known;  // device id -> online, as last printed
    std::string link_error;
    while (!stopping) {
      if (manager.wait_registered(reported + 1, std::chrono::milliseconds(200))) {
        reported = manager.registration_rounds();
        say("REGISTERED " + std::to_string(reported) + " " + std::to_string(manager.devices().size()));
      }
      for (const auto& d : devices.devices()) {
        const auto it = known.find(d.device_id);
        if (it != known.end() && it->second == d.online) continue;
        known[d.device_id] = d.online;
        say("DEVICE " + d.device_id + " " + d.type + " " + (d.room.empty() ? "-" : d.room) + " " +
            (d.online ? "online" : "offline"));
      }
      if (const auto& peer = manager.peer(); peer && !peer->is_connected()) {
        if (auto error = peer->last_error(); !error.empty() && error != link_error) {
          link_error = std::move(error);
          say("LINK DOWN " + link_error);
        }
      }
      if (client->refused()) {
        refused = true;
        break;
      }
    }
  });
  // Until a stop signal, or the broker refuses the bridge.
  int exit_code = 0;
  for (;;) {
    const timespec wait{0, 200'000'000};
    if (sigtimedwait(&signals, nullptr, &wait) > 0) break;
    if (refused) {
      say("BROKER REFUSED " + client->last_error());
      std::cerr << "icars-mqtt-bridge: " << client->last_error() << "\n";
      exit_code = 3;
      break;
    }
  }
  stopping = true;
  reporter.join();
  client->stop();
  return exit_code;
}
