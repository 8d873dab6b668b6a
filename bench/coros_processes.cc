// COROS auctions with one process per robot, as icars-coros runs them: N icars-agent robot
// processes and a user process on loopback, started by the scenario's own code (run_agents,
// apps/coros_scenario), the user auctioning K random deliveries between offices at once.
//
//   coros_processes [--robots 50] [--auctions 3] [--runs 5] [--map FILE] [--bid-window-ms 0]
//                   [--speedup 20] [--seed 1] [--agent-bin PATH] [--json FILE]
//
// Each run is `icars-coros run --map MAP --robots N --random-deliveries K --seed S+r` (run r
// from 0, so every run auctions other offices and the whole is repeatable), in a fresh working
// directory: the robots start with no distance field computed. Per auction (a delivery's first
// round, and any round after it until one is awarded):
//   announce -> award      the user's auction event to its awarded event: announcement, N bids
//                          planned, the close (as soon as every robot it knows of has bid, at
//                          the bid window at the latest);
//   auction -> assigned    to the winner's AWARD_ACK: what icars-coros reports as "auction to
//                          assignment".
// Both from the agents' own event stamps. Prints every auction, then the median and maximum
// over all runs' auctions (the machine is noisy; quote medians); --json writes them as
// {"rows":[{"layer":"coros","workload":...,"agents":N,"value":median,"unit":"ms","min":...,
// "max":...,"runs":R,"samples":R*K}, ...]}. Exit status 1 when an auction was never awarded.
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <vector>

#include "bench_util.h"
#include "scenario.h"
#include "scenario_report.h"

namespace {

namespace s = icars::coros_scenario;

struct Auction {
  std::string task;
  double award_ms = 0, assigned_ms = 0;
  std::size_t bids = 0;
  int rounds = 1;
};

// The auctions of one run, from its report; throws when one was never awarded or assigned.
std::vector<Auction> auctions_of(const s::ScenarioReport& report, int run) {
  std::vector<Auction> out;
  for (const auto& d : report.deliveries()) {
    if (d.rounds.empty() || !d.rounds.front().auction_at) {
      throw std::runtime_error(fmt::format("run {}: {}>{} was never auctioned", run + 1,
                                           d.delivery.pickup, d.delivery.dropoff));
    }
    const double start = *d.rounds.front().auction_at;
    Auction a;
    a.task = d.task;
    const s::RoundReport* awarded = nullptr;
    for (const auto& r : d.rounds) {
      if (r.awarded_at && r.assigned_at) {
        awarded = &r;
        break;
      }
    }
    if (!awarded) {
      throw std::runtime_error(fmt::format("run {}: {} was never awarded and assigned in {} rounds",
                                           run + 1, d.task, d.rounds.size()));
    }
    a.award_ms = (*awarded->awarded_at - start) * 1000;
    a.assigned_ms = (*awarded->assigned_at - start) * 1000;
    a.bids = awarded->bids.size();
    a.rounds = awarded->round;
    out.push_back(a);
  }
  return out;
}

using icars::bench::Stats;
using icars::bench::stats;

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"COROS auctions with one icars-agent process per robot (icars-coros run)"};
  s::ScenarioOptions options;
  options.map = std::string(ICARS_HOUSES_DIR) + "/office_floor.xml";
  options.robots = 50;
  options.random_deliveries = 3;
  int runs = 5;
  std::string map, agent_bin, json_file;
  app.add_option("--robots", options.robots, "robot processes")
      ->check(CLI::Range(1, 500))
      ->capture_default_str();
  app.add_option("--auctions", options.random_deliveries,
                 "random deliveries between offices, all auctioned at once")
      ->check(CLI::Range(1, 100))
      ->capture_default_str();
  app.add_option("--runs", runs, "repetitions")->check(CLI::Range(1, 100))->capture_default_str();
  app.add_option("--map", map, "the map, a house file with waypoints tagged office")
      ->default_str(options.map.string());
  app.add_option("--bid-window-ms", options.bid_window_ms,
                 "the user's bid window, an upper bound (0: icars-coros's, 400 ms plus 25 ms per "
                 "robot beyond 16)")
      ->check(CLI::Range(0, 600000));
  app.add_option("--speedup", options.speedup, "simulated seconds per wall second")
      ->check(CLI::Range(0.1, 10000.0))
      ->capture_default_str();
  app.add_option("--seed", options.seed, "seed of the first run's deliveries")
      ->capture_default_str();
  app.add_option("--agent-bin", agent_bin,
                 "the icars-agent program (default: the one built with it)");
  app.add_option("--json", json_file, "also write the rows to FILE as JSON");
  CLI11_PARSE(app, argc, argv);
  if (!map.empty()) options.map = map;
  if (!agent_bin.empty()) options.agent_bin = agent_bin;
  options.quiet = true;
  const std::uint64_t first_seed = options.seed;
  try {
    const auto window = s::bid_window(options);
    fmt::print(
        "{} robot processes and a user on {}, {} deliveries auctioned at once, bid window {} ms, "
        "{} runs\n",
        options.robots, options.map.filename().string(), options.random_deliveries, window.count(),
        runs);
    fmt::print("{:>4} {:>8} {:>17} {:>19} {:>5} {:>7}\n", "run", "auction", "announce->award ms",
               "auction->assigned ms", "bids", "rounds");
    std::vector<double> award, assigned;
    std::size_t short_auctions = 0, failed_runs = 0;
    for (int r = 0; r < runs; ++r) {
      options.seed = first_seed + static_cast<std::uint64_t>(r);
      const s::ScenarioReport report = s::run_agents(options);
      if (!report.succeeded()) ++failed_runs;
      for (const auto& a : auctions_of(report, r)) {
        fmt::print("{:>4} {:>8} {:>17.1f} {:>19.1f} {:>5} {:>7}\n", r + 1, a.task, a.award_ms,
                   a.assigned_ms, a.bids, a.rounds);
        award.push_back(a.award_ms);
        assigned.push_back(a.assigned_ms);
        if (a.bids < static_cast<std::size_t>(options.robots) || a.rounds > 1) ++short_auctions;
      }
      std::fflush(stdout);
    }
    const Stats aw = stats(award), as = stats(assigned);
    fmt::print(
        "announce -> award:     median {:.1f} ms, max {:.1f} ms (min {:.1f}) over {} auctions\n",
        aw.median, aw.max, aw.min, award.size());
    fmt::print("auction -> assigned:   median {:.1f} ms, max {:.1f} ms (min {:.1f})\n", as.median,
               as.max, as.min);
    if (short_auctions > 0) {
      fmt::print("{} of {} auctions were decided on fewer bids than robots or in a later round\n",
                 short_auctions, award.size());
    }
    if (failed_runs > 0) {
      fmt::print("{} of {} runs did not deliver everything (the auctions above still count)\n",
                 failed_runs, runs);
    }
    if (!json_file.empty()) {
      nlohmann::ordered_json rows = nlohmann::ordered_json::array();
      const auto add_row = [&](const char* workload, const Stats& st, std::size_t samples) {
        rows.push_back({{"layer", "coros"},
                        {"workload", workload},
                        {"agents", options.robots},
                        {"value", st.median},
                        {"unit", "ms"},
                        {"min", st.min},
                        {"max", st.max},
                        {"runs", runs},
                        {"samples", samples},
                        {"concurrent_auctions", options.random_deliveries},
                        {"bid_window_ms", window.count()}});
      };
      add_row("auction completion, robot processes", aw, award.size());
      add_row("auction to assignment, robot processes", as, assigned.size());
      std::ofstream out(json_file);
      out << nlohmann::ordered_json{{"rows", rows}}.dump(2) << '\n';
      if (!out) throw std::runtime_error("cannot write " + json_file);
    }
  } catch (const s::UsageError& e) {
    fmt::print(stderr, "coros_processes: {}\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    fmt::print(stderr, "coros_processes: {}\n", e.what());
    return 1;
  }
  return 0;
}
