// Errands: a market for single stops (COROS market, the home's robot allocation; docs/coros.md,
// docs/distribution.md "Robots").
//
// An errand is one place a robot is to drive to; what happens there is the auctioneer's
// business (in a home, a behavior of the mediating server drives the robot through its
// Navigation service). Work of several stops — a patrol — is sold as one errand per stop in
// sequential single-item auctions: each robot bids what appending the stop to the route it is
// already committed to would cost, so every award changes the next bids and the stops spread
// over the robots by where they are and what they already have to do.
//
// Protocol:
//   1. The ErrandMarket auctions one errand at a time: ERRAND_AUCTION(errand, round, stop,
//      window, exclude), broadcast a few times within the bid window.
//   2. Each ErrandBidder not excluded answers with a BID, planned over its map. With the
//      `append` objective, the path from the end of its route (its last committed stop, or where
//      it stands) to the stop: the awards then minimise the distance all robots drive, and a
//      robot near a run of stops takes them all. With `arrival`, the whole route from where it
//      stands through every committed stop to this one — how far it would drive before it gets
//      there: the awards then minimise the longest route, so the stops spread over the robots
//      and the work ends soonest. A robot that cannot reach the stop, or cannot work now, does
//      not bid.
//   3. The round closes when every robot the market knows of (its neighbour table, minus the
//      excluded and unavailable ones) has bid — once the market has run for neighbor_expiry, so
//      that every robot had the time to announce itself — or when the window ends. Lowest cost wins, equal
//      costs go to the smaller id. No bid: the same errand is auctioned again after a window,
//      up to max_rounds, then it is reported unassigned.
//   4. ERRAND_AWARD is resent until AWARD_ACK; the robot appends the stop to its route. Only then
//      does the next errand's auction start, so its bids see this award.
//   5. When the errand is done (or no longer wanted) the market sends REVOKE and the robot
//      drops it from its route. When the robot fails it — it left the neighbour table, or the
//      auctioneer's user says so (its devices were lost, it stalled) — the errand is auctioned
//      again with round + 1, that robot excluded, ahead of errands not yet auctioned.
// Every message carries (errand, round): a robot holding an older round drops it when it hears
// of a newer one, so an errand is held by one robot at a time.
#pragma once

#include <chrono>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "icars/coros/agent.h"
#include "icars/coros/execution.h"
#include "icars/coros/robot.h"

namespace icars::coros {

// What happened to an errand, told to whoever offered it (on the agent's thread).
struct ErrandNews {
  enum class Kind {
    awarded,      // `robot` won it at `cost` and acknowledged: it is that robot's now
    reauctioned,  // `robot` lost it (`reason`); it is being auctioned again
    unassigned,   // no robot bid in max_rounds rounds (`reason`); the errand is over
  };
  Kind kind = Kind::awarded;
  std::string errand;
  int round = 1;
  std::string robot;
  double cost = 0;
  std::map<std::string, double> bids;  // the deciding round's bids, by robot
  std::vector<std::string> excluded;   // robots that were not allowed to bid
  std::string reason;
  double auction_ms = 0;  // from the round's first announcement to the award's acknowledgement
};
std::string_view to_string(ErrandNews::Kind kind);

class ErrandMarket : public SimpleOperator {
 public:
  struct Options {
    int max_rounds = 5;
    int announcements = 3;  // copies of each ERRAND_AUCTION within the window
  };
  using Listener = std::function<void(const ErrandNews&)>;

  ErrandMarket() : ErrandMarket(Options{}) {}
  explicit ErrandMarket(Options options) : options_(options) {}
  void init(Agent& agent) override;
  void shutdown() override;

  // --- on the agent's thread ---
  // Queues an errand for auction; `listener` hears what becomes of it until it is released.
  // Throws CorosError for an id already offered and not released.
  void offer(const std::string& errand, Place stop, Listener listener);
  // The robot holding the errand failed it: auction it again without that robot. No-op for an
  // errand that is not held by a robot (unknown, released, still being auctioned).
  void reassign(const std::string& errand, const std::string& why);
  // Every errand `robot` holds is auctioned again without it, and it gets no award until
  // set_available(robot) — its devices are gone, or it stopped announcing itself.
  void robot_failed(const std::string& robot, const std::string& why);
  void set_available(const std::string& robot);
  // Done or no longer wanted: the robot holding it drops it; its listener hears nothing more.
  void release(const std::string& errand);

  std::size_t open_errands() const { return errands_.size(); }
  const std::set<std::string>& unavailable() const { return unavailable_; }

 private:
  struct Errand {
    Place stop;
    Listener listener;
    int round = 0;
    std::string robot;  // the winner of this round, "" while auctioning
    bool held = false;  // the winner acknowledged
    double cost = 0;
    std::set<std::string> excluded;
    std::map<std::string, double> bids;
    std::map<std::string, std::string> declined;  // robot -> its reason, this round
    std::map<std::string, asio::ip::udp::endpoint> bidders;
    Clock::time_point round_started{};
    std::shared_ptr<Timer> closer;
    std::shared_ptr<GroupAction> announcer, awarder;
    // The round closed without a bid and the next one waits its pause: a bid that comes in
    // meanwhile opens the next round at once and counts there.
    bool between_rounds = false;
  };
  void next();  // starts the next queued auction when none is running
  // Every errand `robot` holds is auctioned again without it; an auction waiting for it does not.
  void lose(const std::string& robot, const std::string& why);
  void start_round(const std::string& id, Errand& e);
  void close_round(const std::string& id);
  void on_bid(const BidMessage& m, const Envelope& env);
  void on_decline(const DeclineMessage& m, const Envelope& env);
  void on_award_ack(const AwardAckMessage& m, const Envelope& env);
  void tell(const Errand& e, ErrandNews news) const;
  std::vector<std::string> excluded(const Errand& e) const;
  bool every_robot_bid(const Errand& e) const;  // the round may close before its window ends
  // An award `robot` did not take: auction the errand again without it (the news first).
  void auction_again(std::string id, Errand& e, const std::string& robot, const std::string& why);
  void stop_messages(Errand& e);
  void revoke(const std::string& id, const Errand& e);

  Options options_;
  std::unique_ptr<ActionHandler> actions_;
  std::map<std::string, Errand> errands_;
  std::deque<std::string> queue_;  // waiting to be auctioned, in order
  std::string active_;             // being auctioned or awarded, "" when none
  std::set<std::string> unavailable_;
  std::vector<std::shared_ptr<GroupAction>> revokers_;
  Clock::time_point started_{};
};

// A robot's side: bids for errands and keeps the route it is committed to.
class ErrandBidder : public SimpleOperator {
 public:
  // Where the robot is now; nullopt when it cannot take errands (no pose, failed).
  using Locator = std::function<std::optional<sim::Point>()>;
  enum class Objective { append, arrival };
  ErrandBidder(std::shared_ptr<const MapPlanner> map, Locator where, Objective objective = Objective::append);
  void init(Agent& agent) override;
  void shutdown() override;

  // --- on the agent's thread ---
  // What appending `stop` to the route would cost now; nullopt when it cannot be done.
  std::optional<double> cost_of(const Place& stop) const;
  // The errands the robot is committed to, in the order it was given them.
  std::vector<std::string> route() const;

 private:
  struct Commitment {
    std::string errand, auctioneer;
    int round = 1;
    sim::Point at;
  };
  std::optional<sim::Point> locate(const Place& stop) const;
  void on_auction(const ErrandAuctionMessage& m, const Envelope& e);
  void on_award(const ErrandAwardMessage& m, const Envelope& e);
  void on_revoke(const RevokeMessage& m, const Envelope& e);
  void drop(const std::string& errand, int up_to_round, const std::string& why);
  void announce_state();

  std::optional<double> leg(sim::Point from, sim::Point to) const;  // planned, snapping the stop
  std::shared_ptr<const MapPlanner> map_;
  Locator where_;
  Objective objective_;
  std::vector<Commitment> route_;
  std::map<std::string, int> newest_round_;  // errand -> newest round heard of
  void forget_old_rounds();  // bounds newest_round_ to the errands on the route
  struct Cost {
    std::uint64_t version = 0;
    int round = 0;
    std::optional<double> cost;
  };
  std::map<std::string, Cost> costs_;  // errand -> the cost last planned, for the route version
  std::uint64_t version_ = 0;          // changes with the route
  std::shared_ptr<Timer> state_timer_;
};

}  // namespace icars::coros
