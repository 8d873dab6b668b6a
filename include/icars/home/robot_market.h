// The home's robot market: behaviors that need a robot ask for one instead of naming it
// (robot="any"), and the robots of the house — each a COROS agent beside its device manager
// (home::RobotAgents) — bid for the work with the COROS errand market (coros/errands.h).
//
// A RobotMarket is a service of the mediating server (type "RobotMarket") holding a COROS
// agent with the ErrandMarket. A behavior offers stops; the market auctions them one after
// another, the winner's bid being the planned path from the end of its route, and tells the
// behavior what became of each:
//   assigned     a robot won it (the news carries every bid); it waits for its turn
//   turn         the robot is the behavior's now: drive it there (done() when there)
//   reauctioned  the robot failed it (its Navigation service went away, it stopped announcing
//                itself, or the behavior said it stalled): it is being auctioned again without
//                that robot; a new assigned and turn follow
//   unassigned   no robot bid (reason): the errand is over
// A robot drives its errands one at a time in the order it won them (the order its bids
// assumed). The market watches the service container: a robot whose Navigation service becomes
// unavailable loses every errand it holds at once and gets no award until it is back.
//
// Every method is thread-safe; listeners run on the market's agent thread (a behavior wraps
// them with guard()).
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "icars/clock/activity.h"
#include "icars/coros/agent.h"
#include "icars/coros/errands.h"
#include "icars/service/service_container.h"

namespace icars::home {

struct ErrandUpdate {
  enum class Kind { assigned, turn, reauctioned, unassigned };
  Kind kind = Kind::assigned;
  std::string errand, robot, reason;
  int round = 1;
  double cost = 0;
  std::map<std::string, double> bids;
  std::vector<std::string> excluded;
  double auction_ms = 0;
};
std::string_view to_string(ErrandUpdate::Kind kind);

struct RobotMarketOptions {
  // The market's agent: its id (say, the server's name), fleet port, key, timings. The role is
  // set to "market".
  coros::AgentConfiguration agent;
  coros::ErrandMarket::Options market;
  // Lock-step (icars/clock/lock_step.h): an errand being auctioned, and every request on its way
  // to the market's thread, hold this activity, so the simulated clock does not run on while a
  // behavior waits for its robot. Null: nothing is held.
  std::shared_ptr<Activity> activity;
};

class RobotMarket : public service::Service {
 public:
  using Listener = std::function<void(const ErrandUpdate&)>;

  // Starts the agent (throws coros::CorosError when its sockets cannot be bound or it has no
  // key) and watches `container`'s Navigation services, which must outlive the market.
  RobotMarket(service::ServiceContainer& container, RobotMarketOptions options);
  ~RobotMarket() override;  // stop()
  // Stops watching the container and stops the agent: no listener runs afterwards, and what is
  // offered afterwards is never auctioned. Idempotent; call it before the container goes when
  // behaviors may still hold the market.
  void stop();

  // Offers a stop; returns the errand's id. `label` names it in the agent's events.
  std::string offer(const std::string& label, coros::Place stop, Listener listener);
  void done(const std::string& errand);                       // reached, or given up on
  void failed(const std::string& errand, std::string why);    // the robot failed it: again
  void withdraw(const std::string& errand) { done(errand); }  // no longer wanted

  // The robots the market's agent hears, by id.
  std::vector<std::string> robots() const;
  // Errands offered and not yet done, withdrawn or unassigned.
  std::size_t open_errands() const;
  coros::Agent& agent() { return *agent_; }

 private:
  struct Entry {
    Listener listener;
    std::string robot;  // the holder, "" while auctioning
    bool turn = false;
    Activity::Hold auctioning;  // offered or lost, and not yet awarded
  };
  Activity::Hold hold() { return Activity::Hold(activity_.get()); }
  void on_news(const coros::ErrandNews& news);      // agent thread
  void advance(const std::string& robot);           // agent thread: the robot's next errand's turn
  void leave_queue(const std::string& errand, const std::string& robot);
  void tell(const std::string& errand, const ErrandUpdate& update);
  void on_service(const std::shared_ptr<service::Service>& s, service::ServiceChange change);

  service::ServiceContainer& container_;
  std::shared_ptr<Activity> activity_;
  std::shared_ptr<coros::ErrandMarket> market_;
  std::unique_ptr<coros::Agent> agent_;
  std::string prefix_;
  std::atomic<std::uint64_t> next_{1};
  std::uint64_t watcher_ = 0;
  std::once_flag stopped_;
  // agent thread only:
  std::map<std::string, Entry> entries_;
  std::map<std::string, std::vector<std::string>> queues_;  // robot -> errands in award order
  mutable std::mutex mutex_;
  std::size_t open_ = 0;  // entries_.size(), readable from any thread
};

}  // namespace icars::home
