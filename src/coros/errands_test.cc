// The errand market on real loopback UDP sockets in one process: robots (ErrandBidder) at known
// places of the paper house bid the planned cost of appending a stop to their routes, and one
// auctioneer (ErrandMarket) sells stops one at a time. An errand goes to the nearest robot and
// the news carries every bid; a patrol is split by append costs and each route holds its awards
// in order; a released errand leaves its robot's route, also one released while it waited; a
// failed robot's errands, and those of a robot that stops announcing itself, are auctioned again
// without it; an errand nobody can bid for is given up after max_rounds while the queue goes on;
// a robot whose map does not know a stop does not bid; forged awards, auctions and revokes are
// ignored.
#include "icars/coros/errands.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "child_process.h"
#include "fleet.h"
#include "icars/coros/authentication.h"

namespace icars::coros {
namespace {

using namespace std::chrono_literals;
using planet_test::wait_until;

const std::string kMap = std::string(ICARS_HOUSES_DIR) + "/paper_house.xml";
const std::string kOtherMap = std::string(ICARS_HOUSES_DIR) + "/office_floor.xml";

ErrandBidder::Locator standing_at(sim::Point p) {
  return [p] { return std::optional<sim::Point>(p); };
}

std::string describe(const ErrandNews& n) {
  std::string bids;
  for (const auto& [robot, cost] : n.bids) bids += fmt::format(" {}={:.3f}", robot, cost);
  return fmt::format("{} round {} {} {} at {:.3f}, bids:{}, excluded: {}, reason: '{}'", n.errand,
                     n.round, to_string(n.kind), n.robot, n.cost, bids, fmt::join(n.excluded, ","),
                     n.reason);
}

// The messages of `all` about `errand`.
template <class M>
std::vector<M> about(const std::vector<M>& all, const std::string& errand) {
  std::vector<M> out;
  for (const auto& m : all) {
    if (m.task_id == errand) out.push_back(m);
  }
  return out;
}

class ErrandMarketTest : public ::testing::Test, protected coros_test::FleetBase {
 protected:
  ErrandMarketTest() : FleetBase(kMap) {}
  void TearDown() override { stop_all(); }

  struct Bidder {
    Agent* agent = nullptr;
    std::shared_ptr<ErrandBidder> op;
  };
  // A robot agent bidding from where `where` says, on `map` (the fleet's by default).
  void add_bidder(const std::string& id, ErrandBidder::Locator where,
                  std::shared_ptr<const MapPlanner> map = nullptr) {
    Agent& a = add_agent(config(id, "robot"));
    auto op = std::make_shared<ErrandBidder>(map ? map : map_, std::move(where));
    a.add_operator(op);
    bidders_[id] = {&a, op};
  }
  void add_market(ErrandMarket::Options options = {}) {
    market_agent_ = &add_agent(config("market", "user"));
    market_ = std::make_shared<ErrandMarket>(options);
    market_agent_->add_operator(market_);
  }
  bool start_fleet() {
    start_all();
    return wait_until([&] { return converged(); }, 20s);
  }

  Place place(const std::string& name) const {
    const auto p = map_->locate(name);
    return Place{name, p.x, p.y};
  }
  double cost(sim::Point from, const std::string& stop) const {
    return map_->path_cost(from, map_->locate(stop)).value();
  }
  // A listener keeping the news on the market's thread (news() reads it there), then telling
  // `also`.
  ErrandMarket::Listener record(ErrandMarket::Listener also = {}) {
    return [this, also](const ErrandNews& n) {
      news_.push_back(n);
      if (also) also(n);
    };
  }
  void offer(const std::string& errand, const std::string& stop) {
    const Place p = place(stop);
    market_agent_->call([&] { market_->offer(errand, p, record()); });
  }
  std::vector<ErrandNews> news(const std::string& errand) {
    return market_agent_->call([&] {
      std::vector<ErrandNews> out;
      for (const auto& n : news_) {
        if (n.errand == errand) out.push_back(n);
      }
      return out;
    });
  }
  std::vector<ErrandNews> all_news() {
    return market_agent_->call([&] { return news_; });
  }
  // Until `errand` has had `count` pieces of news of `kind`.
  bool wait_for(const std::string& errand, ErrandNews::Kind kind, std::size_t count = 1) {
    return wait_until(
        [&] {
          const auto n = news(errand);
          return static_cast<std::size_t>(std::count_if(
                     n.begin(), n.end(), [&](const ErrandNews& x) { return x.kind == kind; })) >=
                 count;
        },
        20s);
  }
  std::string history(const std::string& errand) {
    std::string out;
    for (const auto& n : news(errand)) out += "\n  " + describe(n);
    return out;
  }
  std::vector<std::string> route(const std::string& robot) {
    const Bidder& b = bidders_.at(robot);
    return b.agent->call([&] { return b.op->route(); });
  }
  // The rounds of `errand` the market announced, from its errand_auction events.
  std::vector<int> auction_rounds(const std::string& errand) const {
    std::vector<int> rounds;
    for (const auto& e : log_.find("errand_auction")) {
      if (e["errand"] == errand) rounds.push_back(e["round"].get<int>());
    }
    return rounds;
  }

  std::map<std::string, Bidder> bidders_;
  Agent* market_agent_ = nullptr;
  std::shared_ptr<ErrandMarket> market_;
  std::vector<ErrandNews> news_;  // on the market's thread
};

TEST_F(ErrandMarketTest, TheNearestRobotWinsAndTheNewsHasEveryBid) {
  const std::map<std::string, sim::Point> at = {
      {"robot1", {1.0, 1.0}}, {"robot2", {5.0, 2.4}}, {"robot3", {8.5, 1.5}}};
  for (const auto& [id, p] : at) add_bidder(id, standing_at(p));
  add_market();
  ASSERT_TRUE(start_fleet());
  std::map<std::string, double> expected;
  for (const auto& [id, p] : at) expected[id] = cost(p, "kitchen_corner");
  ASSERT_LT(expected["robot2"], expected["robot1"]);
  ASSERT_LT(expected["robot2"], expected["robot3"]);

  offer("e1", "kitchen_corner");
  ASSERT_TRUE(wait_for("e1", ErrandNews::Kind::awarded)) << history("e1");
  const auto n = news("e1");
  ASSERT_EQ(n.size(), 1u) << history("e1");
  EXPECT_EQ(n[0].kind, ErrandNews::Kind::awarded);
  EXPECT_EQ(n[0].round, 1);
  EXPECT_EQ(n[0].robot, "robot2");
  EXPECT_NEAR(n[0].cost, expected["robot2"], 1e-6);
  ASSERT_EQ(n[0].bids.size(), 3u) << describe(n[0]);
  for (const auto& [id, c] : expected) EXPECT_NEAR(n[0].bids.at(id), c, 1e-6) << id;
  EXPECT_TRUE(n[0].excluded.empty()) << describe(n[0]);
  EXPECT_TRUE(n[0].reason.empty());
  EXPECT_GT(n[0].auction_ms, 0);
  EXPECT_EQ(route("robot2"), std::vector<std::string>{"e1"});
  EXPECT_TRUE(route("robot1").empty());
  EXPECT_TRUE(route("robot3").empty());
  // The trace says the same.
  const auto awarded = log_.find("errand_awarded");
  ASSERT_EQ(awarded.size(), 1u);
  EXPECT_EQ(awarded[0]["robot"], "robot2");
  EXPECT_EQ(awarded[0]["bids"].size(), 3u);
  const auto taken = log_.find("errand_taken");
  ASSERT_EQ(taken.size(), 1u);
  EXPECT_EQ(taken[0]["agent"], "robot2");
}

// A market that has just started has heard no robot yet: its first auction does not close on
// the first bid (every robot it knows of, none, has bid) but waits for the window.
TEST_F(ErrandMarketTest, AMarketThatJustStartedWaitsForTheRobotsItHasNotHeardYet) {
  const std::map<std::string, sim::Point> at = {{"robot1", {1.0, 1.0}}, {"robot2", {5.0, 2.4}}};
  for (const auto& [id, p] : at) add_bidder(id, standing_at(p));
  add_market();
  market_agent_->start();
  offer("e1", "kitchen_corner");  // before any robot announced itself
  for (const auto& [id, b] : bidders_) b.agent->start();
  ASSERT_TRUE(wait_for("e1", ErrandNews::Kind::awarded)) << history("e1");
  const auto n = news("e1");
  ASSERT_EQ(n.size(), 1u) << history("e1");
  EXPECT_EQ(n[0].bids.size(), 2u) << describe(n[0]);
  EXPECT_EQ(n[0].robot, "robot2") << describe(n[0]);  // the nearer one, not the first to answer
}

TEST_F(ErrandMarketTest, APatrolIsSplitByAppendCostsAndEachRouteHoldsItsAwardsInOrder) {
  std::vector<std::string> patrol;
  for (const auto* w : map_->house().waypoints_tagged("patrol")) patrol.push_back(w->name);
  ASSERT_EQ(patrol.size(), 6u);
  // At the two ends of the house: the living room's left wall and the bedroom's right one.
  const std::map<std::string, sim::Point> start = {{"robot1", {1.0, 1.0}}, {"robot2", {9.0, 2.5}}};
  for (const auto& [id, p] : start) add_bidder(id, standing_at(p));
  add_market();
  ASSERT_TRUE(start_fleet());
  std::vector<std::string> errands;
  for (std::size_t i = 0; i < patrol.size(); ++i) errands.push_back(fmt::format("patrol{}", i + 1));
  market_agent_->call([&] {
    for (std::size_t i = 0; i < patrol.size(); ++i)
      market_->offer(errands[i], place(patrol[i]), record());
  });
  ASSERT_TRUE(wait_until([&] { return all_news().size() >= patrol.size(); }, 60s));
  const auto n = all_news();
  ASSERT_EQ(n.size(), patrol.size());

  // Replay the auctions: each bid is the planned cost from the end of the robot's route so far.
  auto end = start;
  std::map<std::string, std::vector<std::string>> awarded;
  bool append_differs_from_start = false;  // the check below can tell an append cost apart
  for (std::size_t i = 0; i < n.size(); ++i) {
    ASSERT_EQ(n[i].kind, ErrandNews::Kind::awarded) << describe(n[i]);
    ASSERT_EQ(n[i].errand, errands[i]) << "awarded in the order offered";
    EXPECT_EQ(n[i].round, 1);
    ASSERT_EQ(n[i].bids.size(), 2u) << describe(n[i]);
    for (const auto& [id, from] : end) {
      EXPECT_NEAR(n[i].bids.at(id), cost(from, patrol[i]), 1e-6) << id << " for " << patrol[i];
      if (!awarded[id].empty() &&
          std::abs(cost(from, patrol[i]) - cost(start.at(id), patrol[i])) > 0.1) {
        append_differs_from_start = true;
      }
    }
    const auto best =
        std::min_element(n[i].bids.begin(), n[i].bids.end(),
                         [](const auto& a, const auto& b) { return a.second < b.second; });
    EXPECT_EQ(n[i].robot, best->first) << describe(n[i]);
    EXPECT_DOUBLE_EQ(n[i].cost, best->second);
    end[n[i].robot] = map_->locate(patrol[i]);
    awarded[n[i].robot].push_back(n[i].errand);
  }
  EXPECT_TRUE(append_differs_from_start);
  for (const auto& [id, p] : start) {
    EXPECT_GE(awarded[id].size(), 1u) << id << " got none of the patrol";
    EXPECT_EQ(route(id), awarded[id]) << id;
  }
}

TEST_F(ErrandMarketTest, AReleasedErrandIsRevokedFromItsRobotsRoute) {
  add_bidder("robot1", standing_at({1.0, 1.0}));
  add_bidder("robot2", standing_at({8.5, 1.5}));
  add_market();
  ASSERT_TRUE(start_fleet());
  offer("e1", "entrance");
  ASSERT_TRUE(wait_for("e1", ErrandNews::Kind::awarded)) << history("e1");
  ASSERT_EQ(news("e1")[0].robot, "robot1");
  ASSERT_EQ(route("robot1"), std::vector<std::string>{"e1"});

  market_agent_->call([&] { market_->release("e1"); });
  ASSERT_TRUE(wait_until([&] { return route("robot1").empty(); }, 20s));
  const auto dropped = log_.find("errand_dropped");
  ASSERT_EQ(dropped.size(), 1u);
  EXPECT_EQ(dropped[0]["agent"], "robot1");
  EXPECT_EQ(dropped[0]["errand"], "e1");
  EXPECT_EQ(dropped[0]["reason"], "released by market");
  EXPECT_EQ(market_agent_->call([&] { return market_->open_errands(); }), 0u);
  EXPECT_EQ(news("e1").size(), 1u)
      << "a released errand's listener hears nothing more" << history("e1");

  // Its id may be offered again, and is sold again.
  offer("e1", "bedroom_window");
  ASSERT_TRUE(wait_for("e1", ErrandNews::Kind::awarded, 2)) << history("e1");
  EXPECT_EQ(news("e1").back().robot, "robot2");
  EXPECT_EQ(route("robot2"), std::vector<std::string>{"e1"});
  EXPECT_TRUE(route("robot1").empty());
}

TEST_F(ErrandMarketTest, AnErrandReleasedWhileQueuedAndOfferedAgainIsAuctionedOnce) {
  add_bidder("robot1", standing_at({1.0, 1.0}));
  add_bidder("robot2", standing_at({8.5, 1.5}));
  add_market();
  ASSERT_TRUE(start_fleet());
  market_agent_->call([&] {
    market_->offer("e1", place("entrance"), record());        // auctioned at once
    market_->offer("e2", place("bedroom_window"), record());  // waits for e1's award
    market_->release("e2");
    market_->offer("e2", place("bedroom_window"), record());
  });
  ASSERT_TRUE(wait_for("e2", ErrandNews::Kind::awarded)) << history("e2");
  // A later errand is auctioned after whatever the queue still held.
  offer("e3", "sofa_side");
  ASSERT_TRUE(wait_for("e3", ErrandNews::Kind::awarded)) << history("e3");
  EXPECT_EQ(auction_rounds("e2"), std::vector<int>{1});
  const auto n = news("e2");
  ASSERT_EQ(n.size(), 1u) << history("e2");
  EXPECT_EQ(n[0].robot, "robot2");
  EXPECT_EQ(n[0].round, 1);
  EXPECT_EQ(route("robot2").front(), "e2");
}

TEST_F(ErrandMarketTest, AFailedRobotsErrandsAreAuctionedAgainWithoutIt) {
  add_bidder("robot1", standing_at({1.0, 1.0}));
  add_bidder("robot2", standing_at({8.5, 1.5}));
  add_bidder("robot3", standing_at({9.0, 2.5}));
  add_market();
  ASSERT_TRUE(start_fleet());
  offer("e1", "entrance");
  offer("e2", "living_room_center");
  ASSERT_TRUE(wait_for("e2", ErrandNews::Kind::awarded)) << history("e2");
  ASSERT_EQ(news("e1").at(0).robot, "robot1") << history("e1");
  ASSERT_EQ(news("e2").at(0).robot, "robot1") << history("e2");
  ASSERT_EQ(route("robot1"), (std::vector<std::string>{"e1", "e2"}));

  market_agent_->call([&] { market_->robot_failed("robot1", "its wheels are lost"); });
  for (const std::string errand : {"e1", "e2"}) {
    ASSERT_TRUE(wait_for(errand, ErrandNews::Kind::awarded, 2)) << history(errand);
    const auto n = news(errand);
    ASSERT_EQ(n.size(), 3u) << history(errand);
    EXPECT_EQ(n[1].kind, ErrandNews::Kind::reauctioned) << history(errand);
    EXPECT_EQ(n[1].robot, "robot1");
    EXPECT_EQ(n[1].round, 1);
    EXPECT_EQ(n[1].reason, "its wheels are lost");
    EXPECT_EQ(n[2].kind, ErrandNews::Kind::awarded);
    EXPECT_EQ(n[2].round, 2);
    EXPECT_NE(n[2].robot, "robot1");
    EXPECT_EQ(n[2].excluded, std::vector<std::string>{"robot1"});
    EXPECT_EQ(n[2].bids.size(), 2u) << describe(n[2]);
    EXPECT_FALSE(n[2].bids.contains("robot1")) << describe(n[2]);
    const auto r = route(n[2].robot);
    EXPECT_NE(std::find(r.begin(), r.end(), errand), r.end())
        << n[2].robot << " does not hold " << errand;
  }
  // REVOKE, and the new rounds, took them off the failed robot's route.
  ASSERT_TRUE(wait_until([&] { return route("robot1").empty(); }, 20s));

  // It gets nothing until it is available again.
  offer("e3", "sofa_side");
  ASSERT_TRUE(wait_for("e3", ErrandNews::Kind::awarded)) << history("e3");
  EXPECT_EQ(news("e3")[0].excluded, std::vector<std::string>{"robot1"});
  EXPECT_FALSE(news("e3")[0].bids.contains("robot1"));
  market_agent_->call([&] { market_->set_available("robot1"); });
  offer("e4", "sofa_side");
  ASSERT_TRUE(wait_for("e4", ErrandNews::Kind::awarded)) << history("e4");
  EXPECT_TRUE(news("e4")[0].excluded.empty());
  EXPECT_EQ(news("e4")[0].bids.size(), 3u) << describe(news("e4")[0]);
}

TEST_F(ErrandMarketTest, ARobotThatStopsAnnouncingItselfHasItsErrandsAuctionedAgain) {
  add_bidder("robot1", standing_at({1.0, 1.0}));
  add_bidder("robot2", standing_at({8.5, 1.5}));
  add_market();
  ASSERT_TRUE(start_fleet());
  offer("e1", "entrance");
  ASSERT_TRUE(wait_for("e1", ErrandNews::Kind::awarded)) << history("e1");
  ASSERT_EQ(news("e1")[0].robot, "robot1");

  bidders_.at("robot1").agent->stop();  // no more HELLOs: the market forgets it after the expiry
  ASSERT_TRUE(wait_for("e1", ErrandNews::Kind::awarded, 2)) << history("e1");
  const auto n = news("e1");
  ASSERT_EQ(n.size(), 3u) << history("e1");
  EXPECT_EQ(n[1].kind, ErrandNews::Kind::reauctioned);
  EXPECT_EQ(n[1].robot, "robot1");
  EXPECT_EQ(n[1].reason, "robot1 stopped announcing itself");
  EXPECT_EQ(n[2].robot, "robot2");
  EXPECT_EQ(n[2].round, 2);
  EXPECT_EQ(n[2].excluded, std::vector<std::string>{"robot1"});
  EXPECT_EQ(route("robot2"), std::vector<std::string>{"e1"});
  // Gone from the table, it is not kept as unavailable: if it comes back it may bid again.
  EXPECT_TRUE(market_agent_->call([&] { return market_->unavailable().empty(); }));
  bool left = false;
  for (const auto& e : log_.find("neighbor_left")) {
    left = left || (e["agent"] == "market" && e["neighbor"] == "robot1");
  }
  EXPECT_TRUE(left);
}

TEST_F(ErrandMarketTest, WithNoBidAnErrandIsUnassignedAfterMaxRoundsAndTheQueueGoesOn) {
  bid_window_ = 500ms;  // every round without bids lasts the whole window, and so does the pause
  // Nobody can work until the first errand is given up.
  auto can_work = std::make_shared<std::atomic<bool>>(false);
  for (const auto& [id, p] :
       std::map<std::string, sim::Point>{{"robot1", {1.0, 1.0}}, {"robot2", {8.5, 1.5}}}) {
    add_bidder(id, [can_work, p]() -> std::optional<sim::Point> {
      if (!can_work->load()) return std::nullopt;
      return p;
    });
  }
  ErrandMarket::Options options;
  options.max_rounds = 2;
  add_market(options);
  ASSERT_TRUE(start_fleet());
  market_agent_->call([&] {
    market_->offer("e1", place("entrance"), record([can_work](const ErrandNews& n) {
                     if (n.kind == ErrandNews::Kind::unassigned) can_work->store(true);
                   }));
    market_->offer("e2", place("entrance"), record());
  });
  ASSERT_TRUE(wait_for("e2", ErrandNews::Kind::awarded)) << history("e1") << history("e2");
  const auto n = news("e1");
  ASSERT_EQ(n.size(), 1u) << history("e1");
  EXPECT_EQ(n[0].kind, ErrandNews::Kind::unassigned);
  EXPECT_EQ(n[0].round, 2);
  EXPECT_EQ(n[0].reason, "no robot bid in 2 rounds");
  EXPECT_TRUE(n[0].robot.empty());
  EXPECT_TRUE(n[0].bids.empty());
  EXPECT_EQ(auction_rounds("e1"), (std::vector<int>{1, 2}));
  ASSERT_EQ(log_.count("errand_unassigned"), 1u);
  // The queued errand was auctioned after it, and sold in its first round.
  const auto n2 = news("e2");
  ASSERT_EQ(n2.size(), 1u) << history("e2");
  EXPECT_EQ(n2[0].round, 1);
  EXPECT_FALSE(n2[0].bids.empty());
  EXPECT_EQ(route(n2[0].robot), std::vector<std::string>{"e2"});
  EXPECT_EQ(market_agent_->call([&] { return market_->open_errands(); }), 1u);  // e2, held
}

// A bid that comes in after a round closed without bids, while the next round waits its pause,
// starts that round at once and counts in it (here the bidder then refuses the award, which
// tells the round and its bids).
TEST_F(ErrandMarketTest, ABidDuringThePauseAfterARoundWithoutBidsOpensTheNextRoundAndCountsThere) {
  bid_window_ = 5s;  // the pause too: the bid below is sent well within it
  add_bidder("robot1", []() -> std::optional<sim::Point> { return std::nullopt; });  // cannot work
  add_market();
  ASSERT_TRUE(start_fleet());
  offer("e1", "entrance");
  ASSERT_TRUE(wait_until([&] { return log_.count("errand_no_bids") >= 1; }, 20s)) << log_.dump();
  EXPECT_EQ(log_.find("errand_no_bids")[0]["round"], 1);
  EXPECT_EQ(auction_rounds("e1"), std::vector<int>{1});  // round 2 waits its pause

  Agent& robot = *bidders_.at("robot1").agent;
  const auto to = market_agent_->call([&] { return market_agent_->transport().local_endpoint(); });
  robot.call([&] { robot.send(to, BidMessage{"e1", 1, "robot1", 12.5}); });
  ASSERT_TRUE(wait_for("e1", ErrandNews::Kind::reauctioned)) << history("e1");
  const auto n = news("e1");
  EXPECT_EQ(n[0].round, 2) << describe(n[0]);
  EXPECT_EQ(n[0].robot, "robot1");
  EXPECT_EQ(n[0].bids, (std::map<std::string, double>{{"robot1", 12.5}})) << describe(n[0]);
  EXPECT_NE(n[0].reason.find("refused the award: the robot cannot work now"), std::string::npos) << n[0].reason;
  const auto rounds = auction_rounds("e1");
  ASSERT_GE(rounds.size(), 2u);
  EXPECT_EQ(rounds[1], 2);
}

// A robot that cannot bid says so (DECLINE): the round closes once every robot has bid or
// declined, long before its window ends.
TEST_F(ErrandMarketTest, ARobotWhoseMapDoesNotKnowTheStopDeclines) {
  bid_window_ = 20s;
  add_bidder("robot1", standing_at({1.0, 1.0}));
  // Nearer, but on the office floor's map, which has no kitchen corner.
  add_bidder("robot2", standing_at({5.0, 2.4}), MapPlanner::load(kOtherMap, 0.25));
  add_bidder("robot3", []() -> std::optional<sim::Point> { return std::nullopt; });  // cannot work
  add_market();
  ASSERT_TRUE(start_fleet());
  const auto& b2 = bidders_.at("robot2");
  EXPECT_EQ(b2.agent->call([&] { return b2.op->cost_of(place("kitchen_corner")); }), std::nullopt);
  // A market younger than the neighbour expiry waits for robots it may not have heard yet (the
  // test above): the errand is offered once it is older, which the market's start bounds.
  const auto market_started_by = std::chrono::steady_clock::now();
  const auto expiry = market_agent_->call([&] { return market_agent_->config().neighbor_expiry; });
  std::this_thread::sleep_until(market_started_by + expiry);
  offer("e1", "kitchen_corner");
  ASSERT_TRUE(wait_for("e1", ErrandNews::Kind::awarded)) << history("e1");
  const auto n = news("e1");
  ASSERT_EQ(n.size(), 1u) << history("e1");
  EXPECT_EQ(n[0].robot, "robot1");
  EXPECT_EQ(n[0].bids.size(), 1u) << describe(n[0]);
  EXPECT_FALSE(n[0].bids.contains("robot2")) << describe(n[0]);
  EXPECT_LT(n[0].auction_ms, 10000.0);  // half the window, on a loaded machine
  EXPECT_TRUE(route("robot2").empty());
  std::map<std::string, std::string> declined;
  for (const auto& e : log_.find("errand_declined")) declined[e["robot"]] = e["reason"];
  EXPECT_EQ(declined, (std::map<std::string, std::string>{{"robot2", "the stop is not on this robot's map"},
                                                          {"robot3", "the robot cannot work now"}}))
      << log_.dump();
}

TEST_F(ErrandMarketTest, ForgedAwardsAuctionsAndRevokesAreIgnored) {
  const sim::Point at{1.0, 1.0};
  add_bidder("robot1", standing_at(at));
  start_all();
  Agent& robot = *bidders_.at("robot1").agent;
  // A key holder that misbehaves: its datagrams are signed, so only the bidder's checks stop them.
  coros_test::KeyHolder forger(key_, robot.call([&] { return robot.transport().local_endpoint(); }));
  auto send = [&](const std::string& sender, const auto& message, bool truncate = false) {
    forger.send(sender, message, truncate);
  };
  auto bids_for = [&](const std::string& errand) { return about(forger.replies<BidMessage>(), errand); };
  auto acks_for = [&](const std::string& errand) { return about(forger.replies<AwardAckMessage>(), errand); };
  // Replies come in the order the robot handled the datagrams, so once the reply to a genuine
  // one arrives, the forgery sent before it has been handled.
  auto wait_for_reply = [&](auto has) {
    return wait_until([&] {
      forger.receive();
      return has();
    });
  };
  const Place kitchen = place("kitchen_corner");

  // A malformed one is counted, not handled.
  send("forger", ErrandAuctionMessage{"cut", 1, "forger", kitchen, 100, {}}, true);
  ASSERT_TRUE(wait_until([&] { return robot.call([&] { return robot.bad_datagrams(); }) >= 1; }));

  // An auction on behalf of another auctioneer gets no bid; the forger's own one does.
  send("forger", ErrandAuctionMessage{"forged_auction", 1, "market", kitchen, 100, {}});
  send("forger", ErrandAuctionMessage{"auction", 1, "forger", kitchen, 100, {}});
  ASSERT_TRUE(wait_for_reply([&] { return !bids_for("auction").empty(); }));
  EXPECT_NEAR(bids_for("auction")[0].cost, cost(at, "kitchen_corner"), 1e-6);
  EXPECT_TRUE(bids_for("forged_auction").empty());

  // An award for another robot is not taken; one for this robot is.
  send("forger", ErrandAwardMessage{"forged_award", 1, "robot2", kitchen, 1.0});
  send("forger", ErrandAwardMessage{"award", 1, "robot1", kitchen, 1.0});
  ASSERT_TRUE(wait_for_reply([&] { return !acks_for("award").empty(); }));
  EXPECT_TRUE(acks_for("award")[0].accepted) << acks_for("award")[0].reason;
  EXPECT_TRUE(acks_for("forged_award").empty());
  EXPECT_EQ(route("robot1"), std::vector<std::string>{"award"});

  // Only the auctioneer that gave the errand may take it back.
  send("intruder", RevokeMessage{"award", 1, "robot1"});
  send("forger", ErrandAuctionMessage{"probe", 1, "forger", kitchen, 100, {}});
  ASSERT_TRUE(wait_for_reply([&] { return !bids_for("probe").empty(); }));
  EXPECT_EQ(route("robot1"), std::vector<std::string>{"award"});
  send("forger", RevokeMessage{"award", 1, "robot1"});
  ASSERT_TRUE(wait_until([&] { return route("robot1").empty(); }));

  // Ignored, not bad: only the cut datagram was.
  EXPECT_EQ(robot.call([&] { return robot.bad_datagrams(); }), 1u);
}

}  // namespace
}  // namespace icars::coros
