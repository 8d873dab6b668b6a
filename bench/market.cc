// The errand market (errands.h: single stops sold in sequential auctions) against the courier
// market (courier.h) on fleets of the same sizes in one house, measured side by side in one run
// (a plain program printing medians).
//
//   market_bench [--robots 2,5,10] [--runs 5] [--singles 20] [--hello-ms 200]
//                [--bid-window-ms 2000] [--speedup 100] [--map FILE]
//
// Every agent lives in this process on its own real UDP sockets on loopback, on a broadcast port
// of its fleet's own and signing with a fresh fleet key. Robots stand at distinct free spots of
// the map: its waypoints first, then free cells at least 0.75 m from those. For each fleet size N
// and run, two fleets are built in turn (their order alternates between runs), each N robots and
// one auctioneer, and measured once every agent has the others in its neighbour table:
//   errand   N ErrandBidders at the spots (fixed Locators) and an ErrandMarket;
//   courier  N CourierRobotOperators driving SimRobots that start at the same spots (--speedup
//            times real time) and a CourierUserOperator. A delivery here is one stop, like an
//            errand: pickup and dropoff are the same place, so a bid plans one path of length.
// Measures (wall time, std::chrono::steady_clock; "bench" times start on this thread just before
// it calls offer()/request() on the auctioneer's thread and end when the auctioneer's listener or
// event sink sees the moment, on its thread):
//   one auction    --singles auctions one after another, each waited for, at the house's
//                  "patrol" waypoints in turn:
//                  bench    offer -> the errand's awarded news (after the winner's AWARD_ACK);
//                           request -> the courier's "awarded" event (the decision, before its
//                           ack) and -> its "assigned" event (the ack, like the errand's news);
//                  market   the auctioneer's own clock: from the round's first announcement to the
//                           ack (ErrandNews::auction_ms; DeliveryRecord assigned_at -
//                           auction_started).
//                  Every one is bid from empty routes: each errand is released once awarded,
//                  and each delivery waited for (untimed) until the robot has driven it.
//   patrol         the house's 6 patrol waypoints offered at once and sold one after another
//                  (each auction after the previous award): first offer -> last award. The
//                  courier peer: the 6 stops requested at once as deliveries, auctioned
//                  concurrently: first request -> last "assigned".
// Auctions close as soon as every known robot has bid; the bid window only bounds one that lost
// a bid, and those are counted under the table. Printed: per measure the median over --runs of
// each run's median, [min, max] of the runs' medians, and the ratio errand / courier of the
// medians.
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.h"
#include "icars/coros/agent.h"
#include "icars/coros/courier.h"
#include "icars/coros/discovery.h"
#include "icars/coros/errands.h"

namespace {

using namespace icars::coros;
using namespace std::chrono_literals;
using icars::sim::Point;
using Steady = std::chrono::steady_clock;
using Ms = std::chrono::duration<double, std::milli>;

constexpr std::chrono::seconds kBound = 30s;  // any one wait longer than this is an error

struct Settings {
  std::chrono::milliseconds hello{200};
  std::chrono::milliseconds bid_window{2000};
  int singles = 20;
  double speedup = 100;  // courier robots: simulated seconds per wall second
};

// One fleet: agents on a port and key of their own, stopped when it goes.
class Fleet {
 public:
  explicit Fleet(const Settings& s) : settings_(s), port_(free_udp_port()) {}
  ~Fleet() {
    for (auto& a : agents_) a->stop();
  }
  Fleet(const Fleet&) = delete;
  Fleet& operator=(const Fleet&) = delete;

  Agent& add(const std::string& id, const std::string& role) {
    AgentConfiguration c;
    c.id = id;
    c.role = role;
    c.transport.broadcast_port = port_;
    c.transport.key = key_;
    c.hello_period = settings_.hello;
    c.neighbor_expiry = settings_.hello * 10;
    c.bid_window = settings_.bid_window;
    c.retry_period = 50ms;
    agents_.push_back(std::make_unique<Agent>(c));
    agents_.back()->add_operator(std::make_shared<DiscoveryOperator>());
    return *agents_.back();
  }
  // Starts every agent and returns once each knows all the others (outside any timing).
  void start() {
    for (auto& a : agents_) a->start();
    const auto deadline = Steady::now() + kBound;
    for (auto& a : agents_) {
      while (a->call([&] { return a->neighbors().size(); }) != agents_.size() - 1) {
        if (Steady::now() > deadline) {
          throw std::runtime_error(fmt::format("{} agents did not discover each other in {} s",
                                               agents_.size(), kBound.count()));
        }
        std::this_thread::sleep_for(5ms);
      }
    }
  }

 private:
  Settings settings_;
  std::uint16_t port_;
  FleetKey key_ = FleetKey::generate();
  std::vector<std::unique_ptr<Agent>> agents_;
};

// Moments seen on an auctioneer's thread, waited for on the bench thread.
template <class Value>
class Moments {
 public:
  void record(const std::string& key, Value value) {
    std::lock_guard lock(mutex_);
    seen_.emplace(key, std::pair{Steady::now(), std::move(value)});
    changed_.notify_all();
  }
  std::pair<Steady::time_point, Value> wait(const std::string& key, const char* what) {
    std::unique_lock lock(mutex_);
    if (!changed_.wait_for(lock, kBound, [&] { return seen_.contains(key); })) {
      throw std::runtime_error(fmt::format("{} of {} not seen in {} s", what, key, kBound.count()));
    }
    return seen_.at(key);
  }

 private:
  std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::string, std::pair<Steady::time_point, Value>> seen_;
};

struct RunResult {
  std::vector<double> bench_ms;     // errand: offer -> awarded news; courier: request -> "awarded"
  std::vector<double> assigned_ms;  // courier: request -> "assigned"
  std::vector<double> market_ms;    // first announcement -> ack, on the auctioneer's clock
  double patrol_ms = 0;             // first offer/request -> last award acknowledged
  std::size_t patrol_robots = 0;    // robots the patrol's stops went to
  std::size_t short_auctions = 0;   // closed with fewer bids than robots (the window ended)
};

struct House {
  std::shared_ptr<const MapPlanner> map;
  std::vector<Point> spots;         // where robots stand
  std::vector<std::string> patrol;  // the house's patrol waypoints, in file order
  Place place(const std::string& name) const {
    const auto p = map->locate(name);
    return Place{name, p.x, p.y};
  }
};

RunResult run_errands(int robots, const House& house, const Settings& settings) {
  // What the listener writes to outlives the fleet's agents.
  Moments<ErrandNews> awards;
  std::mutex failures_mutex;
  std::vector<std::string> failures;
  const ErrandMarket::Listener listener = [&](const ErrandNews& n) {
    if (n.kind == ErrandNews::Kind::awarded) {
      awards.record(n.errand, n);
    } else if (n.kind == ErrandNews::Kind::unassigned) {
      std::lock_guard lock(failures_mutex);
      failures.push_back(n.errand + ": " + n.reason);
    }
  };
  Fleet fleet(settings);
  for (int i = 0; i < robots; ++i) {
    Agent& a = fleet.add(fmt::format("robot{:02}", i + 1), "robot");
    a.add_operator(std::make_shared<ErrandBidder>(
        house.map,
        [p = house.spots[static_cast<std::size_t>(i)]] { return std::optional<Point>(p); }));
  }
  Agent& auctioneer = fleet.add("market", "user");
  auto market = std::make_shared<ErrandMarket>();
  auctioneer.add_operator(market);
  fleet.start();

  RunResult r;
  const auto n = static_cast<std::size_t>(robots);
  for (int i = 0; i < settings.singles; ++i) {
    const std::string id = fmt::format("single{}", i + 1);
    const Place stop = house.place(house.patrol[static_cast<std::size_t>(i) % house.patrol.size()]);
    const auto t0 = Steady::now();
    auctioneer.call([&] { market->offer(id, stop, listener); });
    const auto [t1, news] = awards.wait(id, "the award");
    r.bench_ms.push_back(Ms(t1 - t0).count());
    r.market_ms.push_back(news.auction_ms);
    if (news.bids.size() < n) ++r.short_auctions;
    auctioneer.call([&] { market->release(id); });
  }
  std::vector<std::string> ids;
  for (std::size_t k = 0; k < house.patrol.size(); ++k)
    ids.push_back(fmt::format("patrol{}", k + 1));
  const auto t0 = Steady::now();
  auctioneer.call([&] {
    for (std::size_t k = 0; k < ids.size(); ++k)
      market->offer(ids[k], house.place(house.patrol[k]), listener);
  });
  std::set<std::string> winners;
  Steady::time_point last = t0;
  for (const auto& id : ids) {
    const auto [t, news] = awards.wait(id, "the award");
    last = std::max(last, t);
    winners.insert(news.robot);
    if (news.bids.size() < n) ++r.short_auctions;
  }
  r.patrol_ms = Ms(last - t0).count();
  r.patrol_robots = winners.size();
  std::lock_guard lock(failures_mutex);
  if (!failures.empty()) throw std::runtime_error("errands unassigned: " + failures.front());
  return r;
}

RunResult run_courier(int robots, const House& house, const Settings& settings) {
  Moments<std::size_t> awarded;   // task -> bids it was decided on
  Moments<std::string> assigned;  // task -> the robot that acknowledged
  Moments<bool> finished;         // task -> whether it was delivered
  Fleet fleet(settings);
  for (int i = 0; i < robots; ++i) {
    const std::string id = fmt::format("robot{:02}", i + 1);
    Agent& a = fleet.add(id, "robot");
    SimRobotOptions o;
    o.id = id;
    const Point p = house.spots[static_cast<std::size_t>(i)];
    o.start = {p.x, p.y, 0};
    o.speedup = settings.speedup;
    a.add_operator(std::make_shared<CourierRobotOperator>(
        std::make_shared<SimRobot>(house.map->house(), o), house.map));
  }
  Agent& auctioneer = fleet.add("user", "user");
  auto user = std::make_shared<CourierUserOperator>(house.map);
  auctioneer.add_operator(user);
  auctioneer.set_event_sink([&](const nlohmann::json& e) {
    const auto event = e.value("event", "");
    if (event == "awarded") awarded.record(e.at("task").get<std::string>(), e.at("bids").size());
    if (event == "assigned")
      assigned.record(e.at("task").get<std::string>(), e.at("robot").get<std::string>());
    if (event == "delivery_finished")
      finished.record(e.at("task").get<std::string>(), e.at("success").get<bool>());
  });
  fleet.start();

  RunResult r;
  const auto n = static_cast<std::size_t>(robots);
  const auto& patrol = house.patrol;
  for (int i = 0; i < settings.singles; ++i) {
    const std::string stop = patrol[static_cast<std::size_t>(i) % patrol.size()];
    const auto t0 = Steady::now();
    const std::string task = auctioneer.call([&] { return user->request(stop, stop); });
    const auto [t1, bids] = awarded.wait(task, "the award");
    const auto t2 = assigned.wait(task, "the acknowledgement").first;
    r.bench_ms.push_back(Ms(t1 - t0).count());
    r.assigned_ms.push_back(Ms(t2 - t0).count());
    const auto record = auctioneer.call([&] { return user->deliveries().at(task); });
    r.market_ms.push_back(Ms(record.assigned_at - record.auction_started).count());
    if (bids < n) ++r.short_auctions;
    if (!finished.wait(task, "the end of the delivery").second) {
      throw std::runtime_error(fmt::format("delivery {} to {} failed", task, stop));
    }
  }
  const auto t0 = Steady::now();
  const auto tasks = auctioneer.call([&] {
    std::vector<std::string> out;
    for (const auto& stop : patrol) out.push_back(user->request(stop, stop));
    return out;
  });
  std::set<std::string> winners;
  Steady::time_point last = t0;
  for (const auto& task : tasks) {
    const auto [t, robot] = assigned.wait(task, "the acknowledgement");
    last = std::max(last, t);
    winners.insert(robot);
    if (awarded.wait(task, "the award").second < n) ++r.short_auctions;
  }
  r.patrol_ms = Ms(last - t0).count();
  r.patrol_robots = winners.size();
  return r;
}

// The map's waypoints, then free cells at least 0.75 m from every spot already taken.
std::vector<Point> robot_spots(const MapPlanner& map, std::size_t count) {
  std::vector<Point> spots;
  auto far_enough = [&](Point p) {
    return std::all_of(spots.begin(), spots.end(),
                       [&](Point q) { return icars::sim::distance(p, q) >= 0.75; });
  };
  for (const auto& w : map.house().waypoints) {
    if (spots.size() < count && map.grid().free(w.at) && far_enough(w.at)) spots.push_back(w.at);
  }
  const auto& grid = map.grid();
  for (int y = 0; y < grid.height() && spots.size() < count; y += 5) {
    for (int x = 0; x < grid.width() && spots.size() < count; x += 5) {
      const Point p = grid.center_of({x, y});
      if (grid.free(p) && far_enough(p)) spots.push_back(p);
    }
  }
  if (spots.size() < count) {
    throw std::runtime_error(fmt::format("map '{}' has room for {} robots, not {}",
                                         map.house().name, spots.size(), count));
  }
  return spots;
}

using icars::bench::Stats;
using icars::bench::stats;

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"errand market against courier market: auction times for fleets of a few robots"};
  std::vector<int> sizes{2, 5, 10};
  int runs = 5;
  int hello_ms = 200;
  int bid_window_ms = 2000;
  Settings settings;
  std::string map_file = std::string(ICARS_HOUSES_DIR) + "/paper_house.xml";
  app.add_option("--robots", sizes, "fleet sizes (robots; one auctioneer is added)")
      ->delimiter(',');
  app.add_option("--runs", runs, "repetitions per size; printed: the median of the runs' medians")
      ->check(CLI::Range(1, 100));
  app.add_option("--singles", settings.singles, "one-errand auctions per run and market")
      ->check(CLI::Range(1, 1000));
  app.add_option("--hello-ms", hello_ms, "HELLO period (neighbours expire after ten)")
      ->check(CLI::Range(10, 10000));
  app.add_option("--bid-window-ms", bid_window_ms,
                 "bid window, an upper bound: auctions close once every robot bid")
      ->check(CLI::Range(10, 600000));
  app.add_option("--speedup", settings.speedup,
                 "courier robots' simulated speed-up over wall-clock time")
      ->check(CLI::Range(1.0, 1000.0));
  app.add_option("--map", map_file, "the house robots plan on (with 6 waypoints tagged patrol)");
  CLI11_PARSE(app, argc, argv);
  settings.hello = std::chrono::milliseconds(hello_ms);
  settings.bid_window = std::chrono::milliseconds(bid_window_ms);

  try {
    House house;
    house.map = MapPlanner::load(map_file, 0.25);
    for (const auto* w : house.map->house().waypoints_tagged("patrol"))
      house.patrol.push_back(w->name);
    if (house.patrol.empty())
      throw std::runtime_error("map '" + map_file + "' has no waypoint tagged patrol");
    house.spots = robot_spots(
        *house.map, static_cast<std::size_t>(*std::max_element(sizes.begin(), sizes.end())));

    fmt::print(
        "map {}, patrol of {} stops; {} runs per size, {} single auctions per run and market; "
        "HELLO every {} "
        "ms, bid window {} ms (an upper bound)\n",
        house.map->house().name, house.patrol.size(), runs, settings.singles, hello_ms,
        bid_window_ms);
    fmt::print(
        "ms: median over runs of each run's median, [min, max] of the runs' medians; ratio: errand "
        "/ courier\n\n");
    fmt::print("{:>6}  {:<56} {:>24} {:>24} {:>7}\n", "robots", "measure", "errand", "courier",
               "ratio");
    for (const int n : sizes) {
      // Per measure: each run's median, for the errand and the courier market.
      std::vector<double> e_bench, e_market, e_patrol, c_awarded, c_assigned, c_market, c_patrol;
      std::size_t e_short = 0, c_short = 0, e_robots = 0, c_robots = 0;
      for (int r = 0; r < runs; ++r) {
        std::optional<RunResult> e, c;
        if (r % 2 == 0) {  // which market goes first alternates
          e = run_errands(n, house, settings);
          c = run_courier(n, house, settings);
        } else {
          c = run_courier(n, house, settings);
          e = run_errands(n, house, settings);
        }
        e_bench.push_back(stats(e->bench_ms).median);
        e_market.push_back(stats(e->market_ms).median);
        e_patrol.push_back(e->patrol_ms);
        c_awarded.push_back(stats(c->bench_ms).median);
        c_assigned.push_back(stats(c->assigned_ms).median);
        c_market.push_back(stats(c->market_ms).median);
        c_patrol.push_back(c->patrol_ms);
        e_short += e->short_auctions;
        c_short += c->short_auctions;
        e_robots += e->patrol_robots;
        c_robots += c->patrol_robots;
      }
      auto cell = [](const std::vector<double>& v) {
        const Stats s = stats(v);
        return fmt::format("{:.2f} [{:.2f}, {:.2f}]", s.median, s.min, s.max);
      };
      auto row = [&](const std::string& label, const std::vector<double>& errand,
                     const std::vector<double>& courier, bool first) {
        fmt::print("{:>6}  {:<56} {:>24} {:>24} {:>6.2f}x\n", first ? std::to_string(n) : "", label,
                   cell(errand), cell(courier), stats(errand).median / stats(courier).median);
      };
      row("one auction, bench: offer -> news / request -> \"awarded\"", e_bench, c_awarded, true);
      row("one auction, bench: offer -> news / request -> \"assigned\"", e_bench, c_assigned,
          false);
      row("one auction, auctioneer: first announcement -> ack", e_market, c_market, false);
      row("patrol of 6: first offer -> last ack (courier: concurrent)", e_patrol, c_patrol, false);
      fmt::print(
          "{:>6}  patrol stops went to {:.1f} robots (errand) and {:.1f} (courier) on average\n",
          "", static_cast<double>(e_robots) / runs, static_cast<double>(c_robots) / runs);
      if (e_short + c_short > 0) {
        fmt::print(
            "{:>6}  closed at the bid window with fewer bids than robots: {} errand, {} courier "
            "auctions\n",
            "", e_short, c_short);
      }
      std::fflush(stdout);
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "market_bench: {}\n", e.what());
    return 1;
  }
  return 0;
}
