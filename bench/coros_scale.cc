// COROS at scale: discovery convergence and auction completion time against the number of
// agents, with every agent on its own real UDP sockets on loopback (one process, one thread per
// agent and per simulated robot).
//
//   coros_scale [--agents 5,20,50] [--runs 5] [--hello-ms 200] [--bid-window-ms 0] [--speedup 10]
//               [--map FILE] [--json FILE]
//
// For each fleet size N (N robots and one user) and each run:
//   discovery  time from starting all N+1 agents until every agent has the N others in its
//              neighbour table (the first HELLO goes out at start, then one every --hello-ms),
//              taken when the last agent reports it (its neighbor_joined event), not polled;
//   join       time from starting one more robot in the running fleet until it knows all
//              N+1 agents and all of them know it (bounded by one HELLO period);
//   auction    time from the user's request until the winner's AWARD_ACK (announcement, N
//              planned bids, early close once every known robot has bid, award, ack), for
//              three deliveries one after another. The bid window (default max(2 s, 40 ms per
//              robot): 100 planners share this machine's cores) only bounds an auction that
//              lost a bid; one that closed on it is reported under the table.
// Each simulated robot's clock driver wakes every 100 ms of simulated time: at --speedup 100
// that is every millisecond, and 100 idle robots then take half a core from the agents being
// measured (at 10, a tenth of that). The robots' speed only decides whether an earlier
// delivery's winner is still driving (so bids with its remaining route) at a later auction.
// Prints the median, minimum and maximum over the runs (the machine is noisy; quote medians);
// --json also writes them as {"rows":[{"layer":"coros","workload":...,"agents":N,"value":median,
// "unit":"ms","min":...,"max":...,"runs":R}, ...]} (auction rows: "samples" = 3 per run).
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <asio/ip/udp.hpp>
#include <condition_variable>
#include <cstdio>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <numeric>
#include <optional>

#include "icars/coros/agent.h"
#include "icars/coros/courier.h"
#include "icars/coros/discovery.h"
#include "bench_util.h"

namespace {

using namespace icars::coros;
using namespace std::chrono_literals;
using Ms = std::chrono::duration<double, std::milli>;

using SteadyTime = std::chrono::steady_clock::time_point;

// The neighbour-table sizes the agents report (the DiscoveryOperator emits neighbor_joined and
// neighbor_left with the table's size), so convergence is seen when it happens, without
// polling every agent's thread (at 100 agents, polling them all every millisecond loads the
// very threads being measured).
class NeighborWatch {
 public:
  // For Agent::set_event_sink: observes, then passes every event on to `next`.
  Agent::EventSink sink(Agent::EventSink next = {}) {
    return [this, next = std::move(next)](const nlohmann::json& e) {
      observe(e);
      if (next) next(e);
    };
  }
  // From now on, watches for each of `count` agents to report `size` neighbours (call it
  // before starting the agents concerned, so no report is missed).
  void expect(std::size_t count, std::size_t size) {
    std::lock_guard lock(mutex_);
    target_ = size;
    agents_ = count;
    at_target_ = static_cast<std::size_t>(
        std::count_if(sizes_.begin(), sizes_.end(), [&](const auto& s) { return s.second == size; }));
    converged_.reset();
  }
  // When the last of them did, or nothing if that has not happened after `bound`.
  std::optional<SteadyTime> wait(std::chrono::seconds bound) {
    std::unique_lock lock(mutex_);
    if (!changed_.wait_for(lock, bound, [&] { return converged_.has_value(); })) return std::nullopt;
    return converged_;
  }

 private:
  void observe(const nlohmann::json& e) {
    const auto event = e.value("event", "");
    if (event != "neighbor_joined" && event != "neighbor_left") return;
    const auto now = std::chrono::steady_clock::now();
    std::lock_guard lock(mutex_);
    auto& size = sizes_[e.at("agent").get<std::string>()];
    if (size == target_) --at_target_;
    size = e.at("size").get<std::size_t>();
    if (size == target_) ++at_target_;
    if (agents_ > 0 && at_target_ == agents_ && !converged_) {
      converged_ = now;
      changed_.notify_all();
    }
  }

  std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::string, std::size_t> sizes_;  // agent id -> its neighbour-table size
  std::size_t target_ = 0, agents_ = 0, at_target_ = 0;
  std::optional<SteadyTime> converged_;
};

struct RunResult {
  double discovery_ms = 0;
  double join_ms = 0;
  std::vector<double> auction_ms;
  std::vector<std::size_t> auction_bids;  // bids the user had when it awarded
};

RunResult run_once(int robots, std::chrono::milliseconds hello, std::chrono::milliseconds bid_window,
                   double speedup, const std::shared_ptr<const MapPlanner>& map) {
  const std::uint16_t port = free_udp_port();
  const FleetKey key = FleetKey::generate();  // agents sign and check every datagram
  auto config = [&](const std::string& id, const std::string& role) {
    AgentConfiguration c;
    c.id = id;
    c.role = role;
    c.transport.broadcast_port = port;
    c.transport.key = key;
    c.hello_period = hello;
    c.neighbor_expiry = hello * 10;
    c.bid_window = bid_window;  // an upper bound: auctions close as soon as every robot has bid
    c.retry_period = 50ms;
    return c;
  };
  // Robots stand on free cells spread over the map.
  std::vector<icars::sim::Point> spots;
  const auto& grid = map->grid();
  for (int y = 0; y < grid.height() && static_cast<int>(spots.size()) < robots * 4; y += 7) {
    for (int x = 0; x < grid.width(); x += 7) {
      if (grid.free(icars::sim::Cell{x, y})) spots.push_back(grid.center_of({x, y}));
    }
  }
  // What the agents' event sinks write to outlives the agents: when a run fails, the agents
  // still running emit while the others are destroyed.
  NeighborWatch watch;
  std::mutex mutex;
  std::condition_variable cv;
  std::map<std::string, std::chrono::steady_clock::time_point> assigned;
  std::map<std::string, std::size_t> bids;  // task -> bids when awarded
  std::vector<std::unique_ptr<Agent>> agents;
  for (int i = 0; i < robots; ++i) {
    const std::string id = fmt::format("robot{:03}", i + 1);
    agents.push_back(std::make_unique<Agent>(config(id, "robot")));
    agents.back()->set_event_sink(watch.sink());
    SimRobotOptions o;
    o.id = id;
    const auto p = spots[static_cast<std::size_t>(i * 4 % static_cast<int>(spots.size()))];
    o.start = {p.x, p.y, 0};
    o.speedup = speedup;
    agents.back()->add_operator(std::make_shared<DiscoveryOperator>());
    agents.back()->add_operator(
        std::make_shared<CourierRobotOperator>(std::make_shared<SimRobot>(map->house(), o), map));
  }
  agents.push_back(std::make_unique<Agent>(config("user", "user")));
  Agent& user_agent = *agents.back();
  auto user = std::make_shared<CourierUserOperator>(map);
  user_agent.add_operator(std::make_shared<DiscoveryOperator>());
  user_agent.add_operator(user);
  user_agent.set_event_sink(watch.sink([&](const nlohmann::json& e) {
    const auto event = e.value("event", "");
    if (event == "awarded") {
      std::lock_guard lock(mutex);
      bids[e["task"].get<std::string>()] = e["bids"].size();
    }
    if (event != "assigned") return;
    std::lock_guard lock(mutex);
    assigned[e["task"].get<std::string>()] = std::chrono::steady_clock::now();
    cv.notify_all();
  }));
  // Every agent has `expected` neighbours, as their reports said (checked on the agents'
  // threads, outside the timing). Not so when a neighbour expired meanwhile: an agent thread
  // starved for a whole expiry period, which only an overloaded machine does.
  auto check_tables = [&](std::size_t expected, const char* what) {
    for (auto& a : agents) {
      const auto n = a->call([&] { return a->neighbors().size(); });
      if (n != expected) {
        fmt::print(stderr, "coros_scale: warning: {} robots, {}: {} knows {} agents, not {}\n", robots,
                   what, a->id(), n, expected);
      }
    }
  };

  const std::size_t others = agents.size() - 1;
  watch.expect(agents.size(), others);
  const auto start = std::chrono::steady_clock::now();
  for (auto& a : agents) a->start();
  RunResult result;
  const auto converged = watch.wait(60s);
  if (!converged) {
    throw std::runtime_error(fmt::format("{} agents: discovery did not converge in 60 s", robots));
  }
  result.discovery_ms = Ms(*converged - start).count();
  check_tables(others, "after discovery");

  const std::vector<std::pair<std::string, std::string>> jobs = {
      {fmt::format("{},{}", spots.front().x, spots.front().y),
       fmt::format("{},{}", spots.back().x, spots.back().y)},
      {fmt::format("{},{}", spots[spots.size() / 2].x, spots[spots.size() / 2].y),
       fmt::format("{},{}", spots.front().x, spots.front().y)},
      {fmt::format("{},{}", spots.back().x, spots.back().y),
       fmt::format("{},{}", spots[spots.size() / 3].x, spots[spots.size() / 3].y)}};
  for (const auto& [a, b] : jobs) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::string task = user_agent.call([&] { return user->request(a, b); });
    std::unique_lock lock(mutex);
    if (!cv.wait_for(lock, 30s, [&] { return assigned.contains(task); })) {
      throw std::runtime_error(
          fmt::format("{} agents: auction of {} not done in 30 s", robots, task));
    }
    result.auction_ms.push_back(Ms(assigned[task] - t0).count());
    result.auction_bids.push_back(bids[task]);
  }
  // A robot joining the running fleet: until it knows everyone and everyone knows it.
  agents.push_back(std::make_unique<Agent>(config("robot_late", "robot")));
  agents.back()->add_operator(std::make_shared<DiscoveryOperator>());
  agents.back()->set_event_sink(watch.sink());
  watch.expect(agents.size(), agents.size() - 1);
  const auto join_start = std::chrono::steady_clock::now();
  agents.back()->start();
  const auto joined = watch.wait(60s);
  if (!joined) {
    throw std::runtime_error(fmt::format("{} agents: a late robot was not known in 60 s", robots));
  }
  result.join_ms = Ms(*joined - join_start).count();
  check_tables(agents.size() - 1, "after the late robot joined");
  for (auto& a : agents) a->stop();
  return result;
}

using icars::bench::Stats;
using icars::bench::stats;

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"COROS discovery convergence and auction completion against fleet size"};
  std::vector<int> sizes{5, 20, 50};
  int runs = 5;
  int hello_ms = 200;
  std::string map_file = std::string(ICARS_HOUSES_DIR) + "/office_floor.xml";
  std::string json_file;
  int bid_window_ms = 0;
  double speedup = 10;
  app.add_option("--agents", sizes, "fleet sizes (robots; one user is added)")->delimiter(',');
  app.add_option("--runs", runs, "repetitions per size")->check(CLI::Range(1, 100));
  app.add_option("--hello-ms", hello_ms, "HELLO period")->check(CLI::Range(10, 10000));
  app.add_option("--map", map_file, "the map robots plan on");
  app.add_option("--json", json_file, "also write the rows to FILE as JSON");
  app.add_option("--bid-window-ms", bid_window_ms,
                 "auction bid window, an upper bound (0: max(2000, 40 x robots))")
      ->check(CLI::Range(0, 600000));
  app.add_option("--speedup", speedup, "simulated robots' speed-up over wall-clock time")
      ->check(CLI::Range(1.0, 1000.0));
  CLI11_PARSE(app, argc, argv);
  try {
    const auto map = MapPlanner::load(map_file, 0.25);
    fmt::print("map {}, HELLO every {} ms, {} runs per size; times in ms (median [min, max])\n",
               map->house().name, hello_ms, runs);
    fmt::print("{:>7} {:>28} {:>28} {:>28}\n", "robots", "discovery convergence",
               "late joiner known", "auction completion");
    nlohmann::ordered_json rows = nlohmann::ordered_json::array();
    auto add_row = [&](const char* workload, int agents, const Stats& s, std::size_t samples) {
      nlohmann::ordered_json row = {{"layer", "coros"}, {"workload", workload}, {"agents", agents},
                            {"value", s.median},  {"unit", "ms"},         {"min", s.min},
                            {"max", s.max},       {"runs", runs}};
      if (samples != static_cast<std::size_t>(runs)) row["samples"] = samples;
      rows.push_back(std::move(row));
    };
    for (int n : sizes) {
      std::vector<double> discovery, join, auction;
      const auto window =
          std::chrono::milliseconds(bid_window_ms > 0 ? bid_window_ms : std::max(2000, 40 * n));
      std::size_t short_auctions = 0, fewest_bids = static_cast<std::size_t>(n);
      for (int r = 0; r < runs; ++r) {
        const auto result = run_once(n, std::chrono::milliseconds(hello_ms), window, speedup, map);
        discovery.push_back(result.discovery_ms);
        join.push_back(result.join_ms);
        auction.insert(auction.end(), result.auction_ms.begin(), result.auction_ms.end());
        for (const auto b : result.auction_bids) {
          if (b < static_cast<std::size_t>(n)) ++short_auctions;
          fewest_bids = std::min(fewest_bids, b);
        }
      }
      const auto d = stats(discovery), j = stats(join), a = stats(auction);
      fmt::print(
          "{:>7} {:>10.1f} [{:>6.1f}, {:>6.1f}] {:>10.1f} [{:>6.1f}, {:>6.1f}] {:>10.1f} "
          "[{:>6.1f}, {:>6.1f}]\n",
          n, d.median, d.min, d.max, j.median, j.min, j.max, a.median, a.min, a.max);
      if (short_auctions > 0) {
        fmt::print("        {} of {} auctions closed at the {} ms bid window with fewer bids than robots "
                   "(fewest {})\n",
                   short_auctions, auction.size(), window.count(), fewest_bids);
      }
      std::fflush(stdout);
      add_row("discovery convergence", n, d, discovery.size());
      add_row("late joiner known", n, j, join.size());
      add_row("auction completion", n, a, auction.size());
    }
    if (!json_file.empty()) {
      std::ofstream out(json_file);
      out << nlohmann::ordered_json{{"rows", rows}}.dump(2) << '\n';
      if (!out) throw std::runtime_error("cannot write " + json_file);
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "coros_scale: {}\n", e.what());
    return 1;
  }
  return 0;
}
