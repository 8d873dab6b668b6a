// Collaboration policies (ICARS paper 4.3.3, Figs. 14 and 15): the description of a
// situation-aware application — its tasks, each a tree of behaviors, and the statechart of
// tasks the Coordinator runs — as a file loaded at run time. The format is in docs/policy.md.
//
// The Policy Parser reads a policy file into a Policy and checks everything that can be checked
// before running: XML, elements and attributes, behavior types and their parameters against the
// BehaviorRegistry, conditions, state and task names, transition targets, and that every
// transition's event can be raised in its state. Problems are reported all at once, each as
// "file:line: error: what was wrong (what was expected)".
#pragma once

#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "icars/behavior/composite.h"
#include "icars/behavior/condition.h"
#include "icars/behavior/decorators.h"
#include "icars/behavior/reactive.h"
#include "icars/behavior/registry.h"

namespace icars::control {

// One node of a task's behavior tree, as the policy gives it.
struct NodeSpec {
  enum class Kind {
    behavior, sequential, concurrent, filter, interpret, aggregate,
    fallback, reactive_sequence, reactive_fallback, condition, when,  // reactive.h, composite.h
    retry, repeat, timeout, invert                                    // decorators.h
  };
  Kind kind = Kind::behavior;
  std::string type;  // behavior type (Kind::behavior), else the element name
  std::string name;
  std::map<std::string, std::string, std::less<>> params;  // behavior parameters
  behavior::SequentialBehavior::Options sequence;
  behavior::Completion completion = behavior::Completion::all;
  behavior::Condition pass;                     // filter
  std::vector<behavior::InterpretRule> rules;   // interpret
  std::vector<int> rule_lines;                  // interpret: the line of each rule
  bool pass_unmatched = false;                  // interpret, aggregate
  behavior::AggregateSpec aggregate;            // aggregate
  behavior::WhenBehavior::Options when;         // when
  behavior::EventTrigger trigger;               // condition
  int times = 0;                                // retry (attempts in all), repeat (runs); 0: forever
  Time delay{0};                                // retry: the wait before each new attempt
  Time limit{0};                                // timeout
  std::vector<NodeSpec> children;
  int line = 0;
  // host="B": the node runs on behavior host B (remote_tree.h); `xml` is the node as the host
  // builds it (the element without its host attribute).
  std::string host;
  std::string xml;
};

struct TaskSpec {
  std::string name;
  std::vector<std::string> events;  // the task events it raises besides done and failed
  std::optional<Time> timeout;  // a task still running after this fails
  NodeSpec root;
  int line = 0;
};

struct TransitionSpec {
  std::string event;          // a task event, or "done" / "failed"; "" for a delayed transition
  std::optional<Time> after;  // a delayed transition: fires once its state has been active this long
  std::string target;         // a state
  behavior::Condition guard;
  int line = 0;
};

// <send event= after=>: an event the statechart raises itself, `after` entering the state that
// declares it (cancelled if the state is left first), offered to the configuration as task
// events are.
struct SendSpec {
  std::string event;
  Time after{0};
  int line = 0;
};

struct StateSpec {
  // A state (atomic, or composite with one active child), a parallel state (all its regions
  // active at once), one region of a parallel state, or a final state (it completes its parent).
  enum class Kind { state, parallel, region, final };
  // What a composite state enters when it is entered again: its initial child (none), the child
  // active when it was left (shallow), or the whole configuration below it then (deep).
  enum class History { none, shallow, deep };
  Kind kind = Kind::state;
  std::string name;
  std::string task;     // "" for a state without a task
  std::string initial;  // a composite state's initial child (default: the first)
  History history = History::none;
  std::vector<StateSpec> children;
  std::vector<TransitionSpec> transitions;
  std::vector<SendSpec> sends;
  int line = 0;
};

struct Policy {
  std::string name;
  std::string file;
  std::string description;
  std::vector<TaskSpec> tasks;
  StateSpec root;  // the statechart: a composite state named after the policy

  const TaskSpec* task(std::string_view task_name) const;
};

// The task events every task raises: its root succeeded, or failed (property `reason`). A
// composite state, region or parallel state raises `done` too when it completes (a final state
// reached), with the property `completed` naming it.
inline constexpr std::string_view kTaskDone = "done";
inline constexpr std::string_view kTaskFailed = "failed";
// The Service Framework's events about devices (service::DeviceRegistry): any state may have a
// transition on them, whatever its tasks raise ("DeviceRestored" when a device came back with
// another state than the one last acknowledged).
inline constexpr std::string_view kDeviceEvents[] = {"DeviceLost", "DeviceBack", "DeviceRestored",
                                                    "DeviceForgotten"};

struct Diagnostic {
  std::string file;
  int line = 0;
  bool warning = false;
  std::string message;
  int column = 0;                 // 1-based; 0: not known (only malformed XML has one)
  std::string to_string() const;  // "file:line[:column]: error: message"
};

class PolicyError : public std::runtime_error {
 public:
  explicit PolicyError(std::vector<Diagnostic> diagnostics);
  const std::vector<Diagnostic>& diagnostics() const { return diagnostics_; }

 private:
  std::vector<Diagnostic> diagnostics_;
};

struct ParsedPolicy {
  Policy policy;
  std::vector<Diagnostic> warnings;
};

// Parses and checks a policy. Throws PolicyError listing every error found.
ParsedPolicy parse_policy_file(const std::string& path, const behavior::BehaviorRegistry& registry);
ParsedPolicy parse_policy(std::string_view xml, const std::string& file_name,
                          const behavior::BehaviorRegistry& registry);

}  // namespace icars::control
