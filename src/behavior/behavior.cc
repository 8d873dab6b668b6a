#include "icars/behavior/behavior.h"

#include <fmt/format.h>

#include <algorithm>

namespace icars::behavior {

std::string_view to_string(Status status) {
  switch (status) {
    case Status::idle: return "idle";
    case Status::running: return "running";
    case Status::succeeded: return "succeeded";
    case Status::failed: return "failed";
    case Status::halted: return "halted";
  }
  return "?";
}

std::string describe_event(const Event& e) {
  std::string out = e.type();
  for (const auto& [name, value] : e.items()) {
    const auto v = trace_value(value);
    if (!v) continue;
    std::string text;
    if (const auto* s = std::get_if<std::string>(&*v)) text = *s;
    else if (const auto* b = std::get_if<bool>(&*v)) text = *b ? "true" : "false";
    else if (const auto* d = std::get_if<double>(&*v)) text = fmt::format("{:g}", *d);
    else text = std::to_string(std::get<std::int64_t>(*v));
    out += fmt::format(" {}={}", name, text);
  }
  return out;
}

Behavior::~Behavior() {
  // The derived part is gone, so exit() cannot run here: owners halt before destroying. What
  // the base holds (children, timers, subscriptions) is still released.
  if (running() && env_) {
    status_ = Status::halted;
    for (auto it = children_.rbegin(); it != children_.rend(); ++it) (*it)->halt();
    for (const auto timer : timers_) env_->runtime.cancel_timer(timer);
    for (auto it = releases_.rbegin(); it != releases_.rend(); ++it) (*it)();
  }
}

void Behavior::listen_devices() {
  auto deliver = guard([this](const Event& e) { receive(e); });
  auto& services = env_->services;
  const auto id = services.watch_devices([deliver](const Event& e) mutable { deliver(e); });
  on_release([&services, id] { services.remove_device_watcher(id); });
}

void Behavior::set_identity(std::string type, std::string name) {
  type_ = std::move(type);
  name_ = name.empty() ? type_ : std::move(name);
}

std::string Behavior::path() const {
  return path_prefix_.empty() ? name_ : path_prefix_ + "/" + name_;
}

Behavior& Behavior::add_child(std::unique_ptr<Behavior> child) {
  child->parent_ = this;
  child->owner_ = this;
  children_.push_back(std::move(child));
  return *children_.back();
}

void Behavior::attach(Environment& env, Owner& owner, std::string path_prefix) {
  env_ = &env;
  owner_ = &owner;
  path_prefix_ = std::move(path_prefix);
  for (auto& child : children_) {
    child->attach(env, *this, path());
    child->parent_ = this;
  }
}

void Behavior::start() {
  if (running()) return;
  status_ = Status::running;
  reason_.clear();
  activation_ = std::make_shared<const char>('\0');
  record("behavior", fmt::format("{} started", path()), {{"event", std::string("start")}, {"type", type_}});
  try {
    entry();
  } catch (const std::exception& e) {
    if (running()) fail(e.what());
  }
}

void Behavior::halt() {
  if (!running()) return;
  status_ = Status::halted;
  release();
  record("behavior", fmt::format("{} halted", path()), {{"event", std::string("halt")}, {"type", type_}});
}

void Behavior::release() {
  for (auto it = children_.rbegin(); it != children_.rend(); ++it) (*it)->halt();
  try {
    exit();
  } catch (const std::exception& e) {
    record("note", fmt::format("{}: exit failed: {}", path(), e.what()));
  }
  for (const auto timer : timers_) env_->runtime.cancel_timer(timer);
  timers_.clear();
  for (auto it = releases_.rbegin(); it != releases_.rend(); ++it) (*it)();
  releases_.clear();
  activation_.reset();  // every guarded callback of this activation is now dropped
}

void Behavior::succeed() { complete(Status::succeeded, ""); }

void Behavior::fail(std::string reason) { complete(Status::failed, std::move(reason)); }

void Behavior::complete(Status status, std::string reason) {
  if (!running()) return;
  status_ = status;
  reason_ = std::move(reason);
  release();
  if (status == Status::succeeded) {
    record("behavior", fmt::format("{} succeeded", path()), {{"event", std::string("success")}, {"type", type_}});
  } else {
    record("behavior", fmt::format("{} failed: {}", path(), reason_),
           {{"event", std::string("failure")}, {"type", type_}, {"reason", reason_}});
  }
  notify_owner_done();
}

void Behavior::notify_owner_done() {
  if (!owner_) return;
  env_->runtime.post([owner = owner_, life = owner_->life(), self = this, me = life()] {
    // Only if both still exist: a halted parent may already have destroyed this child.
    if (life.lock() && me.lock()) owner->child_done(*self);
  });
}

void Behavior::receive(const Event& e) {
  if (running()) handle(e);
}

void Behavior::handle(const Event& e) {
  ++events_handled_;
  try {
    handle_event(e);
  } catch (const std::exception& ex) {
    if (running()) fail(fmt::format("while handling {}: {}", e.type(), ex.what()));
  }
}

void Behavior::child_event(Behavior&, const Event& event) {
  if (running()) propagate(event);
}

void Behavior::propagate(Event e) {
  if (!owner_) return;
  auto shared = std::make_shared<const Event>(std::move(e));
  env_->runtime.post([owner = owner_, life = owner_->life(), self = this, me = life(), shared] {
    if (life.lock() && me.lock()) owner->child_event(*self, *shared);
  });
  if (!parent_) return;
  for (auto& sibling : parent_->children_) {
    if (sibling.get() == this) continue;
    env_->runtime.post([target = sibling.get(), life = sibling->life(), shared] {
      if (life.lock()) target->receive(*shared);
    });
  }
}

std::uint64_t Behavior::after(Time delay, std::function<void()> fn) {
  auto id = std::make_shared<std::uint64_t>(0);
  *id = env_->runtime.start_timer(delay, guard_call([this, id, fn = std::move(fn)] {
    timers_.erase(*id);
    fn();
  }));
  timers_.insert(*id);
  return *id;
}

void Behavior::cancel(std::uint64_t timer) {
  if (timers_.erase(timer) != 0) env_->runtime.cancel_timer(timer);
}

void Behavior::note(std::string text) { record("note", fmt::format("{}: {}", path(), text)); }

Event Behavior::rename(Event e) {
  const auto& type = e.type();
  const auto colon = type.rfind("::");
  if (colon == std::string::npos) return e;
  Event out(type.substr(colon + 2));
  for (const auto& [name, value] : e.items()) out.put(name, value);
  return out;
}

std::string Behavior::describe(std::exception_ptr e) {
  try {
    std::rethrow_exception(e);
  } catch (const planet::RemoteException& ex) {
    const auto& type = ex.type_id();
    const auto colon = type.rfind("::");
    return fmt::format("{}: {}", colon == std::string::npos ? type : type.substr(colon + 2),
                       ex.remote_message().empty() ? ex.what() : ex.remote_message());
  } catch (...) {
    return planet::describe(std::current_exception());
  }
}

void Behavior::trace_call(const std::string& op) {
  record("call", fmt::format("{} -> {}", path(), op), {{"call", op}});
}

void Behavior::trace_call_failure(const std::string& op, std::exception_ptr e) {
  const auto what = describe(e);
  record("call", fmt::format("{} -> {} failed: {}", path(), op, what),
         {{"call", op}, {"ok", false}, {"error", what}});
}

std::function<void(std::exception_ptr)> Behavior::failure_recorder(const std::string& op) const {
  if (!env_) return [](std::exception_ptr) {};
  return [trace = &env_->trace, runtime = &env_->runtime, source = path(), op](std::exception_ptr e) {
    const auto what = describe(e);
    TraceRecord r;
    r.time = runtime->now();
    r.kind = "call";
    r.source = source;
    r.text = fmt::format("{} -> {} failed: {}", source, op, what);
    r.fields = {{"call", op}, {"ok", false}, {"error", what}};
    trace->record(std::move(r));
  };
}

void Behavior::record(std::string kind, std::string text,
                      std::vector<std::pair<std::string, TraceValue>> fields) {
  if (!env_) return;
  TraceRecord r;
  r.time = env_->runtime.now();
  r.kind = std::move(kind);
  r.source = path();
  r.text = std::move(text);
  r.fields = std::move(fields);
  env_->trace.record(std::move(r));
}

}  // namespace icars::behavior
