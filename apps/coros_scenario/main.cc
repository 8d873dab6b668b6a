// icars-coros: the COROS courier delivery scenario (COROS 5.2) with one process per agent.
//
//   icars-coros run --map houses/office_floor.xml --robots N
//       --deliveries "office_101>office_112,office_104>office_109"
//       [--random-deliveries K --seed S] [--speedup 20]
//       [--kill robot2@to_dropoff | --kill robot2@3s] [--faults "drop=0.2,duplicate=0.2,delay=0.3"]
//       [--svg out.svg] [--json summary.json] [--agent-bin PATH] [--keep-dir DIR] [--timeout 120]
//       [--delivery-interval MS] [--bid-window MS] [--neighbor-expiry MS] [--broadcast-port P]
//       [--http 127.0.0.1:8080 [--http-linger S]] [--verbose]
//
// Starts N robot agents and a user agent (icars-agent), lets the user auction the deliveries,
// optionally kills a robot, and prints per delivery the bids of each round, the winners,
// re-auctions and outcome, per robot the distance driven, the discovery convergence time and
// the auction completion times. Exit code: 0 when every delivery succeeded, 1 when not, 2 for
// a usage error.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <exception>
#include <string>

#include "scenario.h"

namespace s = icars::coros_scenario;

int main(int argc, char** argv) {
  CLI::App app{
      "COROS courier delivery scenario: robots and a user as separate icars-agent "
      "processes"};
  app.require_subcommand(1);

  s::ScenarioOptions options;
  std::string deliveries, kill, map, svg, json, agent_bin, keep_dir;
  auto* run = app.add_subcommand("run", "run the courier delivery scenario and print a summary");
  run->add_option("--map", map, "office map, a house file (docs/house.md)")->required();
  run->add_option("--robots", options.robots, "number of robots (robot1..robotN)")
      ->capture_default_str();
  run->add_option("--deliveries", deliveries,
                  "deliveries to auction, PICKUP>DROPOFF separated by commas");
  run->add_option("--random-deliveries", options.random_deliveries,
                  "also this many random deliveries between offices (waypoints tagged office)");
  run->add_option("--seed", options.seed, "seed of the random deliveries and of the faults")
      ->capture_default_str();
  run->add_option("--speedup", options.speedup, "simulated seconds per wall second")
      ->capture_default_str();
  run->add_option("--kill", kill,
                  "kill a robot: ROBOT@STAGE at its own task stage (e.g. robot2@to_dropoff), or "
                  "ROBOT@DELAY after the first award (e.g. robot2@3s, robot2@500ms)");
  run->add_option("--faults", options.faults,
                  "network faults for every agent, e.g. drop=0.2,duplicate=0.2,delay=0.3");
  run->add_option("--svg", svg, "draw the map, the robots' tracks and the deliveries here");
  run->add_option("--json", json, "write the summary as JSON here");
  run->add_option(
      "--agent-bin", agent_bin,
      "the icars-agent program (default: beside icars-coros, or the one built with it)");
  run->add_option("--keep-dir", keep_dir,
                  "write the agents' configurations, logs and tracks here and keep them "
                  "(default: a temporary directory, kept only when the run fails)");
  run->add_option("--timeout", options.timeout_s, "give up after this many wall seconds")
      ->capture_default_str();
  run->add_option("--delivery-interval", options.delivery_interval_ms,
                  "milliseconds between the user's auctions (0: all at once)")
      ->capture_default_str();
  run->add_option("--bid-window", options.bid_window_ms,
                  "milliseconds the user waits for bids; 0: 400, plus 25 per robot beyond 16, since every "
                  "agent plans its bids on this host's cores")
      ->capture_default_str();
  run->add_option("--neighbor-expiry", options.neighbor_expiry_ms,
                  "milliseconds without a HELLO after which an agent counts as gone")
      ->capture_default_str();
  run->add_option("--broadcast-port", options.broadcast_port,
                  "the agents' shared UDP broadcast port (default: a free one)");
  run->add_option("--http", options.http,
                  "serve the dashboard's fleet page on HOST:PORT (loopback unless TLS; port 0: any)");
  run->add_option("--http-tls-cert", options.http_tls_cert, "the dashboard's TLS certificate (PEM)");
  run->add_option("--http-tls-key", options.http_tls_key, "the dashboard's TLS key (PEM)");
  run->add_option("--http-linger", options.http_linger_s,
                  "with --http, keep serving this many seconds after the summary (negative: until "
                  "SIGINT or SIGTERM)")
      ->capture_default_str();
  run->add_flag("--verbose,-v", options.verbose, "print every agent event as it comes");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);  // prints help, or the error with a hint
    return code == 0 ? 0 : 2;
  }

  try {
    options.map = map;
    options.svg = svg;
    options.json = json;
    options.agent_bin = agent_bin;
    options.keep_dir = keep_dir;
    if (!deliveries.empty()) options.deliveries = s::parse_deliveries(deliveries);
    if (!kill.empty()) options.kill = s::parse_kill(kill);
    return s::run_scenario(options);
  } catch (const s::UsageError& e) {
    std::fprintf(stderr, "icars-coros: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "icars-coros: failed: %s\n", e.what());
    return 1;
  }
}
