// Command-line options for a COROS fleet shared by the ICARS programs: the robots' agents beside
// a device manager and the robot market of a mediating server (docs/distribution.md, "Robots").
#pragma once

#include <CLI/CLI.hpp>

#include <cstdint>
#include <string>

#include "icars/coros/knowledge.h"

namespace icars::app {

struct FleetSettings {
  std::uint16_t port = 0;  // the fleet's UDP broadcast port; 0: no fleet
  std::string key_file;    // the fleet key (hex, docs/coros.md)
  bool insecure = false;   // no key on purpose
  std::string address = "127.0.0.1";          // this host's address on the fleet's network
  std::string broadcast = "127.255.255.255";  // the network's broadcast address
  bool enabled() const { return port != 0; }
};

// --fleet-port, --fleet-key, --fleet-insecure, --fleet-address, --fleet-broadcast; `what` says
// what joins the fleet.
void add_fleet_options(CLI::App& app, FleetSettings& fleet, const std::string& what);

// An agent configuration on the fleet (its address, the broadcast address and port, its key),
// with the timings a home uses. Throws std::runtime_error saying what is missing or unreadable.
coros::AgentConfiguration fleet_agent(const FleetSettings& fleet, const std::string& id);

}  // namespace icars::app
