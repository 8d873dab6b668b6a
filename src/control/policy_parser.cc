// The Policy Parser: XML (pugixml) → Policy, with every check that needs no running system.
#include <fmt/format.h>

#include <pugixml.hpp>

#include <algorithm>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>

#include "icars/control/policy.h"

namespace icars::control {

namespace b = icars::behavior;

const TaskSpec* Policy::task(std::string_view task_name) const {
  for (const auto& t : tasks) {
    if (t.name == task_name) return &t;
  }
  return nullptr;
}

std::string Diagnostic::to_string() const {
  return fmt::format("{}:{}: {}: {}", file, line, warning ? "warning" : "error", message);
}

namespace {

// Behavior trees and statecharts are read recursively; deeper nesting is reported as an error
// instead of overflowing the stack (a file 50,000 <sequential> deep did).
constexpr int kMaxNesting = 64;

std::string join_messages(const std::vector<Diagnostic>& diagnostics) {
  std::string out;
  for (const auto& d : diagnostics) {
    if (!out.empty()) out += '\n';
    out += d.to_string();
  }
  return out;
}

}  // namespace

PolicyError::PolicyError(std::vector<Diagnostic> diagnostics)
    : std::runtime_error(join_messages(diagnostics)), diagnostics_(std::move(diagnostics)) {}

namespace {

class Parser {
 public:
  Parser(std::string_view xml, std::string file, const b::BehaviorRegistry& registry)
      : xml_(xml), file_(std::move(file)), registry_(registry) {}

  ParsedPolicy parse() {
    pugi::xml_document doc;
    const auto result = doc.load_buffer(xml_.data(), xml_.size(), pugi::parse_default, pugi::encoding_utf8);
    if (!result) {
      error(line_of(result.offset), fmt::format("malformed XML: {}", result.description()));
      throw PolicyError(errors_);
    }
    const auto root = doc.document_element();
    ParsedPolicy out;
    auto& policy = out.policy;
    policy.file = file_;
    if (std::string_view(root.name()) != "policy") {
      error(line(root), fmt::format("the root element is <{}>, expected <policy>", root.name()));
      throw PolicyError(errors_);
    }
    policy.name = required(root, "name");
    check_attributes(root, {"name", "version"});
    const auto version = std::string_view(root.attribute("version").as_string("1"));
    if (version != "1") error(line(root), fmt::format("policy version '{}' is not supported (expected 1)", version));

    pugi::xml_node statechart;
    for (auto child : root.children()) {
      if (child.type() != pugi::node_element) continue;
      const std::string_view name = child.name();
      if (name == "description") {
        policy.description = child.text().as_string();
      } else if (name == "task") {
        policy.tasks.push_back(parse_task(child));
      } else if (name == "statechart") {
        if (statechart) error(line(child), "a policy has one <statechart>");
        statechart = child;
      } else {
        error(line(child), fmt::format("unexpected <{}> in <policy> (expected <description>, <task> or <statechart>)", name));
      }
    }
    std::set<std::string> task_names;
    for (const auto& t : policy.tasks) {
      if (!task_names.insert(t.name).second) error(t.line, fmt::format("task '{}' is defined twice", t.name));
    }
    if (!statechart) {
      error(line(root), "the policy has no <statechart>");
    } else {
      policy.root = parse_state(statechart, /*is_chart=*/true);
      policy.root.name = policy.name;
      check_chart(policy);
    }
    if (!errors_.empty()) throw PolicyError(errors_);
    out.warnings = warnings_;
    return out;
  }

 private:
  // One level of a recursively read tree; too_deep() beyond kMaxNesting.
  class Nesting {
   public:
    explicit Nesting(int& depth) : depth_(depth) { ++depth_; }
    ~Nesting() { --depth_; }
    Nesting(const Nesting&) = delete;
    Nesting& operator=(const Nesting&) = delete;
    bool too_deep() const { return depth_ > kMaxNesting; }

   private:
    int& depth_;
  };

  // --- Diagnostics ----------------------------------------------------------------------------
  // Line numbers come from the offsets of the newlines, found once: counting them from the start
  // for every node made parsing quadratic in the file's size.
  int line_of(std::ptrdiff_t offset) {
    if (offset < 0) return 0;
    if (!newlines_indexed_) {
      for (std::size_t i = 0; i < xml_.size(); ++i) {
        if (xml_[i] == '\n') newlines_.push_back(i);
      }
      newlines_indexed_ = true;
    }
    const auto end = std::min<std::size_t>(static_cast<std::size_t>(offset), xml_.size());
    return 1 + static_cast<int>(std::lower_bound(newlines_.begin(), newlines_.end(), end) - newlines_.begin());
  }
  int line(const pugi::xml_node& node) { return line_of(node.offset_debug()); }
  void error(int line, std::string message) { errors_.push_back({file_, line, false, std::move(message)}); }
  void warning(int line, std::string message) { warnings_.push_back({file_, line, true, std::move(message)}); }

  std::string required(const pugi::xml_node& node, const char* attribute) {
    const auto a = node.attribute(attribute);
    if (!a || std::string_view(a.value()).empty()) {
      error(line(node), fmt::format("<{}> needs a '{}' attribute", node.name(), attribute));
      return "";
    }
    return a.value();
  }

  void check_attributes(const pugi::xml_node& node, std::initializer_list<std::string_view> allowed) {
    for (auto a : node.attributes()) {
      if (std::find(allowed.begin(), allowed.end(), std::string_view(a.name())) == allowed.end()) {
        error(line(node), fmt::format("<{}> has no attribute '{}' (it takes: {})", node.name(), a.name(),
                                      fmt::join(allowed, ", ")));
      }
    }
  }

  b::Condition condition(const pugi::xml_node& node, const char* attribute) {
    const auto text = node.attribute(attribute).as_string();
    try {
      return b::Condition::parse(text);
    } catch (const b::ConditionError& e) {
      error(line(node), fmt::format("in {}=\"{}\": {}", attribute, text, e.what()));
      return {};
    }
  }

  template <class F>
  auto checked(const pugi::xml_node& node, F parse) -> decltype(parse()) {
    try {
      return parse();
    } catch (const b::ParamError& e) {
      error(line(node), e.what());
      return {};
    }
  }

  // --- Tasks and behavior trees ---------------------------------------------------------------
  TaskSpec parse_task(const pugi::xml_node& node) {
    TaskSpec task;
    task.line = line(node);
    task.name = required(node, "name");
    check_attributes(node, {"name", "events", "timeout"});
    task.events = b::parse_list(node.attribute("events").as_string());
    for (const auto& e : task.events) {
      if (e == kTaskDone || e == kTaskFailed) {
        error(task.line, fmt::format("task '{}' declares '{}', which every task raises by itself", task.name, e));
      }
    }
    if (node.attribute("timeout")) {
      task.timeout = checked(node, [&] { return std::optional(b::parse_duration("timeout", node.attribute("timeout").value())); });
    }
    int roots = 0;
    for (auto child : node.children()) {
      if (child.type() != pugi::node_element) continue;
      if (++roots == 1) task.root = parse_node(child);
    }
    if (roots != 1) {
      error(task.line, fmt::format("task '{}' needs exactly one root behavior or composite, found {}", task.name, roots));
    }
    return task;
  }

  NodeSpec parse_node(const pugi::xml_node& node) {
    NodeSpec spec;
    spec.line = line(node);
    const Nesting nesting(nesting_);
    if (nesting.too_deep()) {
      error(spec.line, fmt::format("behaviors nested more than {} levels deep (expected a flatter "
                                   "tree: move a subtree into a task of its own)", kMaxNesting));
      return spec;
    }
    spec.name = node.attribute("name").as_string();
    const std::string_view kind = node.name();
    if (kind == "behavior") {
      spec.kind = NodeSpec::Kind::behavior;
      spec.type = required(node, "type");
      for (auto a : node.attributes()) {
        const std::string_view n = a.name();
        if (n != "type" && n != "name") spec.params[a.name()] = a.value();
      }
      for (auto child : node.children()) {
        if (child.type() != pugi::node_element) continue;
        if (std::string_view(child.name()) != "param") {
          error(line(child), fmt::format("unexpected <{}> in <behavior> (expected <param name= value=>)", child.name()));
          continue;
        }
        check_attributes(child, {"name", "value"});
        const auto name = required(child, "name");
        if (!name.empty()) spec.params[name] = child.attribute("value").as_string();
      }
      if (!spec.type.empty()) {
        checked(node, [&] { return registry_.check(spec.type, spec.params); });
      }
      if (spec.name.empty()) spec.name = spec.type;
      return spec;
    }
    spec.type = std::string(kind);
    if (spec.name.empty()) spec.name = spec.type;
    if (kind == "sequential") {
      spec.kind = NodeSpec::Kind::sequential;
      check_attributes(node, {"name", "repeat", "on_failure"});
      if (node.attribute("repeat")) {
        const std::string_view r = node.attribute("repeat").value();
        spec.sequence.repeat = r == "forever" ? 0 : static_cast<int>(checked(node, [&] { return b::parse_integer("repeat", r); }));
        if (spec.sequence.repeat < 0) error(spec.line, "repeat must be a positive count or 'forever'");
      }
      const std::string_view on_failure = node.attribute("on_failure").as_string("fail");
      if (on_failure != "fail" && on_failure != "continue") {
        error(spec.line, fmt::format("on_failure=\"{}\": expected fail or continue", on_failure));
      }
      spec.sequence.continue_on_failure = on_failure == "continue";
    } else if (kind == "concurrent" || kind == "filter" || kind == "interpret" || kind == "aggregate") {
      if (kind == "concurrent") {
        spec.kind = NodeSpec::Kind::concurrent;
        check_attributes(node, {"name", "complete"});
      } else if (kind == "filter") {
        spec.kind = NodeSpec::Kind::filter;
        check_attributes(node, {"name", "complete", "pass"});
        if (!node.attribute("pass")) error(spec.line, "<filter> needs a 'pass' condition");
        spec.pass = condition(node, "pass");
      } else if (kind == "interpret") {
        spec.kind = NodeSpec::Kind::interpret;
        check_attributes(node, {"name", "complete", "pass_unmatched"});
        spec.pass_unmatched = checked(node, [&] { return b::parse_boolean("pass_unmatched", node.attribute("pass_unmatched").as_string("false")); });
      } else {
        spec.kind = NodeSpec::Kind::aggregate;
        check_attributes(node, {"name", "complete", "when", "emit", "count", "all_of", "window", "pass_unmatched"});
        auto& a = spec.aggregate;
        a.when = condition(node, "when");
        a.emit = required(node, "emit");
        if (node.attribute("count")) a.count = static_cast<int>(checked(node, [&] { return b::parse_integer("count", node.attribute("count").value()); }));
        a.all_of = b::parse_list(node.attribute("all_of").as_string());
        if (node.attribute("window")) a.window = checked(node, [&] { return b::parse_duration("window", node.attribute("window").value()); });
        a.pass_unmatched = checked(node, [&] { return b::parse_boolean("pass_unmatched", node.attribute("pass_unmatched").as_string("false")); });
        if (a.count < 1) error(spec.line, "count must be at least 1");
      }
      const std::string_view complete = node.attribute("complete").as_string("all");
      if (auto c = b::completion_from_string(complete)) {
        spec.completion = *c;
      } else {
        error(spec.line, fmt::format("complete=\"{}\": expected all, any or first", complete));
      }
    } else {
      error(spec.line, fmt::format("unknown node <{}> (expected behavior, sequential, concurrent, filter, interpret or aggregate)", kind));
      return spec;
    }
    for (auto child : node.children()) {
      if (child.type() != pugi::node_element) continue;
      if (std::string_view(child.name()) == "rule") {
        if (spec.kind != NodeSpec::Kind::interpret) {
          error(line(child), fmt::format("<rule> belongs in <interpret>, not in <{}>", kind));
          continue;
        }
        spec.rules.push_back(parse_rule(child));
        continue;
      }
      spec.children.push_back(parse_node(child));
    }
    if (spec.kind == NodeSpec::Kind::interpret && spec.rules.empty()) {
      error(spec.line, "<interpret> needs at least one <rule when= emit=>");
    }
    return spec;
  }

  b::InterpretRule parse_rule(const pugi::xml_node& node) {
    check_attributes(node, {"when", "emit", "copy"});
    b::InterpretRule rule;
    rule.when = condition(node, "when");
    rule.emit = required(node, "emit");
    rule.copy = checked(node, [&] { return b::parse_boolean("copy", node.attribute("copy").as_string("true")); });
    for (auto child : node.children()) {
      if (child.type() != pugi::node_element) continue;
      if (std::string_view(child.name()) != "set") {
        error(line(child), fmt::format("unexpected <{}> in <rule> (expected <set name= value=>)", child.name()));
        continue;
      }
      check_attributes(child, {"name", "value"});
      rule.set.emplace_back(required(child, "name"), condition(child, "value"));
    }
    return rule;
  }

  // --- The statechart -------------------------------------------------------------------------
  StateSpec parse_state(const pugi::xml_node& node, bool is_chart) {
    StateSpec state;
    state.line = line(node);
    const Nesting nesting(nesting_);
    if (nesting.too_deep()) {
      error(state.line, fmt::format("states nested more than {} levels deep (expected a flatter "
                                    "statechart)", kMaxNesting));
      return state;
    }
    if (is_chart) {
      check_attributes(node, {"initial"});
    } else {
      check_attributes(node, {"name", "task", "initial"});
      state.name = required(node, "name");
    }
    state.task = node.attribute("task").as_string();
    state.initial = node.attribute("initial").as_string();
    for (auto child : node.children()) {
      if (child.type() != pugi::node_element) continue;
      const std::string_view name = child.name();
      if (name == "state") {
        state.children.push_back(parse_state(child, false));
      } else if (name == "transition") {
        check_attributes(child, {"event", "target", "guard"});
        TransitionSpec t;
        t.line = line(child);
        t.event = required(child, "event");
        t.target = required(child, "target");
        t.guard = condition(child, "guard");
        state.transitions.push_back(std::move(t));
      } else {
        error(line(child), fmt::format("unexpected <{}> in a state (expected <state> or <transition>)", name));
      }
    }
    if (is_chart && state.children.empty()) error(state.line, "the statechart has no <state>");
    return state;
  }

  void check_chart(const Policy& policy) {
    std::map<std::string, const StateSpec*> states;
    std::map<const StateSpec*, const StateSpec*> parent;
    std::function<void(const StateSpec&)> collect = [&](const StateSpec& s) {
      for (const auto& c : s.children) {
        if (!states.emplace(c.name, &c).second) error(c.line, fmt::format("state '{}' is defined twice", c.name));
        parent[&c] = &s;
        collect(c);
      }
    };
    collect(policy.root);
    std::set<std::string> handled;
    std::function<void(const StateSpec&)> check = [&](const StateSpec& s) {
      if (!s.task.empty() && !policy.task(s.task)) {
        error(s.line, fmt::format("state '{}' runs task '{}', which the policy does not define", s.name, s.task));
      }
      if (!s.initial.empty() &&
          std::none_of(s.children.begin(), s.children.end(), [&](const StateSpec& c) { return c.name == s.initial; })) {
        error(s.line, fmt::format("initial state '{}' is not a child of '{}'", s.initial, s.name));
      }
      // Events that can reach this state's transitions: those of the tasks active while it is.
      std::set<std::string> raisable{std::string(kTaskDone), std::string(kTaskFailed)};
      for (const auto d : kDeviceEvents) raisable.emplace(d);
      std::vector<std::string> tasks;
      auto add_task = [&](const StateSpec& st) {
        if (const auto* t = policy.task(st.task)) {
          tasks.push_back(t->name);
          raisable.insert(t->events.begin(), t->events.end());
        }
      };
      for (const StateSpec* a = &s; a; a = parent.contains(a) ? parent[a] : nullptr) add_task(*a);
      std::function<void(const StateSpec&)> below = [&](const StateSpec& st) {
        for (const auto& c : st.children) {
          add_task(c);
          below(c);
        }
      };
      below(s);
      for (const auto& t : s.transitions) {
        handled.insert(t.event);
        if (!t.target.empty() && !states.contains(t.target)) {
          error(t.line, fmt::format("transition on '{}' goes to state '{}', which does not exist", t.event, t.target));
        }
        if (!t.event.empty() && !raisable.contains(t.event)) {
          error(t.line, fmt::format(
              "transition on '{}' in state '{}' can never fire: no task active there raises it (tasks: {}; events: {})",
              t.event, s.name.empty() ? policy.name : s.name, tasks.empty() ? std::string("none") : fmt::format("{}", fmt::join(tasks, ", ")),
              fmt::join(raisable, ", ")));
        }
      }
      for (const auto& c : s.children) check(c);
    };
    check(policy.root);
    for (const auto& task : policy.tasks) {
      for (const auto& e : task.events) {
        if (!handled.contains(e)) warning(task.line, fmt::format("task '{}' raises '{}', but no transition handles it", task.name, e));
      }
    }
    // A failing task should lead somewhere: warn for states whose task failure nothing handles.
    std::function<void(const StateSpec&, bool)> failure_handled = [&](const StateSpec& s, bool inherited) {
      const bool here = inherited || std::any_of(s.transitions.begin(), s.transitions.end(),
                                                 [](const TransitionSpec& t) { return t.event == kTaskFailed; });
      if (!s.task.empty() && !here) {
        warning(s.line, fmt::format("if task '{}' fails, state '{}' has no 'failed' transition: the home would stay there idle", s.task, s.name));
      }
      for (const auto& c : s.children) failure_handled(c, here);
    };
    failure_handled(policy.root, false);
  }

  std::string_view xml_;
  std::vector<std::size_t> newlines_;  // offsets of the '\n's in xml_
  bool newlines_indexed_ = false;
  std::string file_;
  const b::BehaviorRegistry& registry_;
  std::vector<Diagnostic> errors_;
  int nesting_ = 0;  // of the behavior tree or state being read
  std::vector<Diagnostic> warnings_;
};

}  // namespace

ParsedPolicy parse_policy(std::string_view xml, const std::string& file_name,
                          const behavior::BehaviorRegistry& registry) {
  return Parser(xml, file_name, registry).parse();
}

ParsedPolicy parse_policy_file(const std::string& path, const behavior::BehaviorRegistry& registry) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw PolicyError({{path, 0, false, "cannot read the policy file"}});
  std::ostringstream text;
  text << in.rdbuf();
  return parse_policy(text.str(), path, registry);
}

}  // namespace icars::control
