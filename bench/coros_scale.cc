// COROS at scale: discovery convergence and auction completion time against the number of
// agents, with every agent on its own real UDP sockets on loopback (one process, one thread per
// agent and per simulated robot).
//
//   coros_scale [--agents 5,20,50] [--runs 5] [--hello-ms 200] [--map FILE]
//
// For each fleet size N (N robots and one user) and each run:
//   discovery  time from starting all N+1 agents until every agent has the N others in its
//              neighbour table (the first HELLO goes out at start, then one every --hello-ms);
//   join       time from starting one more robot in the running fleet until it knows all
//              N+1 agents and all of them know it (bounded by one HELLO period);
//   auction    time from the user's request until the winner's AWARD_ACK (announcement, N
//              planned bids, early close once every known robot has bid, award, ack), for
//              three deliveries one after another.
// Prints the median, minimum and maximum over the runs (the machine is noisy; quote medians).
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <asio/ip/udp.hpp>
#include <condition_variable>
#include <mutex>
#include <numeric>
#include <thread>

#include "icars/coros/agent.h"
#include "icars/coros/courier.h"
#include "icars/coros/discovery.h"

namespace {

using namespace icars::coros;
using namespace std::chrono_literals;
using Ms = std::chrono::duration<double, std::milli>;

std::uint16_t free_udp_port() {
  asio::io_context io;
  asio::ip::udp::socket s(io, asio::ip::udp::endpoint(asio::ip::udp::v4(), 0));
  return s.local_endpoint().port();
}

template <class F>
bool wait_for(F condition, std::chrono::seconds bound) {
  const auto end = std::chrono::steady_clock::now() + bound;
  while (std::chrono::steady_clock::now() < end) {
    if (condition()) return true;
    std::this_thread::sleep_for(1ms);
  }
  return condition();
}

struct RunResult {
  double discovery_ms = 0;
  double join_ms = 0;
  std::vector<double> auction_ms;
};

RunResult run_once(int robots, std::chrono::milliseconds hello,
                   const std::shared_ptr<const MapPlanner>& map) {
  const std::uint16_t port = free_udp_port();
  auto config = [&](const std::string& id, const std::string& role) {
    AgentConfiguration c;
    c.id = id;
    c.role = role;
    c.transport.broadcast_port = port;
    c.hello_period = hello;
    c.neighbor_expiry = hello * 10;
    c.bid_window = 2000ms;  // an upper bound: auctions close as soon as every robot has bid
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
  std::vector<std::unique_ptr<Agent>> agents;
  std::mutex mutex;
  std::condition_variable cv;
  std::map<std::string, std::chrono::steady_clock::time_point> assigned;
  for (int i = 0; i < robots; ++i) {
    const std::string id = fmt::format("robot{:03}", i + 1);
    agents.push_back(std::make_unique<Agent>(config(id, "robot")));
    SimRobotOptions o;
    o.id = id;
    const auto p = spots[static_cast<std::size_t>(i * 4 % static_cast<int>(spots.size()))];
    o.start = {p.x, p.y, 0};
    o.speedup = 100;
    agents.back()->add_operator(std::make_shared<DiscoveryOperator>());
    agents.back()->add_operator(
        std::make_shared<CourierRobotOperator>(std::make_shared<SimRobot>(map->house(), o), map));
  }
  agents.push_back(std::make_unique<Agent>(config("user", "user")));
  Agent& user_agent = *agents.back();
  auto user = std::make_shared<CourierUserOperator>(map);
  user_agent.add_operator(std::make_shared<DiscoveryOperator>());
  user_agent.add_operator(user);
  user_agent.set_event_sink([&](const nlohmann::json& e) {
    if (e.value("event", "") != "assigned") return;
    std::lock_guard lock(mutex);
    assigned[e["task"].get<std::string>()] = std::chrono::steady_clock::now();
    cv.notify_all();
  });

  const auto start = std::chrono::steady_clock::now();
  for (auto& a : agents) a->start();
  const std::size_t others = agents.size() - 1;
  RunResult result;
  if (!wait_for(
          [&] {
            return std::all_of(agents.begin(), agents.end(), [&](auto& a) {
              return a->call([&] { return a->neighbors().size(); }) == others;
            });
          },
          60s)) {
    throw std::runtime_error(fmt::format("{} agents: discovery did not converge in 60 s", robots));
  }
  result.discovery_ms = Ms(std::chrono::steady_clock::now() - start).count();

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
  }
  // A robot joining the running fleet: until it knows everyone and everyone knows it.
  agents.push_back(std::make_unique<Agent>(config("robot_late", "robot")));
  agents.back()->add_operator(std::make_shared<DiscoveryOperator>());
  const auto join_start = std::chrono::steady_clock::now();
  agents.back()->start();
  if (!wait_for(
          [&] {
            return std::all_of(agents.begin(), agents.end(), [&](auto& a) {
              return a->call([&] { return a->neighbors().size(); }) == agents.size() - 1;
            });
          },
          60s)) {
    throw std::runtime_error(fmt::format("{} agents: a late robot was not known in 60 s", robots));
  }
  result.join_ms = Ms(std::chrono::steady_clock::now() - join_start).count();
  for (auto& a : agents) a->stop();
  return result;
}

struct Stats {
  double median, min, max;
};
Stats stats(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  const double median = n % 2 ? v[n / 2] : (v[n / 2 - 1] + v[n / 2]) / 2;
  return {median, v.front(), v.back()};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"COROS discovery convergence and auction completion against fleet size"};
  std::vector<int> sizes{5, 20, 50};
  int runs = 5;
  int hello_ms = 200;
  std::string map_file = std::string(ICARS_HOUSES_DIR) + "/office_floor.xml";
  app.add_option("--agents", sizes, "fleet sizes (robots; one user is added)")->delimiter(',');
  app.add_option("--runs", runs, "repetitions per size")->check(CLI::Range(1, 100));
  app.add_option("--hello-ms", hello_ms, "HELLO period")->check(CLI::Range(10, 10000));
  app.add_option("--map", map_file, "the map robots plan on");
  CLI11_PARSE(app, argc, argv);
  try {
    const auto map = MapPlanner::load(map_file, 0.25);
    fmt::print("map {}, HELLO every {} ms, {} runs per size; times in ms (median [min, max])\n",
               map->house().name, hello_ms, runs);
    fmt::print("{:>7} {:>28} {:>28} {:>28}\n", "robots", "discovery convergence",
               "late joiner known", "auction completion");
    for (int n : sizes) {
      std::vector<double> discovery, join, auction;
      for (int r = 0; r < runs; ++r) {
        const auto result = run_once(n, std::chrono::milliseconds(hello_ms), map);
        discovery.push_back(result.discovery_ms);
        join.push_back(result.join_ms);
        auction.insert(auction.end(), result.auction_ms.begin(), result.auction_ms.end());
      }
      const auto d = stats(discovery), j = stats(join), a = stats(auction);
      fmt::print(
          "{:>7} {:>10.1f} [{:>6.1f}, {:>6.1f}] {:>10.1f} [{:>6.1f}, {:>6.1f}] {:>10.1f} "
          "[{:>6.1f}, {:>6.1f}]\n",
          n, d.median, d.min, d.max, j.median, j.min, j.max, a.median, a.min, a.max);
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "coros_scale: {}\n", e.what());
    return 1;
  }
  return 0;
}
