#include "icars/coros/execution.h"

#include <algorithm>

namespace icars::coros {

// --- ActionHandler -------------------------------------------------------------------------

void ActionHandler::handle(const std::shared_ptr<BaseAction>& action) {
  if (auto group = std::dynamic_pointer_cast<GroupAction>(action)) {
    step(group, 0);
    return;
  }
  action->execute();
}

void ActionHandler::step(const std::shared_ptr<GroupAction>& action, int run) {
  if (action->done()) return;
  if (run >= action->max_runs()) {
    action->give_up();
    return;
  }
  if (action->execute()) {
    action->complete();
    return;
  }
  std::weak_ptr<GroupAction> weak = action;
  action->next_run_ = agent_.after(action->period(), [this, weak, run] {
    if (auto a = weak.lock()) step(a, run + 1);
  });
}

// --- MoveToTask ----------------------------------------------------------------------------

void MoveToTask::execute(Agent& agent, Robot& robot, std::function<void(TaskOutcome)> done) {
  robot_ = &robot;
  alive_ = std::make_shared<bool>(true);
  std::weak_ptr<bool> alive = alive_;
  robot.navigate_to(target_, [&agent, alive, done](NavigationResult r) {
    agent.post([alive, done, r] {
      auto a = alive.lock();
      if (!a || !*a) return;  // cancelled
      *a = false;
      done(TaskOutcome{r.arrived, r.distance, r.detail});
    });
  });
}

void MoveToTask::cancel() {
  if (alive_ && *alive_) {
    *alive_ = false;
    if (robot_) robot_->stop();
  }
}

// --- SequenceTask --------------------------------------------------------------------------

void SequenceTask::execute(Agent& agent, Robot& robot, std::function<void(TaskOutcome)> done) {
  done_ = std::move(done);
  index_ = 0;
  distance_ = 0;
  cancelled_ = false;
  run_step(agent, robot);
}

void SequenceTask::run_step(Agent& agent, Robot& robot) {
  if (index_ >= steps_.size()) {
    done_(TaskOutcome{true, distance_, ""});
    return;
  }
  if (on_step_) on_step_(index_);
  steps_[index_]->execute(agent, robot, [this, &agent, &robot](TaskOutcome outcome) {
    if (cancelled_) return;
    distance_ += outcome.distance;
    if (!outcome.success) {
      done_(TaskOutcome{false, distance_,
                        steps_[index_]->name() + " failed" +
                            (outcome.detail.empty() ? "" : ": " + outcome.detail)});
      return;
    }
    ++index_;
    run_step(agent, robot);
  });
}

void SequenceTask::cancel() {
  cancelled_ = true;
  if (index_ < steps_.size()) steps_[index_]->cancel();
}

// --- TaskPerformer -------------------------------------------------------------------------

void TaskPerformer::perform(const std::string& key, std::shared_ptr<BaseTask> task, Done done) {
  if (contains(key)) return;
  queue_.push_back(Entry{key, std::move(task), std::move(done)});
  if (!current_) next();
}

bool TaskPerformer::cancel(const std::string& key) {
  if (current_ && current_key_ == key) {
    current_->cancel();
    current_key_.clear();
    current_done_ = nullptr;
    agent_.post([this, keep = std::move(current_)] {  // destroyed later, off its own stack
      if (!current_) next();
    });
    return true;
  }
  const auto it =
      std::find_if(queue_.begin(), queue_.end(), [&](const Entry& e) { return e.key == key; });
  if (it == queue_.end()) return false;
  queue_.erase(it);
  return true;
}

bool TaskPerformer::contains(const std::string& key) const {
  if (current_ && current_key_ == key) return true;
  return std::any_of(queue_.begin(), queue_.end(), [&](const Entry& e) { return e.key == key; });
}

std::vector<std::string> TaskPerformer::keys() const {
  std::vector<std::string> out;
  if (current_) out.push_back(current_key_);
  for (const auto& e : queue_) out.push_back(e.key);
  return out;
}

void TaskPerformer::next() {
  if (queue_.empty()) return;
  Entry e = std::move(queue_.front());
  queue_.pop_front();
  current_ = e.task;
  current_key_ = e.key;
  current_done_ = e.done;
  BaseTask* const task = current_.get();  // not owned here: the task holds this callback
  current_->execute(agent_, robot_, [this, task](TaskOutcome outcome) {
    if (current_.get() != task) return;  // cancelled meanwhile
    // This callback lives inside the task: keep the task until the callback has returned.
    agent_.post([keep = current_] {});
    const std::string key = current_key_;
    Done done = std::move(current_done_);
    current_.reset();
    current_key_.clear();
    current_done_ = nullptr;
    if (done) done(key, std::move(outcome));
    if (!current_) next();
  });
}

// --- RobotOperator -------------------------------------------------------------------------

void RobotOperator::init(Agent& agent) {
  SimpleOperator::init(agent);
  performer_ = std::make_unique<TaskPerformer>(agent, *robot_);
  actions_ = std::make_unique<ActionHandler>(agent);
  refresh_state();
  state_timer_ = agent.every(agent.config().hello_period, [this] { refresh_state(); });
}

void RobotOperator::shutdown() {
  if (state_timer_) state_timer_->cancel();
  if (robot_) robot_->stop();
}

void RobotOperator::refresh_state() {
  const sim::Pose p = robot_->pose();
  agent().set_position(p.x, p.y);
  agent().set_load(static_cast<int>(performer_->size()));
  if (robot_->status() == RobotStatus::failed) {
    agent().set_status("failed");
  } else {
    agent().set_status(performer_->size() > 0 ? "busy" : "idle");
  }
}

}  // namespace icars::coros
