#include "icars/control/coordinator.h"

#include <fmt/format.h>

#include <algorithm>
#include <functional>
#include <stdexcept>

namespace icars::control {

namespace b = icars::behavior;

// --- Task -----------------------------------------------------------------------------------------

Task::Task(const TaskSpec& spec, std::unique_ptr<b::Behavior> root, b::Environment& env, EventSink sink)
    : spec_(spec), root_(std::move(root)), env_(env), sink_(std::move(sink)) {
  root_->attach(env_, *this, spec_.name);
}

Task::~Task() { stop(); }

void Task::start() {
  running_ = true;
  if (spec_.timeout) {
    timeout_timer_ = env_.runtime.start_timer(*spec_.timeout, [this, life = life()] {
      if (!life.lock() || !running_) return;
      timeout_timer_ = 0;
      root_->halt();
      running_ = false;
      b::Event failed{std::string(kTaskFailed)};
      failed.set("reason", fmt::format("task {} still running after {}", spec_.name,
                                       format_time(*spec_.timeout).substr(3)));
      raise(std::move(failed));
    });
  }
  root_->start();
}

void Task::stop() {
  if (timeout_timer_ != 0) env_.runtime.cancel_timer(timeout_timer_);
  timeout_timer_ = 0;
  running_ = false;
  root_->halt();
}

void Task::child_event(b::Behavior&, const b::Event& event) {
  if (!running_) return;
  const bool declared = std::find(spec_.events.begin(), spec_.events.end(), event.type()) != spec_.events.end();
  b::TraceRecord r;
  r.time = env_.runtime.now();
  r.kind = "event";
  r.source = spec_.name;
  r.text = fmt::format("{}: {}", spec_.name, b::describe_event(event));
  r.with("event", event.type()).with("task", spec_.name).with("task_event", declared).with_properties(event);
  env_.trace.record(std::move(r));
  if (declared) raise(event);
}

void Task::child_done(b::Behavior& root) {
  if (!running_) return;
  running_ = false;
  if (timeout_timer_ != 0) env_.runtime.cancel_timer(timeout_timer_);
  timeout_timer_ = 0;
  if (root.status() == b::Status::succeeded) {
    raise(b::Event{std::string(kTaskDone)});
  } else {
    b::Event failed{std::string(kTaskFailed)};
    failed.set("reason", fmt::format("{} failed: {}", root.name(), root.failure_reason()));
    raise(std::move(failed));
  }
}

void Task::raise(b::Event event) {
  event.set("task", spec_.name);
  // Posted: the coordinator may destroy this task in response.
  env_.runtime.post([this, life = life(), event = std::move(event)] {
    if (life.lock()) sink_(*this, event);
  });
}

// --- Coordinator ----------------------------------------------------------------------------------

namespace {

// "10min", "90s", "1500ms": a delay as a policy writes it, for the trace.
std::string describe_delay(Time d) {
  const auto ms = d.count();
  if (ms % 3'600'000 == 0) return fmt::format("{}h", ms / 3'600'000);
  if (ms % 60'000 == 0) return fmt::format("{}min", ms / 60'000);
  if (ms % 1000 == 0) return fmt::format("{}s", ms / 1000);
  return fmt::format("{}ms", ms);
}

}  // namespace

struct Coordinator::Node {
  const StateSpec* spec = nullptr;
  Node* parent = nullptr;
  std::vector<std::unique_ptr<Node>> children;
  std::unique_ptr<Task> task;
  bool active = false;
  std::uint64_t stay = 0;             // counts entries: what was posted during an earlier stay is dropped
  std::vector<std::uint64_t> timers;  // its delayed transitions and sends, cancelled when it is left
  Node* last_child = nullptr;         // the child active when this state was last left (history)

  bool is_parallel() const { return spec->kind == StateSpec::Kind::parallel; }
  bool is_final() const { return spec->kind == StateSpec::Kind::final; }
  bool contains(const Node* other) const {  // `other` is this state or one of its descendants
    for (; other; other = other->parent) {
      if (other == this) return true;
    }
    return false;
  }
  Node* active_child() const {
    for (const auto& c : children) {
      if (c->active) return c.get();
    }
    return nullptr;
  }
  Node* initial_child() const {
    for (const auto& c : children) {
      if (c->spec->name == spec->initial) return c.get();
    }
    return children.front().get();
  }
  // The innermost active state below it, following the first active child.
  const Node& first_leaf() const {
    const Node* n = this;
    while (const Node* c = n->active_child()) n = c;
    return *n;
  }
  // The innermost region it is in (itself included), or nullptr.
  const Node* region() const {
    for (const Node* n = this; n; n = n->parent) {
      if (n->spec->kind == StateSpec::Kind::region) return n;
    }
    return nullptr;
  }
};

// A transition chosen for an event: the state declaring it and the active state it was found from.
struct Coordinator::Selected {
  const TransitionSpec* transition = nullptr;
  Node* source = nullptr;
  const Node* from = nullptr;
};

Coordinator::Coordinator(Policy policy, const b::BehaviorRegistry& registry, b::Environment& env, RemoteHosts* hosts)
    : policy_(std::move(policy)), registry_(registry), env_(env), hosts_(hosts) {
  std::function<std::unique_ptr<Node>(const StateSpec&, Node*)> build = [&](const StateSpec& spec, Node* parent) {
    auto node = std::make_unique<Node>();
    node->spec = &spec;
    node->parent = parent;
    for (const auto& c : spec.children) node->children.push_back(build(c, node.get()));
    return node;
  };
  root_ = build(policy_.root, nullptr);
  // Device events reach the statechart as task events do (kDeviceEvents).
  device_watch_ = env_.services.watch_devices([this, life = std::weak_ptr<const char>(life_)](const b::Event& e) {
    env_.runtime.post([this, life, e] {
      if (life.lock()) on_task_event(e, nullptr);
    });
  });
}

Coordinator::~Coordinator() {
  env_.services.remove_device_watcher(device_watch_);
  stop();
}

void Coordinator::start() {
  env_.runtime.run([this] {
    if (root_->active) return;
    finished_ = false;
    record("policy", fmt::format("policy {} started", policy_.name), {{"policy", policy_.name}});
    enter_default(*root_, false);
    complete_finals();
  });
}

void Coordinator::stop() {
  env_.runtime.run([this] {
    if (!root_->active) return;
    exit(*root_);
    record("policy", fmt::format("policy {} stopped", policy_.name), {{"policy", policy_.name}});
  });
}

std::vector<std::string> Coordinator::configuration() const {
  return env_.runtime.run([this] {
    std::vector<std::string> out;
    std::function<void(const Node&)> visit = [&](const Node& n) {
      if (!n.active) return;
      if (&n != root_.get()) out.push_back(n.spec->name);
      for (const auto& c : n.children) visit(*c);
    };
    visit(*root_);
    return out;
  });
}

std::string Coordinator::current() const {
  auto c = configuration();
  return c.empty() ? "" : c.back();
}

void Coordinator::raise(b::Event event) {
  if (event.type() == kTaskDone || event.type() == kTaskFailed) {
    throw std::invalid_argument("'" + event.type() + "' is raised by tasks only, not from outside the policy");
  }
  env_.runtime.post([this, life = std::weak_ptr<const char>(life_), event = std::move(event)] {
    if (life.lock()) on_task_event(event, nullptr);
  });
}

std::vector<std::string> Coordinator::events() const {
  std::vector<std::string> out;
  std::function<void(const StateSpec&)> visit = [&](const StateSpec& s) {
    for (const auto& t : s.transitions) {
      if (t.event.empty() || t.event == kTaskDone || t.event == kTaskFailed) continue;
      if (std::find(out.begin(), out.end(), t.event) == out.end()) out.push_back(t.event);
    }
    for (const auto& c : s.children) visit(c);
  };
  visit(policy_.root);
  return out;
}

std::uint64_t Coordinator::transitions() const {
  return env_.runtime.run([this] { return transitions_; });
}

bool Coordinator::finished() const {
  return env_.runtime.run([this] { return finished_; });
}

Coordinator::Node* Coordinator::find(const std::string& name) {
  std::function<Node*(Node&)> search = [&](Node& n) -> Node* {
    if (n.spec->name == name && &n != root_.get()) return &n;
    for (auto& c : n.children) {
      if (auto* f = search(*c)) return f;
    }
    return nullptr;
  };
  return search(*root_);
}

// The active states without an active child, in document order: one per active region.
std::vector<Coordinator::Node*> Coordinator::active_leaves() const {
  std::vector<Node*> out;
  std::function<void(Node&)> visit = [&](Node& n) {
    if (!n.active) return;
    const auto before = out.size();
    for (const auto& c : n.children) visit(*c);
    if (out.size() == before) out.push_back(&n);
  };
  visit(*root_);
  return out;
}

void Coordinator::activate(Node& node) {
  node.active = true;
  const auto stay = ++node.stay;
  const auto& spec = *node.spec;
  const auto life = std::weak_ptr<const char>(life_);
  if (&node != root_.get()) {
    record("state", fmt::format("entered {}", spec.name), {{"state", spec.name}, {"event", std::string("enter")}});
  }
  if (!spec.task.empty()) {
    const auto* task_spec = policy_.task(spec.task);
    try {
      node.task = std::make_unique<Task>(*task_spec, build_tree(task_spec->root, registry_, hosts_), env_,
                                         [this, life, &node](Task&, const b::Event& e) {
                                           if (life.lock()) on_task_event(e, &node);
                                         });
      record("task", fmt::format("task {} started", spec.task), {{"task", spec.task}, {"event", std::string("start")}});
      node.task->start();
    } catch (const std::exception& e) {
      // A tree that cannot be built (the policy was checked, so only a factory's own failure)
      // is reported as the task failing, so a failure transition can handle it.
      record("task", fmt::format("task {} could not start: {}", spec.task, e.what()),
             {{"task", spec.task}, {"event", std::string("failure")}, {"reason", std::string(e.what())}});
      node.task.reset();
      b::Event failed{std::string(kTaskFailed)};
      failed.set("reason", std::string(e.what()));
      failed.set("task", spec.task);
      env_.runtime.post([this, life, failed, &node, stay] {
        if (life.lock() && node.active && node.stay == stay) on_task_event(failed, &node);
      });
    }
  }
  for (const auto& t : spec.transitions) {
    if (!t.after) continue;
    node.timers.push_back(env_.runtime.start_timer(*t.after, [this, life, &node, &t] {
      if (life.lock()) on_delay(node, t);
    }));
  }
  for (const auto& send : spec.sends) {
    auto raise = [this, life, &node, stay, &send] {
      if (life.lock() && node.active && node.stay == stay) on_task_event(b::Event{send.event}, nullptr);
    };
    if (send.after > Time{0}) {
      node.timers.push_back(env_.runtime.start_timer(send.after, std::move(raise)));
    } else {
      env_.runtime.post(std::move(raise));  // after the entry, never inside it
    }
  }
  if (node.is_final()) finals_entered_.push_back(&node);
}

void Coordinator::enter_default(Node& node, bool deep) {
  activate(node);
  if (node.children.empty()) return;
  if (node.is_parallel()) {
    for (auto& region : node.children) enter_default(*region, deep);
    return;
  }
  // History: the child active when it was left (and, deep, what was active below it then).
  const auto history = node.spec->history;
  if (node.last_child && (deep || history != StateSpec::History::none)) {
    enter_default(*node.last_child, deep || history == StateSpec::History::deep);
  } else {
    enter_default(*node.initial_child(), false);
  }
}

// Enters path[i..], each state the parent of the next, the last by its default entry; a parallel
// state on the way enters its other regions by theirs, in document order.
void Coordinator::enter_path(const std::vector<Node*>& path, std::size_t i) {
  Node& node = *path[i];
  if (i + 1 == path.size()) {
    enter_default(node, false);
    return;
  }
  activate(node);
  if (!node.is_parallel()) {
    enter_path(path, i + 1);
    return;
  }
  for (auto& region : node.children) {
    if (region.get() == path[i + 1]) {
      enter_path(path, i + 1);
    } else {
      enter_default(*region, false);
    }
  }
}

void Coordinator::exit(Node& node) {
  for (auto it = node.children.rbegin(); it != node.children.rend(); ++it) {
    if ((*it)->active) exit(**it);
  }
  for (const auto id : node.timers) env_.runtime.cancel_timer(id);
  node.timers.clear();
  if (node.task) {
    node.task->stop();
    const auto halted = node.task->name();
    node.task.reset();  // the behavior tree goes with it
    record("task", fmt::format("task {} stopped", halted), {{"task", halted}, {"event", std::string("stop")}});
  }
  node.active = false;
  if (node.parent) node.parent->last_child = &node;
  if (&node != root_.get()) {
    record("state", fmt::format("left {}", node.spec->name), {{"state", node.spec->name}, {"event", std::string("exit")}});
  }
}

// A final state completes its parent: the parent's `done` is posted (a region's, then its
// parallel state's once every region is in a final state); a final state of the statechart
// itself ends the policy.
void Coordinator::complete_finals() {
  const auto finals = std::exchange(finals_entered_, {});
  std::vector<Node*> completed;
  for (Node* final_state : finals) {
    if (!final_state->active) continue;
    Node* parent = final_state->parent;
    if (parent == root_.get()) {
      exit(*root_);
      finished_ = true;
      record("policy", fmt::format("policy {} finished in {}", policy_.name, final_state->spec->name),
             {{"policy", policy_.name}});
      return;
    }
    completed.push_back(parent);
    Node* parallel = parent->parent;
    if (parent->spec->kind == StateSpec::Kind::region && parallel->active &&
        std::find(completed.begin(), completed.end(), parallel) == completed.end() &&
        std::all_of(parallel->children.begin(), parallel->children.end(), [](const auto& region) {
          const Node* c = region->active_child();
          return c && c->is_final();
        })) {
      completed.push_back(parallel);
    }
  }
  const auto life = std::weak_ptr<const char>(life_);
  for (Node* state : completed) {
    env_.runtime.post([this, life, state, stay = state->stay] {
      if (life.lock() && state->active && state->stay == stay) on_completion(*state);
    });
  }
}

bool Coordinator::admit(std::string_view event_type) {
  // A statechart that keeps transitioning without time passing (a task failing at entry whose
  // failure transition leads back to it) would spin forever: after kMaxTransitionsPerInstant at
  // one instant, further events of that instant are dropped (reported once in the trace).
  const auto instant = env_.runtime.now();
  if (instant != last_transition_at_) {
    last_transition_at_ = instant;
    transitions_this_instant_ = 0;
  } else if (transitions_this_instant_ >= kMaxTransitionsPerInstant) {
    if (transitions_this_instant_++ == kMaxTransitionsPerInstant) {
      record("note", fmt::format("{} transitions at one instant: the statechart is looping; ignoring {} until time passes",
                                 kMaxTransitionsPerInstant, event_type), {});
    }
    return false;
  }
  return true;
}

namespace {

const TransitionSpec* first_match(const StateSpec& state, const b::Event& event, const b::ConditionScope& scope) {
  for (const auto& t : state.transitions) {
    if (!t.event.empty() && t.event == event.type() && t.guard.evaluate(event, scope)) return &t;
  }
  return nullptr;
}

}  // namespace

void Coordinator::on_task_event(const b::Event& event, Node* raised_in) {
  if (!root_->active || !admit(event.type())) return;
  b::ConditionScope scope;
  scope.now = env_.runtime.now();
  const auto trigger = "on " + event.type();
  const auto reason = event.has("reason") ? event.get<std::string>("reason") : std::string();
  // A task's `done` or `failed` is its state's: offered to that state, then its ancestors.
  if (raised_in && (event.type() == kTaskDone || event.type() == kTaskFailed)) {
    if (!raised_in->active) return;
    const Node& from = raised_in->first_leaf();
    scope.variables.emplace("state", from.spec->name);
    for (Node* s = raised_in; s; s = s->parent) {
      if (const auto* t = first_match(*s->spec, event, scope)) {
        fire({t, s, &from}, trigger, reason);
        return;
      }
    }
    if (event.type() == kTaskFailed) {
      record("note", fmt::format("task {} failed and no transition handles it: staying in {}",
                                 event.get<std::string>("task"), from.spec->name),
             {});
    }
    return;
  }
  // Any other event is offered to the whole configuration as SCXML does: from each active leaf
  // in document order up to the statechart, the first matching transition of the innermost state
  // that has one; of two whose exits overlap, the one declared deeper wins, else the first.
  std::vector<Selected> enabled;
  for (Node* leaf : active_leaves()) {
    scope.variables.insert_or_assign("state", leaf->spec->name);
    for (Node* s = leaf; s; s = s->parent) {
      const auto* t = first_match(*s->spec, event, scope);
      if (!t) continue;
      if (std::none_of(enabled.begin(), enabled.end(), [&](const Selected& e) { return e.transition == t; })) {
        enabled.push_back({t, s, leaf});
      }
      break;
    }
  }
  std::vector<Node*> entry;
  std::vector<Selected> chosen;
  for (const auto& candidate : enabled) {
    const Node* mine = plan(candidate, entry);
    bool preempted = false;
    std::vector<const TransitionSpec*> preempting;
    for (const auto& other : chosen) {
      const Node* theirs = plan(other, entry);
      if (!mine || !theirs || !(mine->contains(theirs) || theirs->contains(mine))) continue;
      if (candidate.source != other.source && other.source->contains(candidate.source)) {
        preempting.push_back(other.transition);
      } else {
        preempted = true;
        break;
      }
    }
    if (preempted) continue;
    std::erase_if(chosen, [&](const Selected& s) {
      return std::find(preempting.begin(), preempting.end(), s.transition) != preempting.end();
    });
    chosen.push_back(candidate);
  }
  for (const auto& s : chosen) {
    if (s.source->active && root_->active) fire(s, trigger, reason);
  }
}

void Coordinator::on_completion(Node& state) {
  if (!admit(kTaskDone)) return;
  b::Event done{std::string(kTaskDone)};
  done.set("completed", state.spec->name);
  b::ConditionScope scope;
  scope.now = env_.runtime.now();
  scope.variables.emplace("state", state.first_leaf().spec->name);
  // Only the completed state's own transitions: a region's `done` is not its parallel state's.
  if (const auto* t = first_match(*state.spec, done, scope)) fire({t, &state, &state}, "on done", "");
}

void Coordinator::on_delay(Node& source, const TransitionSpec& transition) {
  if (!source.active || !root_->active || !admit("after")) return;
  b::ConditionScope scope;
  scope.now = env_.runtime.now();
  const Node& from = source.first_leaf();
  scope.variables.emplace("state", from.spec->name);
  if (!transition.guard.evaluate(b::Event{"after"}, scope)) return;
  fire({&transition, &source, &from}, "after " + describe_delay(*transition.after), "");
}

Coordinator::Node* Coordinator::plan(const Selected& selected, std::vector<Node*>& entry) {
  Node* source = selected.source;
  Node* target = find(selected.transition->target);
  entry.clear();
  if (!target) return nullptr;  // checked by the parser
  std::vector<Node*> path;  // from the statechart down to the target
  for (Node* n = target; n; n = n->parent) path.insert(path.begin(), n);
  // The domain: the deepest active state on the target's path that is the source, one of its
  // ancestors or one of its active descendants. Transitions are external: when the domain is the
  // target or the source, it is left and re-entered too.
  std::size_t domain = 0;
  for (std::size_t i = 0; i < path.size(); ++i) {
    if (!path[i]->active || !(path[i]->contains(source) || source->contains(path[i]))) break;
    domain = i;
  }
  while ((path[domain] == target || path[domain] == source) && domain > 0) --domain;
  // In a parallel state, a transition within one region leaves and re-enters only that region;
  // one between regions leaves and re-enters the parallel state, with all its regions.
  Node* leave = nullptr;
  if (path[domain]->is_parallel()) {
    if (path[domain + 1]->contains(source)) {
      leave = path[domain + 1];
    } else {
      --domain;
    }
  }
  if (!leave) leave = path[domain]->active_child();
  entry.assign(path.begin() + static_cast<std::ptrdiff_t>(domain) + 1, path.end());
  return leave;
}

void Coordinator::fire(const Selected& selected, const std::string& trigger, const std::string& reason) {
  const auto& t = *selected.transition;
  std::vector<Node*> entry;
  Node* leave = plan(selected, entry);
  if (entry.empty()) return;
  const auto from = selected.from->spec->name;
  const auto* region = selected.source->region();
  ++transitions_;
  ++transitions_this_instant_;
  record("transition",
         fmt::format("{}{} -> {} {}{}", region ? region->spec->name + ": " : "", from, t.target, trigger,
                     reason.empty() ? "" : " (" + reason + ")"),
         reason.empty()
             ? std::vector<std::pair<std::string, b::TraceValue>>{{"from", from}, {"to", t.target},
                                                                  {"event", t.after ? trigger : t.event},
                                                                  {"declared_in", selected.source->spec->name}}
             : std::vector<std::pair<std::string, b::TraceValue>>{{"from", from}, {"to", t.target},
                                                                  {"event", t.after ? trigger : t.event},
                                                                  {"declared_in", selected.source->spec->name},
                                                                  {"reason", reason}});
  if (leave) exit(*leave);
  enter_path(entry, 0);
  complete_finals();
}

void Coordinator::record(std::string kind, std::string text, std::vector<std::pair<std::string, b::TraceValue>> fields) {
  b::TraceRecord r;
  r.time = env_.runtime.now();
  r.kind = std::move(kind);
  r.source = "coordinator";
  r.text = std::move(text);
  r.fields = std::move(fields);
  env_.trace.record(std::move(r));
}

}  // namespace icars::control
