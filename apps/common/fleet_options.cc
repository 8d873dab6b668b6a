#include "fleet_options.h"

#include <stdexcept>

#include "icars/coros/authentication.h"

namespace icars::app {

void add_fleet_options(CLI::App& app, FleetSettings& fleet, const std::string& what) {
  app.add_option("--fleet-port", fleet.port, what + " on this COROS fleet: its UDP broadcast port on the host")
      ->check(CLI::Range(1, 65535));
  app.add_option("--fleet-key", fleet.key_file, "the fleet's key file (hex: openssl rand -hex 32 > fleet.key; docs/coros.md)")
      ->check(CLI::ExistingFile);
  app.add_flag("--fleet-insecure", fleet.insecure, "the fleet's datagrams are neither signed nor checked");
  app.add_option("--fleet-address", fleet.address, "this host's IPv4 address on the fleet's network")
      ->check(CLI::ValidIPV4)
      ->capture_default_str();
  app.add_option("--fleet-broadcast", fleet.broadcast,
                 "the fleet network's broadcast address (robots on other hosts: the subnet's, e.g. 192.168.1.255)")
      ->check(CLI::ValidIPV4)
      ->capture_default_str();
}

coros::AgentConfiguration fleet_agent(const FleetSettings& fleet, const std::string& id) {
  coros::AgentConfiguration c;
  c.id = id;
  c.transport.broadcast_port = fleet.port;
  c.transport.ip = fleet.address;
  c.transport.broadcast_address = fleet.broadcast;
  if (!fleet.key_file.empty()) {
    try {
      c.transport.key = coros::FleetKey::load(fleet.key_file);
    } catch (const std::exception& e) {
      throw std::runtime_error("--fleet-key " + fleet.key_file + ": " + e.what());
    }
  } else if (fleet.insecure) {
    c.transport.insecure = true;
  } else {
    throw std::runtime_error("--fleet-port needs --fleet-key FILE (or --fleet-insecure)");
  }
  return c;
}

}  // namespace icars::app
