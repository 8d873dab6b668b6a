// The courier delivery application (COROS 5.2): a market where a user agent auctions
// deliveries between two offices and robots bid their planned travel cost.
//
// Protocol (docs/coros.md has the message sequence and the failure cases):
//   1. The user's CourierUserOperator broadcasts AUCTION(task, round, pickup, dropoff, window),
//      repeating it a few times within the bid window so a lost datagram does not lose bids.
//   2. Each CourierRobotOperator that is not excluded bids the length of the path it would
//      drive, planned over the map: from the end of its current queue (or where it stands)
//      to the pickup office, then to the dropoff office. It answers every copy of the auction
//      with the same bid.
//   3. The auction closes when every robot in the user's neighbour table has bid (a robot that
//      leaves the table is no longer waited for), or when the window ends. The lowest cost wins; equal costs go to the smaller robot id. No bid:
//      the task is auctioned again (round + 1) after a pause, up to max_rounds.
//   4. The user resends AWARD until the winner's AWARD_ACK; a winner that never answers is
//      excluded and the task auctioned again. The robot queues the CourierDeliveryTask
//      (MoveToTask to the pickup, then to the dropoff), broadcasts TASK_STATUS at each stage
//      and resends RESULT until RESULT_ACK.
//   5. Fault tolerance: when the assigned robot leaves the user's neighbour table (its HELLOs
//      stopped) before the result, the task is auctioned again with round + 1, excluding it.
//      Every message carries (task, round): anything about an older round is stale, and a
//      robot holding a stale assignment drops it when it hears of a newer round (a REVOKE,
//      or an AUCTION of the same task). So a task is assigned to one robot at a time, and
//      completed once: duplicates and reordering change nothing, losses are repaired by
//      resending.
#pragma once

#include <asio/thread_pool.hpp>
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

// Drive to the pickup office, take the courier, drive to the dropoff office.
class CourierDeliveryTask : public SequenceTask {
 public:
  CourierDeliveryTask(const Place& pickup, const Place& dropoff);
};

class CourierRobotOperator : public RobotOperator {
 public:
  CourierRobotOperator(std::shared_ptr<Robot> robot, std::shared_ptr<const MapPlanner> map);
  void init(Agent& agent) override;

  ~CourierRobotOperator() override;
  void shutdown() override;  // also stops the planner thread
  // What this robot would bid now for a delivery; nullopt when it cannot do it. Computed on
  // the calling thread; bids are planned on the operator's planner thread.
  std::optional<double> cost_of(const Place& pickup, const Place& dropoff) const;

  // The robot's commitments: where it is, and the deliveries it still has to drive.
  struct Route {
    sim::Point from;
    struct Leg {
      Place pickup, dropoff;
      bool picked_up = false;
    };
    std::vector<Leg> legs;
  };
  static std::optional<double> route_cost(const MapPlanner& map, const Route& route,
                                          const Place& pickup, const Place& dropoff);

 private:
  Route route() const;
  void bid(const AuctionMessage& m, std::optional<double> cost);  // to all who asked
  struct Assignment {
    std::string task_id, auctioneer;
    int round = 1;
    Place pickup, dropoff;
    asio::ip::udp::endpoint reply_to;
    TaskStage stage = TaskStage::assigned;
    double distance = 0;
    double started_s = 0;
    double start_odometer = 0;
    std::shared_ptr<GroupAction> result_sender;
  };
  void on_auction(const AuctionMessage& m, const Envelope& e);
  void on_award(const AwardMessage& m, const Envelope& e);
  void on_revoke(const RevokeMessage& m, const Envelope& e);
  void on_result_ack(const ResultAckMessage& m, const Envelope& e);
  void drop(const std::string& task_id, const std::string& why);
  void set_stage(Assignment& a, TaskStage stage);
  void finish(const std::string& task_id, const TaskOutcome& outcome);

  std::shared_ptr<const MapPlanner> map_;
  std::map<std::string, Assignment> assignments_;  // task id -> held assignment
  std::map<std::string, int> newest_round_;        // task id -> newest round heard of
  std::map<std::string, double> bids_;             // "task#round" -> bid sent
  std::set<std::string> finished_;                 // "task#round" already ended here
  std::shared_ptr<Timer> status_timer_;
  struct Cost {
    std::uint64_t route_version = 0;
    std::optional<double> cost;
    Clock::time_point at{};
  };
  std::map<std::string, Cost> costs_;  // task id -> the last cost planned for it
  std::uint64_t route_version_ = 0;    // changes whenever the robot's commitments change
  // task id -> who asked (endpoint, round) while its cost was being planned
  std::map<std::string, std::vector<std::pair<asio::ip::udp::endpoint, int>>> planning_;
  asio::thread_pool planner_{1};  // last member: joined first, before anything it uses goes
};

struct DeliveryRecord {
  std::string task_id;
  Place pickup, dropoff;
  int round = 0;
  std::string robot;  // assigned robot ("" while auctioning)
  double cost = 0;
  std::map<std::string, double> bids;  // this round's bids
  std::vector<std::string> excluded;
  bool finished = false;
  bool success = false;
  double distance = 0;
  double duration_s = 0;
  std::string detail;
  Clock::time_point requested{}, auction_started{}, assigned_at{}, finished_at{};
  std::vector<std::string> history;  // "round 1: robot3 won at 12.40 m of 5 bids", ...
};

class CourierUserOperator : public SimpleOperator {
 public:
  struct Options {
    int max_rounds = 10;
    int announcements = 3;  // copies of each AUCTION within the window
  };
  explicit CourierUserOperator(std::shared_ptr<const MapPlanner> map)
      : CourierUserOperator(std::move(map), Options{}) {}
  CourierUserOperator(std::shared_ptr<const MapPlanner> map, Options options);
  void init(Agent& agent) override;
  void shutdown() override;

  // On the agent's thread: auctions a delivery between two places of the map; returns the
  // task id. Throws CorosError for an unknown place.
  std::string request(const std::string& pickup, const std::string& dropoff);
  const std::map<std::string, DeliveryRecord>& deliveries() const { return deliveries_; }
  bool all_finished() const;
  void on_finished(std::function<void(const DeliveryRecord&)> fn) { finished_fn_ = std::move(fn); }

 private:
  struct Auction {
    std::shared_ptr<Timer> closer;
    std::shared_ptr<GroupAction> announcer, awarder;
    std::map<std::string, asio::ip::udp::endpoint> bidders;
    // The round closed without a bid and the next one waits its pause: a bid that comes in
    // meanwhile opens the next round at once and counts there.
    bool between_rounds = false;
    std::map<std::string, std::string> declined;  // robot -> its reason, this round
  };
  void start_round(DeliveryRecord& record);
  void close_round(const std::string& task_id);
  void on_bid(const BidMessage& m, const Envelope& e);
  void on_decline(const DeclineMessage& m, const Envelope& e);
  // Every robot in the neighbour table (robots only, not monitors or users) that may bid in
  // this round has bid or declined: the round closes without waiting for the rest of its window.
  bool every_known_robot_bid(const DeliveryRecord& record) const;
  void on_award_ack(const AwardAckMessage& m, const Envelope& e);
  void on_status(const TaskStatusMessage& m, const Envelope& e);
  void on_result(const ResultMessage& m, const Envelope& e);
  void on_neighbor_left(const AgentState& agent);
  void reauction(DeliveryRecord& record, const std::string& robot, const std::string& why);
  void start_configured_deliveries();
  void conclude(DeliveryRecord& record);  // finished: emit, notify, maybe all_done
  void check_all_done();  // every configured delivery finished or rejected: all_done, once
  TaskState state_of(const DeliveryRecord& record, TaskStage stage) const;

  std::shared_ptr<const MapPlanner> map_;
  Options options_;
  std::unique_ptr<ActionHandler> actions_;
  std::map<std::string, DeliveryRecord> deliveries_;
  std::map<std::string, Auction> auctions_;
  std::function<void(const DeliveryRecord&)> finished_fn_;
  std::shared_ptr<Timer> start_timer_;
  std::vector<std::shared_ptr<Timer>> delivery_timers_;
  int next_task_ = 1;
  bool configured_started_ = false;
  bool all_done_sent_ = false;
  std::size_t rejected_ = 0;  // configured deliveries naming unknown places
};

}  // namespace icars::coros
