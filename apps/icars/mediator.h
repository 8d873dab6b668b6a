// The `icars run` command: a mediating server running a collaboration policy on a house.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "fleet_options.h"
#include "icars/planet/security.h"
#include "live_dashboard.h"

namespace icars::app {

struct RunOptions {
  std::string policy;          // a policy file, or a name in policy_dir
  std::string policy_dir = "examples/smart_home";
  std::string world;           // the house file
  double speed = 1500;         // simulated seconds per wall-clock second; 0: as fast as possible
                               // (lock-step only)
  bool free_running = false;   // the embedded house's clock runs with the wall clock, not in
                               // lock-step with the mediator (icars/clock/lock_step.h)
  std::string until = "07:30"; // stop at this time of day (the next one after the house's start)
  int days = 1;                // ... or the days-th one: run that many simulated days
  std::string trace_file;      // JSON lines
  std::string plot_file;       // SVG
  std::string listen = "127.0.0.1:0";
  bool external = false;       // device managers run elsewhere (icars-device-manager)
  bool quiet = false;          // no timeline on stdout, only the summary
  planet::TlsOptions tls;      // TLS of the listener (docs/security.md)
  std::string access_file;     // who may connect and call what; empty: anyone (loopback only)
  std::vector<std::string> plugins;  // shared libraries adding behavior, adaptor, composer types
  // mqtt://HOST[:PORT] or mqtts://HOST[:PORT]: the house's MQTT devices (docs/house.md) are
  // simulated on this broker and brought in by an MQTT bridge in this process.
  std::string mqtt;
  std::string mqtt_ca_file;    // the CA an mqtts:// broker's certificate is checked against
  // Publish the mediator to Home Assistant on the --mqtt broker (docs/mqtt.md, "Home
  // Assistant's view"), as the device `ha_node_id` (default: icars_<house name>).
  bool home_assistant = false;
  std::string ha_node_id;
  DashboardSettings dashboard;  // --http: the live dashboard (docs/dashboard.md)
  // The robot market (docs/distribution.md, "Robots"): on with --market, or when the house has
  // two robots or more; the embedded house's robots then bid on a fleet of their own (a free
  // port, a fresh key) unless `fleet` names one, which --external needs.
  bool market = false;
  FleetSettings fleet;
  // --external: start the policy once these devices are services (at most 60 s), not as soon as
  // the house's clock is known: the devices its first behaviors need, registered by managers
  // that may come up later.
  std::vector<std::string> wait_for;
};

// Runs until the stop time or SIGINT/SIGTERM; returns the process exit code (0 ok, 1 the run
// failed, 2 bad input: house, policy or options).
int run(const RunOptions& options);

}  // namespace icars::app
