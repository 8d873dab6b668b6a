// COROS operations (COROS 4.2, Table 2): actions, which only compute and communicate, and
// tasks, which drive an actuator (the robot's wheels).
//
//   BaseAction   execute() once per step; SingleAction runs once, GroupAction runs every
//                period and keeps its context between runs until it reports done or gives up
//                (resending an award until it is acknowledged is a GroupAction).
//   ActionHandler (IActionHandler) runs actions on an agent's thread.
//   BaseTask     execute(robot, done) and cancel(); MoveToTask drives to one target;
//                SequenceTask runs tasks one after another (CourierDeliveryTask is one).
//   TaskPerformer (ITaskPerformer) keeps a robot's queue of tasks and runs them in order.
//
// All of these live on the agent's thread; robot callbacks are posted to it.
#pragma once

#include <chrono>
#include <deque>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "icars/coros/agent.h"
#include "icars/coros/robot.h"

namespace icars::coros {

class BaseAction {
 public:
  virtual ~BaseAction() = default;
  // One step; true when the action is complete.
  virtual bool execute() = 0;
  // The group action ran out of attempts before completing.
  virtual void give_up() {}
};

class SingleAction : public BaseAction {
 public:
  explicit SingleAction(std::function<void()> fn) : fn_(std::move(fn)) {}
  bool execute() override {
    fn_();
    return true;
  }

 private:
  std::function<void()> fn_;
};

// Runs `step` every `period` (the first time at once) until it returns true, or until it has
// run `max_runs` times, when `on_give_up` runs. complete() ends it from outside (an ack came).
class GroupAction : public BaseAction {
 public:
  GroupAction(std::function<bool()> step, std::chrono::milliseconds period, int max_runs,
              std::function<void()> on_give_up = {})
      : step_(std::move(step)),
        on_give_up_(std::move(on_give_up)),
        period_(period),
        max_runs_(max_runs) {}
  bool execute() override { return done_ || step_(); }
  void give_up() override {
    if (on_give_up_) on_give_up_();
  }
  void complete() {
    done_ = true;
    if (next_run_) next_run_->cancel();
  }
  bool done() const { return done_; }
  std::chrono::milliseconds period() const { return period_; }
  int max_runs() const { return max_runs_; }

 private:
  friend class ActionHandler;
  std::function<bool()> step_;
  std::function<void()> on_give_up_;
  std::chrono::milliseconds period_;
  int max_runs_;
  bool done_ = false;
  std::shared_ptr<Timer> next_run_;  // the pending retry; cancelled with the action
};

// Runs actions on an agent's thread (the paper's IActionHandler).
class ActionHandler {
 public:
  explicit ActionHandler(Agent& agent) : agent_(agent) {}
  void handle(const std::shared_ptr<BaseAction>& action);

 private:
  void step(const std::shared_ptr<GroupAction>& action, int run);
  Agent& agent_;
};

struct TaskOutcome {
  bool success = false;
  double distance = 0;
  std::string detail;
};

class BaseTask {
 public:
  virtual ~BaseTask() = default;
  virtual std::string name() const = 0;
  // Starts the task; `done` runs once on the agent's thread unless the task is cancelled.
  virtual void execute(Agent& agent, Robot& robot, std::function<void(TaskOutcome)> done) = 0;
  // Stops the task; its `done` never runs afterwards.
  virtual void cancel() = 0;
};

class MoveToTask : public BaseTask {
 public:
  MoveToTask(std::string target_name, sim::Point target)
      : target_name_(std::move(target_name)), target_(target) {}
  std::string name() const override { return "move to " + target_name_; }
  void execute(Agent& agent, Robot& robot, std::function<void(TaskOutcome)> done) override;
  void cancel() override;
  sim::Point target() const { return target_; }

 private:
  std::string target_name_;
  sim::Point target_;
  Robot* robot_ = nullptr;
  std::shared_ptr<bool> alive_;
};

// Runs its steps in order; fails at the first failing step. `on_step` hears each step start.
class SequenceTask : public BaseTask {
 public:
  SequenceTask(std::string name, std::vector<std::shared_ptr<BaseTask>> steps)
      : name_(std::move(name)), steps_(std::move(steps)) {}
  std::string name() const override { return name_; }
  void execute(Agent& agent, Robot& robot, std::function<void(TaskOutcome)> done) override;
  void cancel() override;
  void on_step(std::function<void(std::size_t index)> fn) { on_step_ = std::move(fn); }
  std::size_t current_step() const { return index_; }

 private:
  void run_step(Agent& agent, Robot& robot);
  std::string name_;
  std::vector<std::shared_ptr<BaseTask>> steps_;
  std::function<void(std::size_t)> on_step_;
  std::function<void(TaskOutcome)> done_;
  std::size_t index_ = 0;
  double distance_ = 0;
  bool cancelled_ = false;
};

// A robot's task queue (the paper's ITaskPerformer): tasks run one after another.
class TaskPerformer {
 public:
  using Done = std::function<void(const std::string& key, TaskOutcome)>;
  TaskPerformer(Agent& agent, Robot& robot) : agent_(agent), robot_(robot) {}

  // Queues a task under a key; `done` hears its outcome. A key already queued is ignored.
  void perform(const std::string& key, std::shared_ptr<BaseTask> task, Done done);
  // Removes a queued task, or cancels it when running (its done never runs). True if found.
  bool cancel(const std::string& key);
  bool contains(const std::string& key) const;
  std::size_t size() const { return queue_.size() + (current_ ? 1 : 0); }
  const std::string& current_key() const { return current_key_; }
  std::vector<std::string> keys() const;  // the running one first

 private:
  struct Entry {
    std::string key;
    std::shared_ptr<BaseTask> task;
    Done done;
  };
  void next();
  Agent& agent_;
  Robot& robot_;
  std::deque<Entry> queue_;
  std::shared_ptr<BaseTask> current_;
  std::string current_key_;
  Done current_done_;
};

// The base of operators that drive a robot (the paper's RobotOperator): a SimpleOperator with
// a robot, its task queue and an action handler. It keeps the agent's announced position,
// status (idle/busy/failed) and load up to date from the robot every hello period.
class RobotOperator : public SimpleOperator {
 public:
  explicit RobotOperator(std::shared_ptr<Robot> robot) : robot_(std::move(robot)) {}
  void init(Agent& agent) override;
  void shutdown() override;

 protected:
  Robot& robot() const { return *robot_; }
  TaskPerformer& performer() const { return *performer_; }
  ActionHandler& actions() const { return *actions_; }
  void refresh_state();

 private:
  std::shared_ptr<Robot> robot_;
  std::unique_ptr<TaskPerformer> performer_;
  std::unique_ptr<ActionHandler> actions_;
  std::shared_ptr<Timer> state_timer_;
};

}  // namespace icars::coros
