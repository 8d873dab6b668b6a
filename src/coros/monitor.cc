#include "icars/coros/monitor.h"

#include <fmt/format.h>

namespace icars::coros {

void TaskObserverOperator::init(Agent& agent) {
  SimpleOperator::init(agent);
  agent.processor().on<TaskStatusMessage>([this](const TaskStatusMessage& m, const Envelope& e) {
    const auto stage = parse_task_stage(m.state);
    if (!stage) {
      throw CorosError("TASK_STATUS with unknown state '" + m.state + "' from " + e.sender);
    }
    TaskState s;
    s.id = m.task_id;
    s.auctioneer = m.auctioneer;
    s.robot = m.robot;
    s.round = m.round;
    s.stage = *stage;
    s.distance = m.distance;
    s.updated = Clock::now();
    this->agent().tasks().update(s);
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

}  // namespace icars::coros
