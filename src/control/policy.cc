// The Policy Parser: XML (pugixml) → Policy, with every check that needs no running system.
#include <fmt/format.h>


#include <algorithm>
#include <fstream>
#include <functional>
#include <limits>
#include <set>
#include <sstream>

#include "icars/control/policy.h"
#include "icars/xml/xml_text.h"

namespace icars::control {

namespace b = icars::behavior;

const TaskSpec* Policy::task(std::string_view task_name) const {
  for (const auto& t : tasks) {
    if (t.name == task_name) return &t;
  }
  return nullptr;
}

std::string Diagnostic::to_string() const {
  const auto where = column > 0 ? fmt::format("{}:{}:{}", file, line, column) : fmt::format("{}:{}", file, line);
  return fmt::format("{}: {}: {}", where, warning ? "warning" : "error", message);
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
      : text_(xml), file_(std::move(file)), registry_(registry) {}

  ParsedPolicy parse() {
    pugi::xml_document doc;
    if (const auto problem = text_.load(doc)) {
      errors_.push_back({file_, static_cast<int>(problem->at.line), false, problem->message,
                         static_cast<int>(problem->at.column)});
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
  int line(const pugi::xml_node& node) { return static_cast<int>(text_.line(node)); }
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

  // host="B": the node and its subtree run on behavior host B (docs/distribution.md); the
  // node's XML without the attribute is what the host builds it from.
  void placement(const pugi::xml_node& node, NodeSpec& spec) {
    const auto host = node.attribute("host");
    if (!host) return;
    spec.host = host.as_string();
    if (spec.host.empty() || spec.host.find_first_of(" \t\r\n/") != std::string::npos) {
      error(line(node), fmt::format("host=\"{}\": expected the name of a behavior host", spec.host));
      return;
    }
    if (std::string_view(node.name()) == "condition") {
      error(line(node), "<condition> is part of its reactive composite and cannot run on another host");
      return;
    }
    pugi::xml_document copy;
    auto placed = copy.append_copy(node);
    placed.remove_attribute("host");
    std::ostringstream xml;
    placed.print(xml, "", pugi::format_raw);
    spec.xml = xml.str();
  }

  // A node of a behavior tree, inside `parent` (an element name; "task" for a root).
  NodeSpec parse_node(const pugi::xml_node& node, std::string_view parent = "task") {
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
    placement(node, spec);
    if (kind == "behavior") {
      spec.kind = NodeSpec::Kind::behavior;
      spec.type = required(node, "type");
      for (auto a : node.attributes()) {
        const std::string_view n = a.name();
        if (n != "type" && n != "name" && n != "host") spec.params[a.name()] = a.value();
      }
      for (auto child : node.children()) {
        if (child.type() != pugi::node_element) continue;
        if (std::string_view(child.name()) != "param") {
          error(line(child), fmt::format("unexpected <{}> in <behavior> (expected <param name= value=>)", child.name()));
          continue;
        }
        check_attributes(child, {"name", "value"});
        const auto name = required(child, "name");
        // The value is the attribute, or the element's text (which keeps its line breaks: a
        // command table, one entry per line).
        const bool has_text = !std::string_view(child.text().get()).empty();
        if (child.attribute("value") && has_text) {
          error(line(child), fmt::format("<param name=\"{}\"> has both a value attribute and text (expected one)", name));
        }
        if (!name.empty()) spec.params[name] = has_text ? child.text().get() : child.attribute("value").as_string();
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
      check_attributes(node, {"name", "host", "repeat", "on_failure"});
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
        check_attributes(node, {"name", "host", "complete"});
      } else if (kind == "filter") {
        spec.kind = NodeSpec::Kind::filter;
        check_attributes(node, {"name", "host", "complete", "pass"});
        if (!node.attribute("pass")) error(spec.line, "<filter> needs a 'pass' condition");
        spec.pass = condition(node, "pass");
      } else if (kind == "interpret") {
        spec.kind = NodeSpec::Kind::interpret;
        check_attributes(node, {"name", "host", "complete", "pass_unmatched"});
        spec.pass_unmatched = checked(node, [&] { return b::parse_boolean("pass_unmatched", node.attribute("pass_unmatched").as_string("false")); });
      } else {
        spec.kind = NodeSpec::Kind::aggregate;
        check_attributes(node, {"name", "host", "complete", "when", "emit", "count", "all_of", "window", "pass_unmatched"});
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
    } else if (kind == "fallback" || kind == "reactive_sequence" || kind == "reactive_fallback") {
      spec.kind = kind == "fallback"            ? NodeSpec::Kind::fallback
                  : kind == "reactive_sequence" ? NodeSpec::Kind::reactive_sequence
                                                : NodeSpec::Kind::reactive_fallback;
      check_attributes(node, {"name", "host"});
    } else if (kind == "condition") {
      spec.kind = NodeSpec::Kind::condition;
      check_attributes(node, {"name", "event", "if"});
      spec.trigger = trigger(node);
      if (parent != "reactive_sequence" && parent != "reactive_fallback") {
        error(spec.line, fmt::format("<condition> belongs in <reactive_sequence> or <reactive_fallback>, not in <{}>", parent));
      }
    } else if (kind == "when") {
      spec.kind = NodeSpec::Kind::when;
      check_attributes(node, {"name", "host", "event", "if", "running", "times", "on_failure"});
      auto& w = spec.when;
      w.trigger = trigger(node);
      const std::string_view running = node.attribute("running").as_string("ignore");
      if (auto r = b::while_running_from_string(running)) {
        w.while_running = *r;
      } else {
        error(spec.line, fmt::format("running=\"{}\": expected restart or ignore", running));
      }
      if (node.attribute("times")) w.times = count(node, "times");
      const std::string_view on_failure = node.attribute("on_failure").as_string("fail");
      if (on_failure != "fail" && on_failure != "continue") {
        error(spec.line, fmt::format("on_failure=\"{}\": expected fail or continue", on_failure));
      }
      w.continue_on_failure = on_failure == "continue";
    } else if (kind == "retry" || kind == "repeat") {
      spec.kind = kind == "retry" ? NodeSpec::Kind::retry : NodeSpec::Kind::repeat;
      if (kind == "retry") {
        check_attributes(node, {"name", "host", "times", "delay"});
        if (node.attribute("delay")) spec.delay = checked(node, [&] { return b::parse_duration("delay", node.attribute("delay").value()); });
      } else {
        check_attributes(node, {"name", "host", "times"});
      }
      if (!required(node, "times").empty()) spec.times = count(node, "times");
    } else if (kind == "timeout") {
      spec.kind = NodeSpec::Kind::timeout;
      check_attributes(node, {"name", "host", "after"});
      if (const auto after = required(node, "after"); !after.empty()) {
        spec.limit = checked(node, [&] { return b::parse_duration("after", after); });
        if (spec.limit.count() <= 0) error(spec.line, fmt::format("after=\"{}\": expected a duration longer than 0 (30s, 5min)", after));
      }
    } else if (kind == "invert") {
      spec.kind = NodeSpec::Kind::invert;
      check_attributes(node, {"name", "host"});
    } else {
      error(spec.line, fmt::format("unknown node <{}> (expected behavior, sequential, fallback, concurrent, filter, "
                                   "interpret, aggregate, reactive_sequence, reactive_fallback, when, retry, "
                                   "repeat, timeout or invert)", kind));
      return spec;
    }
    for (auto child : node.children()) {
      if (child.type() != pugi::node_element) continue;
      if (spec.kind == NodeSpec::Kind::condition) {
        error(line(child), fmt::format("unexpected <{}> in <condition> (it takes no children)", child.name()));
        continue;
      }
      if (std::string_view(child.name()) == "rule") {
        if (spec.kind != NodeSpec::Kind::interpret) {
          error(line(child), fmt::format("<rule> belongs in <interpret>, not in <{}>", kind));
          continue;
        }
        spec.rules.push_back(parse_rule(child));
        spec.rule_lines.push_back(line(child));
        continue;
      }
      spec.children.push_back(parse_node(child, kind));
    }
    if (spec.kind == NodeSpec::Kind::interpret && spec.rules.empty()) {
      error(spec.line, "<interpret> needs at least one <rule when= emit=>");
    }
    switch (spec.kind) {
      case NodeSpec::Kind::when:
      case NodeSpec::Kind::retry:
      case NodeSpec::Kind::repeat:
      case NodeSpec::Kind::timeout:
      case NodeSpec::Kind::invert:
        if (spec.children.size() != 1) {
          error(spec.line, fmt::format("<{}> wraps exactly one node, found {}", kind, spec.children.size()));
        }
        break;
      case NodeSpec::Kind::fallback:
      case NodeSpec::Kind::reactive_sequence:
      case NodeSpec::Kind::reactive_fallback:
        if (spec.children.empty()) error(spec.line, fmt::format("<{}> needs at least one node", kind));
        break;
      default:
        break;
    }
    return spec;
  }

  // `event` (required) and `if` of a <when> or a <condition>.
  b::EventTrigger trigger(const pugi::xml_node& node) { return {required(node, "event"), condition(node, "if")}; }

  // A count attribute: a whole number of at least 1, or `forever` (also `0`, as in
  // <sequential repeat>), read as 0.
  int count(const pugi::xml_node& node, const char* attribute) {
    const std::string_view text = node.attribute(attribute).value();
    if (text == "forever") return 0;
    long long n = -1;
    try {
      n = b::parse_integer(attribute, text);
    } catch (const b::ParamError&) {
      n = -1;  // reported below, with what a count looks like
    }
    if (n >= 0 && n <= std::numeric_limits<int>::max()) return static_cast<int>(n);
    error(line(node), fmt::format("{}=\"{}\": expected a count (1, 2, ...) or forever", attribute, text));
    return 1;
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
  // <statechart> (is_chart), <state>, <parallel>, <region> or <final>, with what it holds.
  StateSpec parse_state(const pugi::xml_node& node, bool is_chart) {
    StateSpec state;
    state.line = line(node);
    const Nesting nesting(nesting_);
    if (nesting.too_deep()) {
      error(state.line, fmt::format("states nested more than {} levels deep (expected a flatter "
                                    "statechart)", kMaxNesting));
      return state;
    }
    const std::string_view element = node.name();
    if (is_chart) {
      check_attributes(node, {"initial"});
    } else {
      if (element == "parallel") {
        state.kind = StateSpec::Kind::parallel;
        check_attributes(node, {"name", "task"});
      } else if (element == "region") {
        state.kind = StateSpec::Kind::region;
        check_attributes(node, {"name", "task", "initial", "history"});
      } else if (element == "final") {
        state.kind = StateSpec::Kind::final;
        check_attributes(node, {"name"});
      } else {
        check_attributes(node, {"name", "task", "initial", "history"});
      }
      state.name = required(node, "name");
    }
    state.task = node.attribute("task").as_string();
    state.initial = node.attribute("initial").as_string();
    if (const auto history = node.attribute("history");
        history && (state.kind == StateSpec::Kind::state || state.kind == StateSpec::Kind::region)) {
      const std::string_view h = history.value();
      if (h == "shallow") {
        state.history = StateSpec::History::shallow;
      } else if (h == "deep") {
        state.history = StateSpec::History::deep;
      } else {
        error(state.line, fmt::format("history=\"{}\": expected shallow or deep", h));
      }
    }
    for (auto child : node.children()) {
      if (child.type() != pugi::node_element) continue;
      const std::string_view name = child.name();
      if (state.kind == StateSpec::Kind::final) {
        error(line(child), fmt::format("final state '{}' cannot hold <{}>: a final state has no task, child "
                                       "states or transitions", state.name, name));
      } else if (name == "transition") {
        state.transitions.push_back(parse_transition(child));
      } else if (name == "send") {
        state.sends.push_back(parse_send(child));
      } else if (state.kind == StateSpec::Kind::parallel) {
        if (name == "region") {
          state.children.push_back(parse_state(child, false));
        } else {
          error(line(child), fmt::format("unexpected <{}> in <parallel> (expected <region>, <transition> or <send>)", name));
        }
      } else if (name == "state" || name == "parallel" || name == "final") {
        state.children.push_back(parse_state(child, false));
      } else if (name == "region") {
        error(line(child), fmt::format("<region> belongs in <parallel>, not in <{}>", element));
      } else {
        error(line(child), fmt::format("unexpected <{}> in a state (expected <state>, <parallel>, <final>, "
                                       "<transition> or <send>)", name));
      }
    }
    if (is_chart && state.children.empty()) error(state.line, "the statechart has no <state>");
    if (state.kind == StateSpec::Kind::parallel && state.children.size() < 2) {
      error(state.line, fmt::format("parallel state '{}' needs at least two <region>s, found {}", state.name,
                                    state.children.size()));
    }
    if (state.history != StateSpec::History::none && state.children.empty()) {
      error(state.line, fmt::format("history=\"{}\" on '{}', which has no child states (history belongs on a "
                                    "composite state or a region)", node.attribute("history").value(), state.name));
    }
    return state;
  }

  TransitionSpec parse_transition(const pugi::xml_node& node) {
    check_attributes(node, {"event", "after", "target", "guard"});
    TransitionSpec t;
    t.line = line(node);
    const bool has_event = !node.attribute("event").empty();
    const bool has_after = !node.attribute("after").empty();
    if (has_event && has_after) {
      error(t.line, "<transition> takes an 'event' or an 'after' delay, not both");
    } else if (has_after) {
      const std::string_view after = node.attribute("after").value();
      t.after = checked(node, [&] { return std::optional(b::parse_duration("after", after)); });
      if (t.after && *t.after <= Time{0}) error(t.line, fmt::format("after=\"{}\": a delayed transition needs a duration longer than 0", after));
    } else if (!has_event) {
      error(t.line, "<transition> needs an 'event' attribute (or 'after' for a delayed transition)");
    } else {
      t.event = required(node, "event");
    }
    t.target = required(node, "target");
    t.guard = condition(node, "guard");
    return t;
  }

  SendSpec parse_send(const pugi::xml_node& node) {
    check_attributes(node, {"event", "after"});
    SendSpec send;
    send.line = line(node);
    send.event = required(node, "event");
    if (send.event == kTaskDone || send.event == kTaskFailed) {
      error(send.line, fmt::format("<send> cannot raise '{}': the Coordinator raises it when a task or state completes",
                                   send.event));
    }
    if (node.attribute("after")) {
      send.after = checked(node, [&] { return b::parse_duration("after", node.attribute("after").value()); });
    }
    for (auto child : node.children()) {
      if (child.type() == pugi::node_element) error(line(child), fmt::format("unexpected <{}> in <send> (it holds nothing)", child.name()));
    }
    return send;
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
    const auto parent_of = [&](const StateSpec* s) -> const StateSpec* {
      const auto it = parent.find(s);
      return it == parent.end() ? nullptr : it->second;
    };
    std::set<std::string> handled;
    std::function<void(const StateSpec&)> check = [&](const StateSpec& s) {
      if (!s.task.empty() && !policy.task(s.task)) {
        error(s.line, fmt::format("state '{}' runs task '{}', which the policy does not define", s.name, s.task));
      }
      if (!s.initial.empty() &&
          std::none_of(s.children.begin(), s.children.end(), [&](const StateSpec& c) { return c.name == s.initial; })) {
        error(s.line, fmt::format("initial state '{}' is not a child of '{}'", s.initial, s.name));
      }
      // Events that can reach this state's transitions: those the tasks and <send>s of the states
      // active while it is raise — its ancestors, its descendants, and every region of a parallel
      // state it is in.
      std::set<std::string> raisable{std::string(kTaskDone), std::string(kTaskFailed)};
      for (const auto d : kDeviceEvents) raisable.emplace(d);
      std::vector<std::string> tasks;
      auto add_state = [&](const StateSpec& st) {
        if (const auto* t = policy.task(st.task)) {
          if (std::find(tasks.begin(), tasks.end(), t->name) == tasks.end()) tasks.push_back(t->name);
          raisable.insert(t->events.begin(), t->events.end());
        }
        for (const auto& send : st.sends) raisable.insert(send.event);
      };
      std::function<void(const StateSpec&)> below = [&](const StateSpec& st) {
        for (const auto& c : st.children) {
          add_state(c);
          below(c);
        }
      };
      for (const StateSpec* a = &s; a; a = parent_of(a)) {
        add_state(*a);
        if (a->kind == StateSpec::Kind::parallel) below(*a);
      }
      below(s);
      for (const auto& t : s.transitions) {
        if (!t.event.empty()) handled.insert(t.event);
        if (!t.target.empty() && !states.contains(t.target)) {
          error(t.line, fmt::format("transition {} goes to state '{}', which does not exist",
                                    t.event.empty() ? "after a delay" : fmt::format("on '{}'", t.event), t.target));
        }
        if (!t.event.empty() && !raisable.contains(t.event)) {
          error(t.line, fmt::format(
              "transition on '{}' in state '{}' can never fire: no task active there raises it (tasks: {}; events: {})",
              t.event, s.name.empty() ? policy.name : s.name, tasks.empty() ? std::string("none") : fmt::format("{}", fmt::join(tasks, ", ")),
              fmt::join(raisable, ", ")));
        }
      }
      // A parallel state completes when every region reached a final state: one without any
      // leaves a 'done' transition on it to its tasks' done only.
      if (s.kind == StateSpec::Kind::parallel &&
          std::any_of(s.transitions.begin(), s.transitions.end(), [](const TransitionSpec& t) { return t.event == kTaskDone; })) {
        for (const auto& region : s.children) {
          if (std::none_of(region.children.begin(), region.children.end(),
                           [](const StateSpec& c) { return c.kind == StateSpec::Kind::final; })) {
            warning(region.line, fmt::format("region '{}' has no <final>: parallel state '{}' never completes, so its "
                                             "'done' transition fires only on a task's done", region.name, s.name));
          }
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
    std::function<void(const StateSpec&)> sends_handled = [&](const StateSpec& s) {
      for (const auto& send : s.sends) {
        if (!handled.contains(send.event)) {
          warning(send.line, fmt::format("state '{}' sends '{}', but no transition handles it",
                                         s.name.empty() ? policy.name : s.name, send.event));
        }
      }
      for (const auto& c : s.children) sends_handled(c);
    };
    sends_handled(policy.root);
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

  xml::XmlText text_;
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
