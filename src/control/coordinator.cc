#include "icars/control/coordinator.h"

#include <fmt/format.h>

#include <algorithm>

namespace icars::control {

namespace b = icars::behavior;

// --- Building behavior trees --------------------------------------------------------------------

std::unique_ptr<b::Behavior> build_tree(const NodeSpec& spec, const b::BehaviorRegistry& registry) {
  std::unique_ptr<b::Behavior> node;
  switch (spec.kind) {
    case NodeSpec::Kind::behavior:
      return registry.create(spec.type, spec.name, spec.params);
    case NodeSpec::Kind::sequential:
      node = std::make_unique<b::SequentialBehavior>(spec.sequence);
      break;
    case NodeSpec::Kind::concurrent:
      node = std::make_unique<b::ConcurrentBehavior>(spec.completion);
      break;
    case NodeSpec::Kind::filter:
      node = std::make_unique<b::FilterBehavior>(spec.pass, spec.completion);
      break;
    case NodeSpec::Kind::interpret:
      node = std::make_unique<b::InterpretBehavior>(spec.rules, spec.pass_unmatched, spec.completion);
      break;
    case NodeSpec::Kind::aggregate:
      node = std::make_unique<b::AggregateBehavior>(spec.aggregate, spec.completion);
      break;
  }
  node->set_identity(spec.type, spec.name);
  for (const auto& child : spec.children) node->add_child(build_tree(child, registry));
  return node;
}

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
  r.with("event", event.type()).with("task", spec_.name).with("task_event", declared);
  for (const auto& [name, value] : event.items()) {
    if (value.is<std::string>()) r.with(name, value.as<std::string>());
    else if (value.is<bool>()) r.with(name, value.as<bool>());
    else if (value.is<double>()) r.with(name, value.as<double>());
  }
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

struct Coordinator::Node {
  const StateSpec* spec = nullptr;
  Node* parent = nullptr;
  std::vector<std::unique_ptr<Node>> children;
  std::unique_ptr<Task> task;
  int depth = 0;
};

Coordinator::Coordinator(Policy policy, const b::BehaviorRegistry& registry, b::Environment& env)
    : policy_(std::move(policy)), registry_(registry), env_(env) {
  std::function<std::unique_ptr<Node>(const StateSpec&, Node*, int)> build =
      [&](const StateSpec& spec, Node* parent, int depth) {
        auto node = std::make_unique<Node>();
        node->spec = &spec;
        node->parent = parent;
        node->depth = depth;
        for (const auto& c : spec.children) node->children.push_back(build(c, node.get(), depth + 1));
        return node;
      };
  root_ = build(policy_.root, nullptr, 0);
  // Device events reach the statechart as task events do (kDeviceEvents).
  device_watch_ = env_.services.watch_devices([this, life = std::weak_ptr<const char>(life_)](const b::Event& e) {
    env_.runtime.post([this, life, e] {
      if (life.lock()) on_task_event(e);
    });
  });
}

Coordinator::~Coordinator() {
  env_.services.remove_device_watcher(device_watch_);
  stop();
}

void Coordinator::start() {
  env_.runtime.run([this] {
    if (!active_.empty()) return;
    record("policy", fmt::format("policy {} started", policy_.name), {{"policy", policy_.name}});
    enter(*root_, true);
  });
}

void Coordinator::stop() {
  env_.runtime.run([this] {
    if (active_.empty()) return;
    exit_to(nullptr);
    record("policy", fmt::format("policy {} stopped", policy_.name), {{"policy", policy_.name}});
  });
}

std::vector<std::string> Coordinator::configuration() const {
  return env_.runtime.run([this] {
    std::vector<std::string> out;
    for (const auto* n : active_) {
      if (n != root_.get()) out.push_back(n->spec->name);
    }
    return out;
  });
}

std::string Coordinator::current() const {
  auto c = configuration();
  return c.empty() ? "" : c.back();
}

std::uint64_t Coordinator::transitions() const {
  return env_.runtime.run([this] { return transitions_; });
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

void Coordinator::enter(Node& node, bool with_initial) {
  active_.push_back(&node);
  const auto& spec = *node.spec;
  if (&node != root_.get()) {
    record("state", fmt::format("entered {}", spec.name), {{"state", spec.name}, {"event", std::string("enter")}});
  }
  if (!spec.task.empty()) {
    const auto* task_spec = policy_.task(spec.task);
    try {
      node.task = std::make_unique<Task>(*task_spec, build_tree(task_spec->root, registry_), env_,
                                         [this, life = std::weak_ptr<const char>(life_)](Task&, const b::Event& e) {
                                           if (life.lock()) on_task_event(e);
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
      env_.runtime.post([this, life = std::weak_ptr<const char>(life_), failed, &node] {
        if (!life.lock()) return;
        if (std::find(active_.begin(), active_.end(), &node) == active_.end()) return;
        on_task_event(failed);
      });
    }
  }
  if (with_initial && !node.children.empty()) {
    Node* initial = node.children.front().get();
    for (auto& c : node.children) {
      if (c->spec->name == spec.initial) initial = c.get();
    }
    enter(*initial, true);
  }
}

void Coordinator::exit_to(Node* keep) {
  while (!active_.empty() && active_.back() != keep) {
    Node* node = active_.back();
    if (node->task) {
      node->task->stop();
      const auto halted = node->task->name();
      node->task.reset();  // the behavior tree goes with it
      record("task", fmt::format("task {} stopped", halted), {{"task", halted}, {"event", std::string("stop")}});
    }
    active_.pop_back();
    if (node != root_.get()) {
      record("state", fmt::format("left {}", node->spec->name), {{"state", node->spec->name}, {"event", std::string("exit")}});
    }
  }
}

void Coordinator::on_task_event(const b::Event& event) {
  if (active_.empty()) return;
  // A statechart that keeps transitioning without time passing (a task failing at entry whose
  // failure transition leads back to it) would spin forever: after kMaxTransitionsPerInstant at
  // one instant, further task events of that instant are dropped (reported once in the trace).
  const auto instant = env_.runtime.now();
  if (instant != last_transition_at_) {
    last_transition_at_ = instant;
    transitions_this_instant_ = 0;
  } else if (transitions_this_instant_ >= kMaxTransitionsPerInstant) {
    if (transitions_this_instant_++ == kMaxTransitionsPerInstant) {
      record("note", fmt::format("{} transitions at one instant: the statechart is looping; ignoring {} until time passes",
                                 kMaxTransitionsPerInstant, event.type()), {});
    }
    return;
  }
  b::ConditionScope scope;
  scope.now = env_.runtime.now();
  scope.variables.emplace("state", active_.back()->spec->name);
  // Innermost first: the deepest active state with a matching transition whose guard holds.
  for (auto it = active_.rbegin(); it != active_.rend(); ++it) {
    Node* source = *it;
    for (const auto& t : source->spec->transitions) {
      if (t.event != event.type() || !t.guard.evaluate(event, scope)) continue;
      Node* target = find(t.target);
      if (!target) continue;  // checked by the parser
      // The least common ancestor; a transition to itself or an ancestor leaves and re-enters.
      std::vector<Node*> target_path;
      for (Node* n = target; n; n = n->parent) target_path.insert(target_path.begin(), n);
      Node* lca = root_.get();
      for (std::size_t i = 0; i < target_path.size() && i < active_.size(); ++i) {
        if (active_[i] != target_path[i]) break;
        lca = active_[i];
      }
      if (lca == target || lca == source) lca = lca->parent ? lca->parent : root_.get();
      const auto from = active_.back()->spec->name;
      ++transitions_;
      ++transitions_this_instant_;
      const auto reason = event.has("reason") ? event.get<std::string>("reason") : std::string();
      record("transition",
             fmt::format("{} -> {} on {}{}", from, t.target, event.type(), reason.empty() ? "" : " (" + reason + ")"),
             {{"from", from}, {"to", t.target}, {"event", event.type()}, {"declared_in", source->spec->name}});
      exit_to(lca);
      const auto depth = static_cast<std::size_t>(lca->depth) + 1;
      for (std::size_t i = depth; i < target_path.size(); ++i) {
        enter(*target_path[i], i + 1 == target_path.size());
      }
      return;
    }
  }
  if (event.type() == kTaskFailed) {
    record("note", fmt::format("task {} failed and no transition handles it: staying in {}",
                               event.get<std::string>("task"), active_.back()->spec->name),
           {});
  }
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
