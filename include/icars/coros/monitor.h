// The monitor agent's operator (COROS 4.2, Monitor Agent): it follows the fleet without taking
// part — the neighbour table from HELLOs (with a DiscoveryOperator beside it) and the task
// table from the robots' TASK_STATUS broadcasts — and renders both as text tables.
#pragma once

#include <string>

#include "icars/coros/agent.h"

namespace icars::coros {

class TaskObserverOperator : public SimpleOperator {
 public:
  void init(Agent& agent) override;
};

// "agent  role  status  load  position  heard" and "task  round  robot  stage  distance".
std::string render_neighbors(const NeighborMonitor& neighbors, Clock::time_point now);
std::string render_tasks(const TaskMonitor& tasks);
// "datagrams: 812 received, 240 sent; dropped: 0 malformed, 3 unsigned, 1 bad tag, 0 replayed".
std::string render_datagram_stats(const TransportStats& stats);

}  // namespace icars::coros
