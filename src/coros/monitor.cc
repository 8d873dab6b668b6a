#include "icars/coros/monitor.h"

#include <fmt/format.h>

namespace icars::coros {

void TaskObserverOperator::init(Agent& agent) {
  SimpleOperator::init(agent);
  agent.processor().on<TaskStatusMessage>([this](const TaskStatusMessage& m, const Envelope& e) {
    this->agent().tasks().update(TaskState::from_status(m, e.sender));
  });
}

std::string render_neighbors(const NeighborMonitor& neighbors, Clock::time_point now) {
  std::string out = fmt::format("{:<12} {:<8} {:<7} {:>4} {:>16} {:>8}\n", "agent", "role",
                                "status", "load", "position", "heard");
  for (const auto& n : neighbors.neighbors()) {
    const auto ago = std::chrono::duration_cast<std::chrono::milliseconds>(now - n.last_heard);
    out += fmt::format("{:<12} {:<8} {:<7} {:>4} {:>16} {:>6}ms\n", n.id, n.role, n.status, n.load,
                       fmt::format("({:.1f}, {:.1f})", n.x, n.y), ago.count());
  }
  return out;
}

std::string render_tasks(const TaskMonitor& tasks) {
  std::string out = fmt::format("{:<14} {:>5} {:<12} {:<11} {:>9}\n", "task", "round", "robot",
                                "stage", "distance");
  for (const auto& t : tasks.tasks()) {
    out += fmt::format("{:<14} {:>5} {:<12} {:<11} {:>8.1f}m\n", t.id, t.round,
                       t.robot.empty() ? "-" : t.robot, to_string(t.stage), t.distance);
  }
  return out;
}

std::string render_datagram_stats(const TransportStats& s) {
  return fmt::format(
      "datagrams: {} received, {} sent; dropped: {} malformed, {} unsigned, {} bad tag, {} "
      "replayed\n",
      s.received, s.sent, s.malformed, s.rejected_unsigned, s.rejected_bad_tag,
      s.rejected_replayed);
}

}  // namespace icars::coros
