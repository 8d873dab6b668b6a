// ICARS Control Architecture (paper 3.4, 4.3.3, Figs. 13 and 14): every situation-aware
// application is a statechart whose states are bound to Tasks; the Coordinator moves between
// states on the task events the running tasks raise.
//
// - A Task is a named behavior tree. Events its root propagates are "top-level events"; those
//   the task declares become task events for the Coordinator. Its root succeeding or failing
//   raises `done` or `failed` (with `reason`); a task still running after its timeout fails.
// - The statechart is hierarchical: a composite state enters its initial child; a transition
//   declared on a state applies in all its descendants; the innermost matching transition whose
//   guard holds fires; leaving a state halts and destroys its task (and so its whole behavior
//   tree), entering one creates and starts its task.
//
// Everything runs on the behavior Runtime's thread; start() and stop() may be called from any
// thread.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "icars/behavior/behavior.h"
#include "icars/behavior/registry.h"
#include "icars/control/policy.h"

namespace icars::control {

// Builds the behavior tree of a node spec (the Policy Factory's half for behaviors).
std::unique_ptr<behavior::Behavior> build_tree(const NodeSpec& spec, const behavior::BehaviorRegistry& registry);

class Task : public behavior::Owner {
 public:
  using EventSink = std::function<void(Task&, const behavior::Event&)>;
  Task(const TaskSpec& spec, std::unique_ptr<behavior::Behavior> root, behavior::Environment& env,
       EventSink sink);
  ~Task() override;  // stops

  const std::string& name() const { return spec_.name; }
  behavior::Behavior& root() { return *root_; }
  void start();
  void stop();  // halts the tree (deepest first); no task event follows

 protected:
  void child_event(behavior::Behavior& child, const behavior::Event& event) override;
  void child_done(behavior::Behavior& child) override;

 private:
  void raise(behavior::Event event);
  const TaskSpec& spec_;
  std::unique_ptr<behavior::Behavior> root_;
  behavior::Environment& env_;
  EventSink sink_;
  std::uint64_t timeout_timer_ = 0;
  bool running_ = false;
};

class Coordinator {
 public:
  Coordinator(Policy policy, const behavior::BehaviorRegistry& registry, behavior::Environment& env);
  ~Coordinator();  // stops
  Coordinator(const Coordinator&) = delete;
  Coordinator& operator=(const Coordinator&) = delete;

  void start();  // enters the initial configuration
  void stop();   // leaves every state, innermost first

  const Policy& policy() const { return policy_; }
  // The active states, outermost first (the statechart's root, named after the policy, excluded).
  std::vector<std::string> configuration() const;
  std::string current() const;  // the innermost active state
  std::uint64_t transitions() const;

 private:
  struct Node;
  void enter(Node& node, bool with_initial);
  void exit_to(Node* keep);  // exits active states below `keep`
  void on_task_event(const behavior::Event& event);
  Node* find(const std::string& name);
  void record(std::string kind, std::string text, std::vector<std::pair<std::string, behavior::TraceValue>> fields);

  Policy policy_;
  const behavior::BehaviorRegistry& registry_;
  behavior::Environment& env_;
  std::unique_ptr<Node> root_;
  std::vector<Node*> active_;  // outermost first
  std::uint64_t transitions_ = 0;
  static constexpr int kMaxTransitionsPerInstant = 100;
  Time last_transition_at_{-1};
  int transitions_this_instant_ = 0;
  std::uint64_t device_watch_ = 0;
  std::shared_ptr<const char> life_ = std::make_shared<const char>('\0');
};

}  // namespace icars::control
