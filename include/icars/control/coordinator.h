// ICARS Control Architecture (paper 3.4, 4.3.3, Figs. 13 and 14): every situation-aware
// application is a statechart whose states are bound to Tasks; the Coordinator moves between
// states on the task events the running tasks raise.
//
// - A Task is a named behavior tree. Events its root propagates are "top-level events"; those
//   the task declares become task events for the Coordinator. Its root succeeding or failing
//   raises `done` or `failed` (with `reason`); a task still running after its timeout fails.
// - The statechart is hierarchical: a composite state enters its initial child (or, with
//   history, what was active when it was left); a transition declared on a state applies in all
//   its descendants; the innermost matching transition whose guard holds fires; leaving a state
//   halts and destroys its task (and so its whole behavior tree), entering one creates and
//   starts its task.
// - A parallel state runs all its regions at once, each with its own states and tasks; an event
//   may fire one transition per region (SCXML's selection: active states in document order,
//   inner states first). Reaching a final state completes its parent (`done`); a final state of
//   the statechart itself ends the policy. Delayed transitions (`after`) and `<send>`s follow
//   the runtime's clock and are cancelled when their state is left.
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
#include "icars/control/tree_builder.h"

namespace icars::control {

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
  // `hosts`: where nodes with a host attribute run (remote_tree.h); null: none may.
  Coordinator(Policy policy, const behavior::BehaviorRegistry& registry, behavior::Environment& env,
              RemoteHosts* hosts = nullptr);
  ~Coordinator();  // stops
  Coordinator(const Coordinator&) = delete;
  Coordinator& operator=(const Coordinator&) = delete;

  void start();  // enters the initial configuration
  void stop();   // leaves every state, innermost first

  const Policy& policy() const { return policy_; }
  // The active states in document order, each before its children (the statechart's root, named
  // after the policy, excluded): without parallel states, outermost first.
  std::vector<std::string> configuration() const;
  std::string current() const;  // the innermost active state (in a parallel state: of its last region)
  // An event from outside the policy — an operator's command from Home Assistant or a dashboard
  // — offered to the active configuration as a device event is (on the runtime's thread, after
  // what is queued there). Thread-safe. Throws std::invalid_argument for `done` and `failed`,
  // which only tasks raise.
  void raise(behavior::Event event);
  // The events the statechart's transitions wait for, besides `done` and `failed`, in document
  // order without repeats: what an operator's command may raise to move it.
  std::vector<std::string> events() const;
  std::uint64_t transitions() const;
  // The statechart reached one of its own final states: every state was left and the policy
  // does nothing more (until start() runs it again).
  bool finished() const;

 private:
  struct Node;
  struct Selected;
  void activate(Node& node);                   // one state: its trace record, task and timers
  void enter_default(Node& node, bool deep);   // a state, then its initial (or remembered) children
  void enter_path(const std::vector<Node*>& path, std::size_t i);
  void exit(Node& node);                       // its active descendants, innermost first, then it
  void complete_finals();                      // final states just entered complete their parents
  // The state a transition leaves (with its active descendants; nullptr: none) and, in `entry`,
  // the states it enters on the way to its target.
  Node* plan(const Selected& selected, std::vector<Node*>& entry);
  void fire(const Selected& selected, const std::string& trigger, const std::string& reason);
  void on_task_event(const behavior::Event& event, Node* raised_in);  // nullptr: device, <send>
  void on_completion(Node& state);
  void on_delay(Node& source, const TransitionSpec& transition);
  bool admit(std::string_view event_type);     // false while the statechart is looping
  Node* find(const std::string& name);
  std::vector<Node*> active_leaves() const;
  void record(std::string kind, std::string text, std::vector<std::pair<std::string, behavior::TraceValue>> fields);

  Policy policy_;
  const behavior::BehaviorRegistry& registry_;
  behavior::Environment& env_;
  RemoteHosts* hosts_ = nullptr;
  std::unique_ptr<Node> root_;
  std::vector<Node*> finals_entered_;  // by the entry under way, for complete_finals()
  bool finished_ = false;
  std::uint64_t transitions_ = 0;
  static constexpr int kMaxTransitionsPerInstant = 100;
  Time last_transition_at_{-1};
  int transitions_this_instant_ = 0;
  std::uint64_t device_watch_ = 0;
  std::shared_ptr<const char> life_ = std::make_shared<const char>('\0');
};

}  // namespace icars::control
