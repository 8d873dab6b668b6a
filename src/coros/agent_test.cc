// Agents on real loopback UDP sockets in one process: discovery converges and forgets agents
// that stop, garbage datagrams are counted and never stop an agent, the courier auction goes
// to the lowest planned cost with a deterministic tie-break and closes once every known robot
// has bid (at the end of its window when one stays silent), a robot that dies mid-delivery
// has its delivery auctioned again and completed, and with datagrams dropped, duplicated and
// delayed every delivery is still done once.
#include "icars/coros/agent.h"

#include <gtest/gtest.h>

#include <asio/ip/udp.hpp>
#include <map>
#include <mutex>

#include "child_process.h"
#include "fleet.h"
#include "icars/coros/courier.h"
#include "icars/coros/discovery.h"
#include "icars/coros/monitor.h"

namespace icars::coros {
namespace {

using namespace std::chrono_literals;
using planet_test::wait_until;

const std::string kMap = std::string(ICARS_HOUSES_DIR) + "/paper_house.xml";

class Fleet : public ::testing::Test, protected coros_test::FleetBase {
 protected:
  Fleet() : FleetBase(kMap) {}
  std::shared_ptr<CourierUserOperator> add_user() {
    Agent& a = add_agent(config("user", "user"));
    auto op = std::make_shared<CourierUserOperator>(map_);
    a.add_operator(op);
    user_ = &a;
    return op;
  }
  double planned_cost(const std::string& robot, const std::string& pickup,
                      const std::string& dropoff) {
    const auto p = robots_.at(robot)->pose().position();
    return *map_->path_cost(p, map_->locate(pickup)) +
           *map_->path_cost(map_->locate(pickup), map_->locate(dropoff));
  }
  void TearDown() override { stop_all(); }

  Agent* user_ = nullptr;
};

TEST_F(Fleet, DiscoveryConvergesAndForgetsStoppedAgents) {
  for (int i = 1; i <= 6; ++i) add_agent(config("agent" + std::to_string(i), "robot"));
  auto& monitor = add_agent(config("monitor", "monitor"));
  start_all();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto table =
      monitor.call([&] { return render_neighbors(monitor.neighbors(), Clock::now()); });
  EXPECT_NE(table.find("agent6"), std::string::npos) << table;
  const auto hello = monitor.call([&] { return *monitor.neighbors().find("agent3"); });
  EXPECT_EQ(hello.role, "robot");
  EXPECT_EQ(hello.ip, "127.0.0.1");
  EXPECT_EQ(hello.status, "idle");
  EXPECT_GT(hello.timestamp, 1.6e9);

  agents_[2]->stop();  // agent3
  ASSERT_TRUE(wait_until(
      [&] { return monitor.call([&] { return monitor.neighbors().find("agent3") == nullptr; }); },
      20s));
  const auto left = log_.find("neighbor_left");
  ASSERT_FALSE(left.empty());
  EXPECT_EQ(left[0]["neighbor"], "agent3");
}

TEST_F(Fleet, GarbageDatagramsAreCountedAndIgnored) {
  auto& a = add_agent(config("agent1", "robot"));
  auto& b = add_agent(config("agent2", "robot"));
  start_all();
  asio::io_context io;
  asio::ip::udp::socket s(io, asio::ip::udp::endpoint(asio::ip::udp::v4(), 0));
  s.set_option(asio::socket_base::broadcast(true));
  const auto to = a.call([&] { return a.transport().local_endpoint(); });
  // The last two are well-formed datagrams that handlers reject. They are signed with the
  // fleet's key (by a misbehaving key holder), or authentication would drop them first.
  DatagramSigner key_holder(key_);
  const std::vector<std::pair<std::vector<std::byte>, bool>> junk = {
      {{}, false},
      {{std::byte{'G'}, std::byte{'E'}, std::byte{'T'}}, false},
      {encode_header(MessageCode::hello, "intruder"), false},  // no body
      {[] {                                                    // a HELLO code with a BID body
         auto d = encode_datagram("intruder", BidMessage{"t", 1, "intruder", 1});
         const auto h = encode_header(MessageCode::hello, "intruder");
         std::copy(h.begin(), h.end(), d.begin());
         return d;
       }(),
       true},
      {encode_datagram("intruder",  // a HELLO naming someone else
                       HelloMessage{"agent2", "127.0.0.1", 1, "robot", "idle", 1, 0, 0, 0}),
       true},
  };
  for (const auto& [bytes, sign] : junk) {
    for (const auto& dest :
         {to, asio::ip::udp::endpoint(asio::ip::make_address("127.255.255.255"), port_)}) {
      auto copy = bytes;
      if (sign) key_holder.sign(copy);  // each copy its own counter: no replay
      s.send_to(asio::buffer(copy), dest);
    }
  }
  ASSERT_TRUE(wait_until(
      [&] { return a.call([&] { return a.bad_datagrams(); }) >= 2 * junk.size(); }, 20s));
  // Still working: the two agents discover each other.
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  EXPECT_EQ(b.call([&] { return b.neighbors().find("intruder"); }), nullptr);
  // Reported per source, at most once a second, each event with its count.
  ASSERT_TRUE(wait_until(
      [&] {
        std::uint64_t reported = 0;
        for (const auto& e : log_.find("bad_datagram")) {
          if (e.value("agent", "") == "agent1") reported += e.value("count", std::uint64_t{0});
        }
        return reported >= 2 * junk.size();
      },
      20s));
}

TEST_F(Fleet, LowestPlannedCostWinsAndTiesGoToTheSmallerId) {
  // robot3 is nearest to the entrance in a straight line, but through the bedroom wall; the
  // planner sends it round by the door, so robot2 (in the living room) is cheaper.
  add_robot("robot1", 1.0, 1.5);
  add_robot("robot2", 3.0, 2.0);
  add_robot("robot3", 7.0, 2.0);
  add_robot("robot4", 3.0, 2.0);  // same spot as robot2: a tie
  auto user = add_user();
  Agent& monitor = add_agent(config("monitor", "monitor"));
  monitor.add_operator(std::make_shared<TaskObserverOperator>());
  start_all();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const double c2 = planned_cost("robot2", "living_room_center", "bedroom_window");
  const double c3 = planned_cost("robot3", "living_room_center", "bedroom_window");
  const double c1 = planned_cost("robot1", "living_room_center", "bedroom_window");
  ASSERT_LT(c2, c1);
  ASSERT_LT(c2, c3);
  const auto task =
      user_->call([&] { return user->request("living_room_center", "bedroom_window"); });
  ASSERT_TRUE(wait_until([&] { return user_->call([&] { return user->all_finished(); }); }, 60s));
  const auto record = user_->call([&] { return user->deliveries().at(task); });
  EXPECT_TRUE(record.success) << record.detail;
  EXPECT_EQ(record.robot, "robot2");  // robot4 bid the same: the smaller id wins
  ASSERT_EQ(record.bids.size(), 4u);
  EXPECT_NEAR(record.bids.at("robot2"), c2, 1e-6);
  EXPECT_NEAR(record.bids.at("robot3"), c3, 1e-6);
  EXPECT_DOUBLE_EQ(record.bids.at("robot2"), record.bids.at("robot4"));
  EXPECT_EQ(record.round, 1);
  // The robot really drove there: it stands at the dropoff.
  const auto end = robots_.at("robot2")->pose().position();
  EXPECT_LT(sim::distance(end, map_->locate("bedroom_window")), 0.3);
  EXPECT_NEAR(record.distance, c2, 0.5);
  // The monitor followed the task from the robot's broadcasts.
  ASSERT_TRUE(wait_until(
      [&] {
        return monitor.call([&] {
          const auto* t = monitor.tasks().find(task);
          return t && t->stage == TaskStage::delivered;
        });
      },
      20s));
  const auto table = monitor.call([&] { return render_tasks(monitor.tasks()); });
  EXPECT_NE(table.find("robot2"), std::string::npos) << table;
  EXPECT_NE(table.find("delivered"), std::string::npos) << table;
}

// Seconds from the user's auction of `task` (its first round) to the award, from the events'
// own wall-clock stamps.
double auction_to_award(const coros_test::EventLog& log, const std::string& task) {
  const auto time_of = [&](const std::string& kind) {
    for (const auto& e : log.find(kind)) {
      if (e["task"] == task && e["round"] == 1) return e["time"].get<double>();
    }
    ADD_FAILURE() << "no " << kind << " event for " << task << ":\n" << log.dump();
    return 0.0;
  };
  return time_of("awarded") - time_of("auction");
}

// The auction does not wait for the rest of its window once every robot the user knows of has
// bid; a monitor in the user's neighbour table is no bidder.
TEST_F(Fleet, AnAuctionClosesAsSoonAsEveryKnownRobotHasBid) {
  bid_window_ = 10s;
  add_robot("robot1", 1.0, 1.5);
  add_robot("robot2", 3.0, 2.0);
  add_robot("robot3", 7.0, 2.0);
  auto user = add_user();
  add_agent(config("monitor", "monitor"));
  start_all();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto task =
      user_->call([&] { return user->request("living_room_center", "bedroom_window"); });
  ASSERT_TRUE(wait_until([&] { return log_.count("awarded") >= 1; }, 20s));
  EXPECT_LT(auction_to_award(log_, task), 5.0);  // half the window, on a loaded machine
  EXPECT_EQ(log_.find("awarded")[0]["bids"].size(), 3u);
  EXPECT_EQ(log_.find("awarded")[0]["robot"], "robot2");
}

// A robot that never bids (here an agent announcing itself as a robot without the courier
// operator) holds the auction open until its window ends; then the bids in decide it.
TEST_F(Fleet, AnAuctionWithASilentRobotClosesWhenItsWindowEnds) {
  bid_window_ = 1500ms;
  add_robot("robot1", 1.0, 1.5);
  add_robot("robot2", 3.0, 2.0);
  add_agent(config("robot3", "robot"));
  auto user = add_user();
  start_all();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto task =
      user_->call([&] { return user->request("living_room_center", "bedroom_window"); });
  ASSERT_TRUE(wait_until([&] { return log_.count("awarded") >= 1; }, 20s));
  EXPECT_GE(auction_to_award(log_, task), 1.45);
  const auto awarded = log_.find("awarded")[0];
  EXPECT_EQ(awarded["bids"].size(), 2u) << awarded.dump();
  EXPECT_EQ(awarded["robot"], "robot2");
  EXPECT_EQ(awarded["round"], 1);
}

// A bid that comes in after a round closed without bids, while the next round waits its pause
// (a slow planner's), starts that round at once and counts in it: the round the "reauction"
// event announced is the one that is awarded.
TEST_F(Fleet, ABidDuringThePauseAfterARoundWithoutBidsOpensTheNextRoundAndCountsThere) {
  bid_window_ = 5s;  // the pause too: the bid below is sent well within it
  Agent& late = add_agent(config("robot3", "robot"));  // a robot agent whose bid is sent by hand
  auto user = add_user();
  start_all();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto task =
      user_->call([&] { return user->request("living_room_center", "bedroom_window"); });
  ASSERT_TRUE(wait_until([&] { return log_.count("reauction") >= 1; }, 20s)) << log_.dump();
  const auto reauction = log_.find("reauction")[0];
  EXPECT_EQ(reauction["round"], 2);
  EXPECT_EQ(reauction["reason"], "no bids");
  EXPECT_EQ(log_.count("auction"), 1u) << log_.dump();  // round 2 waits its pause

  const auto to = user_->call([&] { return user_->transport().local_endpoint(); });
  late.call([&] { late.send(to, BidMessage{task, 1, "robot3", 12.5}); });
  ASSERT_TRUE(wait_until([&] { return log_.count("awarded") >= 1; }, 20s)) << log_.dump();
  const auto awarded = log_.find("awarded")[0];
  EXPECT_EQ(awarded["round"], 2) << awarded.dump();
  EXPECT_EQ(awarded["robot"], "robot3");
  EXPECT_EQ(awarded["bids"].size(), 1u);
  const auto auctions = log_.find("auction");
  ASSERT_GE(auctions.size(), 2u);
  EXPECT_EQ(auctions[1]["round"], 2);
  const auto bids = log_.find("bid_received");
  ASSERT_EQ(bids.size(), 1u) << log_.dump();
  EXPECT_EQ(bids[0]["round"], 2);
  EXPECT_EQ(bids[0]["bid_round"], 1);
}

// A robot that cannot bid (here: no path to the pickup) says so with DECLINE to the auctioneer,
// naming the round and why, for every copy of the AUCTION.
TEST_F(Fleet, ARobotThatCannotReachAPlaceDeclinesTheAuction) {
  Agent& robot = add_robot("robot1", 1.0, 1.5);
  start_all();
  coros_test::KeyHolder user(key_, robot.call([&] { return robot.transport().local_endpoint(); }));
  const Place nowhere{"nowhere", -50, -50};
  const auto there = map_->locate("bedroom_window");
  const Place dropoff{"bedroom_window", there.x, there.y};
  for (std::size_t copy = 1; copy <= 2; ++copy) {
    user.send("user", AuctionMessage{"t1", 3, "user", nowhere, dropoff, 1000, {}});
    ASSERT_TRUE(wait_until([&] { return user.receive(), user.replies<DeclineMessage>().size() >= copy; }, 20s));
  }
  EXPECT_TRUE(user.replies<BidMessage>().empty());
  const auto declines = user.replies<DeclineMessage>();
  for (const auto& d : declines) {
    EXPECT_EQ(d.task_id, "t1");
    EXPECT_EQ(d.round, 3);
    EXPECT_EQ(d.robot, "robot1");
    EXPECT_EQ(d.reason, "no path to nowhere or bedroom_window");
  }
  EXPECT_EQ(log_.count("no_bid"), 2u) << log_.dump();
}

// A DECLINE counts as an answer: the round closes once every known robot has bid or declined,
// not when the window ends; the user's "declined" event tells who and why. A DECLINE of another
// round, or from another agent than the robot it names, is not taken.
TEST_F(Fleet, AnAuctionClosesAsSoonAsEveryKnownRobotHasBidOrDeclined) {
  bid_window_ = 20s;
  add_robot("robot1", 1.0, 1.5);
  add_robot("robot2", 3.0, 2.0);
  Agent& robot3 = add_agent(config("robot3", "robot"));  // its DECLINE is sent by hand
  Agent& other = add_agent(config("robot4", "monitor"));
  auto user = add_user();
  start_all();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto task =
      user_->call([&] { return user->request("living_room_center", "bedroom_window"); });
  ASSERT_TRUE(wait_until([&] { return log_.count("bid_received") >= 2; }, 20s)) << log_.dump();
  const auto to = user_->call([&] { return user_->transport().local_endpoint(); });
  other.call([&] { other.send(to, DeclineMessage{task, 1, "robot3", "forged"}); });
  robot3.call([&] { robot3.send(to, DeclineMessage{task, 2, "robot3", "a round not yet open"}); });
  robot3.call([&] { robot3.send(to, DeclineMessage{task, 1, "robot3", "its battery is flat"}); });
  ASSERT_TRUE(wait_until([&] { return log_.count("awarded") >= 1; }, 15s)) << log_.dump();
  EXPECT_LT(auction_to_award(log_, task), 10.0);  // half the window, on a loaded machine
  const auto awarded = log_.find("awarded")[0];
  EXPECT_EQ(awarded["round"], 1);
  EXPECT_EQ(awarded["bids"].size(), 2u) << awarded.dump();
  EXPECT_EQ(awarded["robot"], "robot2");
  const auto declined = log_.find("declined");
  ASSERT_EQ(declined.size(), 1u) << log_.dump();
  EXPECT_EQ(declined[0]["robot"], "robot3");
  EXPECT_EQ(declined[0]["round"], 1);
  EXPECT_EQ(declined[0]["reason"], "its battery is flat");
}

// A silent robot that leaves the user's neighbour table (its HELLOs stop) is no longer waited
// for: the auction closes then, not at the end of its window.
TEST_F(Fleet, AnAuctionStopsWaitingForASilentRobotThatLeaves) {
  bid_window_ = 20s;
  add_robot("robot1", 1.0, 1.5);
  add_robot("robot2", 3.0, 2.0);
  Agent& silent = add_agent(config("robot3", "robot"));
  auto user = add_user();
  start_all();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto task =
      user_->call([&] { return user->request("living_room_center", "bedroom_window"); });
  ASSERT_TRUE(wait_until([&] { return log_.count("bid_received") >= 2; }, 20s));
  silent.stop();
  ASSERT_TRUE(wait_until([&] { return log_.count("awarded") >= 1; }, 15s));
  EXPECT_LT(auction_to_award(log_, task), 15.0);  // the expiry is 1.5 s
  const auto awarded = log_.find("awarded")[0];
  EXPECT_EQ(awarded["bids"].size(), 2u) << awarded.dump();
  EXPECT_EQ(awarded["robot"], "robot2");
}

TEST_F(Fleet, DeadWinnerIsDetectedAndTheTaskAuctionedAgain) {
  add_robot("robot1", 1.0, 1.0, 20);  // slow enough to be killed on the way
  add_robot("robot2", 9.0, 1.0, 20);
  add_robot("robot3", 8.0, 4.0, 20);
  auto user = add_user();
  start_all();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 20s));
  const auto task = user_->call([&] { return user->request("entrance", "bedroom_window"); });
  ASSERT_TRUE(wait_until([&] { return log_.count("assigned") >= 1; }, 20s));
  const std::string first = log_.find("assigned")[0]["robot"];
  EXPECT_EQ(first, "robot1");
  ASSERT_TRUE(wait_until(
      [&] {
        for (const auto& e : log_.find("task_stage")) {
          if (e["agent"] == first && e["stage"] == "to_dropoff") return true;
        }
        return false;
      },
      30s));
  agents_[0]->stop();  // robot1 dies with the courier on board
  robots_.at("robot1")->stop();
  ASSERT_TRUE(wait_until([&] { return user_->call([&] { return user->all_finished(); }); }, 60s));
  const auto record = user_->call([&] { return user->deliveries().at(task); });
  EXPECT_TRUE(record.success) << record.detail;
  EXPECT_EQ(record.round, 2);
  EXPECT_NE(record.robot, "robot1");
  EXPECT_EQ(record.excluded, std::vector<std::string>{"robot1"});
  const auto re = log_.find("reauction");
  ASSERT_EQ(re.size(), 1u);
  EXPECT_NE(re[0]["reason"].get<std::string>().find("robot1 stopped answering"), std::string::npos);
}

TEST_F(Fleet, LossyNetworkStillAssignsAndDeliversEachTaskOnce) {
  faults_ = FaultInjection::parse("drop=0.25,duplicate=0.25,delay=0.3,max_delay_ms=60");
  add_robot("robot1", 1.0, 1.0);
  add_robot("robot2", 5.0, 4.0);
  add_robot("robot3", 7.0, 2.0);
  add_robot("robot4", 9.0, 1.0);
  auto user = add_user();
  start_all();
  ASSERT_TRUE(wait_until([&] { return converged(); }, 30s));
  const std::vector<std::pair<std::string, std::string>> jobs = {{"entrance", "bedroom_window"},
                                                                 {"bed_side", "kitchen_corner"},
                                                                 {"dock", "desk"},
                                                                 {"sofa_side", "door"},
                                                                 {"bedroom_center", "entrance"},
                                                                 {"kitchen_corner", "bed_side"}};
  user_->call([&] {
    for (const auto& [a, b] : jobs) user->request(a, b);
    return 0;
  });
  const bool finished =
      wait_until([&] { return user_->call([&] { return user->all_finished(); }); }, 90s);
  const auto records = user_->call([&] { return user->deliveries(); });
  for (const auto& [id, r] : records) {
    std::string history;
    for (const auto& h : r.history) history += "\n  " + h;
    if (!r.finished) ADD_FAILURE() << id << " round " << r.round << " robot " << r.robot << history;
  }
  if (!finished) std::cerr << log_.dump();
  ASSERT_TRUE(finished);
  ASSERT_EQ(records.size(), jobs.size());
  std::map<std::string, int> delivered;  // task -> robots that delivered it
  for (const auto& e : log_.find("task_stage")) {
    if (e["stage"] == "delivered") ++delivered[e["task"]];
  }
  for (const auto& [id, r] : records) {
    EXPECT_TRUE(r.success) << id << ": " << r.detail;
    EXPECT_EQ(delivered[id], 1) << id << " delivered " << delivered[id] << " times";
  }
  EXPECT_EQ(log_.count("delivery_finished"), jobs.size());
  // The hook really was at work.
  std::uint64_t dropped = 0, duplicated = 0, delayed = 0;
  for (auto& a : agents_) {
    const auto s = a->call([&] { return a->transport().stats(); });
    dropped += s.dropped_by_hook;
    duplicated += s.duplicated_by_hook;
    delayed += s.delayed_by_hook;
  }
  EXPECT_GT(dropped, 10u);
  EXPECT_GT(duplicated, 10u);
  EXPECT_GT(delayed, 10u);
  // Duplicates are identical signed bytes: receivers drop the second copy as a replay, while
  // delayed (reordered) datagrams are still accepted within the replay window.
  std::uint64_t replayed = 0, forged = 0;
  for (auto& a : agents_) {
    const auto s = a->stats();
    replayed += s.rejected_replayed;
    forged += s.rejected_unsigned + s.rejected_bad_tag;
  }
  EXPECT_GT(replayed, 0u);
  EXPECT_EQ(forged, 0u);
}

}  // namespace
}  // namespace icars::coros
