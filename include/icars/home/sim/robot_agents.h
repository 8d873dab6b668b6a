// The robots of a simulated house as COROS agents (docs/distribution.md, "Robots"): beside a
// device manager hosting a robot's wheels, one agent per robot announces it (HELLO with its
// pose and load) and bids for the errands a RobotMarket auctions (coros::ErrandBidder): the
// planned path, over the house's map for the robot's radius, from the end of its route to the
// stop. The agents run on the wall clock; the robots' poses come from the world.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "icars/coros/agent.h"
#include "icars/coros/errands.h"
#include "icars/sim/world.h"

namespace icars::home {

class RobotAgents {
 public:
  // An agent for each robot in `robots` (ids of the world's robots; throws
  // std::invalid_argument for another), configured as `base` with the robot's id and role
  // "robot". Throws coros::CorosError when a socket cannot be bound or there is no key.
  RobotAgents(sim::World& world, const std::vector<std::string>& robots, const coros::AgentConfiguration& base);
  ~RobotAgents();  // stops the agents
  RobotAgents(const RobotAgents&) = delete;
  RobotAgents& operator=(const RobotAgents&) = delete;

  void start();
  void stop();
  std::vector<coros::Agent*> agents();
  // The errands robot `robot` is committed to, in order (from its agent's thread).
  std::vector<std::string> route(const std::string& robot);

 private:
  struct Robot {
    std::unique_ptr<coros::Agent> agent;
    std::shared_ptr<coros::ErrandBidder> bidder;
  };
  std::vector<std::pair<std::string, Robot>> robots_;
};

}  // namespace icars::home
