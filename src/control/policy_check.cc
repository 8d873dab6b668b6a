// check_policy: the events flowing up each task's behavior tree, computed from the behavior
// types' declarations, against the conditions that read them; and the world's names against
// the parameters and conditions that use them.
#include "icars/control/policy_check.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <map>
#include <set>

namespace icars::control {

namespace b = icars::behavior;

namespace {

std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t next = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = row[j];
      row[j] = next;
    }
  }
  return row[b.size()];
}

// " (did you mean 'x'?)" for the closest known name within a few edits, else " (known: ...)".
std::string alternatives(std::string_view given, const std::set<std::string>& known) {
  const std::string* best = nullptr;
  std::size_t best_distance = std::max<std::size_t>(2, given.size() / 3) + 1;
  for (const auto& k : known) {
    const auto d = edit_distance(given, k);
    if (d < best_distance) {
      best_distance = d;
      best = &k;
    }
  }
  if (best != nullptr) return fmt::format(" (did you mean '{}'?)", *best);
  if (known.empty()) return " (there are none)";
  constexpr std::size_t kListed = 12;
  std::vector<std::string> listed(known.begin(), known.end());
  const bool more = listed.size() > kListed;
  if (more) listed.resize(kListed);
  return fmt::format(" (known: {}{})", fmt::join(listed, ", "), more ? ", ..." : "");
}

// The events that leave a node of a behavior tree, with their properties. `open`: some node
// below did not declare what it propagates, so anything may.
struct Flow {
  std::map<std::string, std::set<std::string>> events;
  bool open = false;

  void add(const std::string& type, const std::set<std::string>& properties) {
    events[type].insert(properties.begin(), properties.end());
  }
  void merge(const Flow& other) {
    for (const auto& [type, properties] : other.events) add(type, properties);
    open = open || other.open;
  }
  std::set<std::string> all_properties() const {
    std::set<std::string> out;
    for (const auto& [type, properties] : events) out.insert(properties.begin(), properties.end());
    return out;
  }
  std::set<std::string> types() const {
    std::set<std::string> out;
    for (const auto& [type, properties] : events) out.insert(type);
    return out;
  }
};

class Checker {
 public:
  Checker(const Policy& policy, const b::BehaviorRegistry& registry, const b::Vocabulary& world)
      : policy_(policy), registry_(registry), world_(world) {}

  std::vector<Diagnostic> run() {
    const Flow nothing;  // no event reaches a task's root
    for (const auto& task : policy_.tasks) flow(task.root, &nothing);
    return std::move(problems_);
  }

 private:
  void error(int line, std::string message) {
    if (quiet_ == 0) problems_.push_back({policy_.file, line, false, std::move(message)});
  }
  // While one lives, nothing is reported: a subtree's flow computed only for what it propagates.
  class Quiet {
   public:
    explicit Quiet(int& depth) : depth_(depth) { ++depth_; }
    ~Quiet() { --depth_; }
    Quiet(const Quiet&) = delete;
    Quiet& operator=(const Quiet&) = delete;

   private:
    int& depth_;
  };

  // The names of `kind` in the world, or null when the world does not list that kind.
  const std::set<std::string>* names_of(std::string_view kind) const {
    const auto it = world_.names.find(kind);
    return it == world_.names.end() ? nullptr : &it->second;
  }
  std::string world_name() const { return world_.source.empty() ? std::string("the world") : world_.source; }

  void check_name(int line, std::string_view where, std::string_view kind, const std::string& value) {
    const auto* known = names_of(kind);
    if (known == nullptr || value.empty() || known->contains(value)) return;
    error(line, fmt::format("{}: '{}' is not a {} of {}{}", where, value, kind, world_name(), alternatives(value, *known)));
  }

  // The events leaving `node`. Given `in`, the events that reach it, also checks its subtree: each
  // condition against the events reaching it, each name against the world. Without, only computes.
  Flow flow(const NodeSpec& node, const Flow* in) {
    std::vector<Flow> outs;
    {
      const Quiet quiet(quiet_);
      for (const auto& child : node.children) outs.push_back(flow(child, nullptr));
    }
    Flow children;
    for (const auto& out : outs) children.merge(out);
    if (in != nullptr) {
      for (std::size_t i = 0; i < node.children.size(); ++i) {
        const auto reaching = reaching_child(node, i, outs, *in);
        flow(node.children[i], &reaching);
      }
    }
    switch (node.kind) {
      case NodeSpec::Kind::behavior:
        return leaf(node);
      case NodeSpec::Kind::sequential:
      case NodeSpec::Kind::concurrent:
      case NodeSpec::Kind::fallback:
      case NodeSpec::Kind::reactive_sequence:
      case NodeSpec::Kind::reactive_fallback:
      case NodeSpec::Kind::retry:
      case NodeSpec::Kind::repeat:
      case NodeSpec::Kind::timeout:
      case NodeSpec::Kind::invert:
        return children;
      case NodeSpec::Kind::condition:
        if (in != nullptr) check_trigger(node, node.trigger, *in);
        return {};
      case NodeSpec::Kind::when:
        if (in != nullptr) check_trigger(node, node.when.trigger, *in);
        return children;
      case NodeSpec::Kind::filter:
        check_condition(node, node.line, node.pass, children, "pass");
        return children;
      case NodeSpec::Kind::interpret: {
        Flow out;
        out.open = children.open;
        for (std::size_t i = 0; i < node.rules.size(); ++i) {
          const auto& rule = node.rules[i];
          const int line = i < node.rule_lines.size() ? node.rule_lines[i] : node.line;
          check_condition(node, line, rule.when, children, "<rule> when");
          std::set<std::string> properties;
          if (rule.copy) properties = children.all_properties();
          for (const auto& [name, expression] : rule.set) {
            check_condition(node, line, expression, children, fmt::format("<set name=\"{}\"> value", name));
            properties.insert(name);
          }
          out.add(rule.emit, properties);
        }
        if (node.pass_unmatched) out.merge(children);
        return out;
      }
      case NodeSpec::Kind::aggregate: {
        check_condition(node, node.line, node.aggregate.when, children, "when");
        if (!children.open) {
          for (const auto& type : node.aggregate.all_of) {
            if (!children.events.contains(type)) {
              error(node.line, fmt::format("<aggregate> all_of: no event '{}' reaches it{}", type,
                                           alternatives(type, children.types())));
            }
          }
        }
        Flow out;
        out.open = children.open;
        auto properties = children.all_properties();
        properties.insert({"count", "first_ms", "last_ms"});
        out.add(node.aggregate.emit, properties);
        if (node.aggregate.pass_unmatched) out.merge(children);
        return out;
      }
    }
    return children;
  }

  // What reaches child `i` of `node`, given what reaches `node` and what each child propagates.
  // Its siblings' events; but a decorator's or a <when>'s child, and a reactive composite's
  // <condition>s, hear what reaches the node itself (docs/policy.md, "Reactive nodes").
  static Flow reaching_child(const NodeSpec& node, std::size_t i, const std::vector<Flow>& outs, const Flow& in) {
    switch (node.kind) {
      case NodeSpec::Kind::when:
      case NodeSpec::Kind::retry:
      case NodeSpec::Kind::repeat:
      case NodeSpec::Kind::timeout:
      case NodeSpec::Kind::invert:
        return in;
      default:
        break;
    }
    if (node.children[i].kind == NodeSpec::Kind::condition) return in;
    Flow siblings;
    for (std::size_t j = 0; j < outs.size(); ++j) {
      if (j != i) siblings.merge(outs[j]);
    }
    return siblings;
  }

  // The `event` and `if` of a <when> or <condition>, against the events reaching it: the type
  // must be one of them, and `if` reads only that type's properties.
  void check_trigger(const NodeSpec& node, const b::EventTrigger& trigger, const Flow& in) {
    const auto it = in.events.find(trigger.event);
    if (!in.open && it == in.events.end()) {
      const auto hint = !in.events.empty() ? alternatives(trigger.event, in.types())
                        : node.kind == NodeSpec::Kind::condition
                            ? std::string(" (nothing reaches it: a <condition> hears the events that reach its "
                                          "reactive composite, from that composite's siblings)")
                            : fmt::format(" (nothing reaches it: a <{}> hears the events its siblings propagate; "
                                          "put it in a <concurrent> beside a behavior that propagates them)",
                                          node.type);
      error(node.line, fmt::format("<{}> event=\"{}\": no event '{}' reaches it{}", node.type, trigger.event,
                                   trigger.event, hint));
      return;
    }
    Flow matching;
    matching.open = in.open;
    if (it != in.events.end()) matching.add(it->first, it->second);
    check_condition(node, node.line, trigger.condition, matching, "if");
  }

  Flow leaf(const NodeSpec& node) {
    Flow out;
    const auto* entry = registry_.find(node.type);
    if (entry == nullptr) return out;  // the parser reported it
    if (entry->emits) {
      for (const auto& e : *entry->emits) out.add(e.type, {e.properties.begin(), e.properties.end()});
    } else {
      out.open = true;
    }
    for (const auto& spec : entry->params) {
      const auto given = node.params.find(spec.name);
      const std::string value = given != node.params.end() ? given->second : spec.default_value.value_or("");
      if (spec.names_in) {
        for (const auto& [kind, name] : spec.names_in(value)) {
          check_name(node.line, fmt::format("{} {}", node.type, spec.name), kind, name);
        }
      }
      if (spec.names.empty()) continue;
      std::vector<std::string> values;
      if (spec.type == b::ParamType::list) {
        values = b::parse_list(value);
      } else if (!value.empty()) {
        values.push_back(value);
      }
      for (const auto& v : values) {
        if (spec.names == "event") {
          out.add(v, {});
        } else {
          check_name(node.line, fmt::format("{} {}", node.type, spec.name), spec.names, v);
        }
      }
    }
    return out;
  }

  // A condition of `node`, at `line`, reading the events in `in`.
  void check_condition(const NodeSpec& node, int line, const b::Condition& condition, const Flow& in,
                       std::string_view what) {
    if (condition.empty()) return;
    const auto where = node.kind == NodeSpec::Kind::interpret
                           ? fmt::format("{} \"{}\"", what, condition.text())
                           : fmt::format("<{}> {} \"{}\"", node.type, what, condition.text());
    const auto properties = in.all_properties();
    if (!in.open) {
      static const std::set<std::string, std::less<>> kBuiltin = {"event", "time", "day", "child"};
      for (const auto& name : condition.identifiers()) {
        if (kBuiltin.contains(name) || properties.contains(name)) continue;
        error(line, fmt::format("{}: no event reaching it carries '{}'{}", where, name, alternatives(name, properties)));
      }
    }
    for (const auto& [name, literal] : condition.compared_strings()) {
      if (name == "event") {
        if (!in.open && !in.events.contains(literal)) {
          error(line, fmt::format("{}: no event '{}' reaches it{}", where, literal, alternatives(literal, in.types())));
        }
      } else if (const auto kind = world_.property_kinds.find(name); kind != world_.property_kinds.end()) {
        check_name(line, where, kind->second, literal);
      }
    }
  }

  const Policy& policy_;
  const b::BehaviorRegistry& registry_;
  const b::Vocabulary& world_;
  std::vector<Diagnostic> problems_;
  int quiet_ = 0;  // Quiet objects alive
};

}  // namespace

std::vector<Diagnostic> check_policy(const Policy& policy, const b::BehaviorRegistry& registry,
                                     const b::Vocabulary& world) {
  return Checker(policy, registry, world).run();
}

}  // namespace icars::control
