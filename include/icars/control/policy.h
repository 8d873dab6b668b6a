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
#include "icars/behavior/registry.h"

namespace icars::control {

// One node of a task's behavior tree, as the policy gives it.
struct NodeSpec {
  enum class Kind { behavior, sequential, concurrent, filter, interpret, aggregate };
  Kind kind = Kind::behavior;
  std::string type;  // behavior type (Kind::behavior), else the element name
  std::string name;
  std::map<std::string, std::string, std::less<>> params;  // behavior parameters
  behavior::SequentialBehavior::Options sequence;
  behavior::Completion completion = behavior::Completion::all;
  behavior::Condition pass;                     // filter
  std::vector<behavior::InterpretRule> rules;   // interpret
  bool pass_unmatched = false;                  // interpret, aggregate
  behavior::AggregateSpec aggregate;            // aggregate
  std::vector<NodeSpec> children;
  int line = 0;
};

struct TaskSpec {
  std::string name;
  std::vector<std::string> events;  // the task events it raises besides done and failed
  std::optional<Time> timeout;  // a task still running after this fails
  NodeSpec root;
  int line = 0;
};

struct TransitionSpec {
  std::string event;   // a task event, or "done" / "failed"
  std::string target;  // a state
  behavior::Condition guard;
  int line = 0;
};

struct StateSpec {
  std::string name;
  std::string task;     // "" for a state without a task
  std::string initial;  // a composite state's initial child (default: the first)
  std::vector<StateSpec> children;
  std::vector<TransitionSpec> transitions;
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

// The task events every task raises: its root succeeded, or failed (property `reason`).
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
  std::string to_string() const;  // "file:line: error: message"
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
