// The `icars serve` command: one server of a logical mediating server made of several processes
// (docs/distribution.md). Every server shares the devices registered on it, uses the devices of
// its peers as its own services, and runs behavior subtrees that other servers' policies place
// on it; the one given a policy is the coordinator, which owns the statechart.
#pragma once

#include <string>
#include <vector>

#include "fleet_options.h"
#include "icars/planet/security.h"

namespace icars::app {

struct ServeOptions {
  std::string name = "icars";  // how policies (host="NAME") and the other servers name this one
  std::string listen = "127.0.0.1:0";
  // The other servers: "NAME=HOST:PORT", from the command line and from `peers_file` (one per
  // line; '#' starts a comment).
  std::vector<std::string> peers;
  std::string peers_file;
  // The coordinator's: a policy (a file, or a name in policy_dir) and, optionally, the house
  // it runs on (its names are checked, and --until counts from its start).
  std::string policy;
  std::string policy_dir = "examples/smart_home";
  std::string world;
  // The coordinator starts its policy once these devices are services here (registered here
  // or at a peer), waiting at most 60 s: the devices its first behaviors need.
  std::vector<std::string> wait_for;
  std::string until;            // stop at this time of day (needs --world); "": on SIGINT/SIGTERM
  int days = 1;
  bool wall_clock = false;      // behaviors count wall time, not the simulated house's
  std::string trace_file;       // JSON lines; every record names this server ("server")
  bool quiet = false;
  planet::TlsOptions tls;       // of the listener, and of the links to the peers
  std::string access_file;      // who may connect and call what (peers need a principal too)
  std::string token_file;       // the token this server presents to its peers
  std::vector<std::string> plugins;
  // The robot market of the behaviors running here (docs/distribution.md, "Robots"): on when
  // the fleet is given; give it to the server whose behaviors ask for robot="any".
  FleetSettings fleet;
};

// A peer as given: NAME=HOST:PORT. Throws std::invalid_argument naming what is wrong.
struct PeerAddress {
  std::string name;
  std::string host;
  std::uint16_t port = 0;
};
PeerAddress parse_peer(const std::string& text);

// Runs until the stop time (a coordinator with --until) or SIGINT/SIGTERM; returns the exit code
// (0 ok, 1 the run failed, 2 bad input).
int serve(const ServeOptions& options);

}  // namespace icars::app
