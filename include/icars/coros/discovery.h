// The discovery protocol (COROS 5.1): every agent broadcasts a HELLO with its id, address,
// role, status and a timestamp every hello_period; every HELLO heard updates the neighbour
// table, and neighbours not heard from for neighbor_expiry are removed. Changes are emitted as
// {"event":"neighbor_joined"/"neighbor_left",...} and reach NeighborMonitor listeners, which
// the ROS layer publishes as the agent's neighbourhood topic.
#pragma once

#include <memory>

#include "icars/coros/agent.h"

namespace icars::coros {

class DiscoveryOperator : public SimpleOperator {
 public:
  void init(Agent& agent) override;
  void shutdown() override;
  // Sends a HELLO now (also done every hello_period).
  void announce();

 private:
  std::shared_ptr<Timer> hello_timer_, expiry_timer_;
};

}  // namespace icars::coros
