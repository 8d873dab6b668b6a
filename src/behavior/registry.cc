#include "icars/behavior/registry.h"

#include <fmt/format.h>

#include <stdexcept>

#include "icars/behavior/composite.h"

namespace icars::behavior {

void BehaviorRegistry::add(std::string type, std::string doc, std::vector<ParamSpec> params,
                           Factory factory) {
  if (entries_.contains(type)) throw std::invalid_argument("behavior type " + type + " is already registered");
  Entry entry{type, std::move(doc), std::move(params), std::move(factory), std::nullopt};
  entries_.emplace(std::move(type), std::move(entry));
}

void BehaviorRegistry::merge(BehaviorRegistry&& other) {
  for (const auto& [type, entry] : other.entries_) {
    if (entries_.contains(type)) throw std::invalid_argument("behavior type " + type + " is already registered");
  }
  entries_.merge(other.entries_);
}

void BehaviorRegistry::declare_events(std::string_view type, std::vector<EventSpec> events) {
  auto it = entries_.find(type);
  if (it == entries_.end()) throw std::invalid_argument(fmt::format("behavior type {} is not registered", type));
  it->second.emits = std::move(events);
}

const BehaviorRegistry::Entry* BehaviorRegistry::find(std::string_view type) const {
  auto it = entries_.find(type);
  return it == entries_.end() ? nullptr : &it->second;
}

std::vector<std::string> BehaviorRegistry::types() const {
  std::vector<std::string> out;
  for (const auto& [type, entry] : entries_) out.push_back(type);
  return out;
}

Params BehaviorRegistry::check(std::string_view type,
                               const std::map<std::string, std::string, std::less<>>& given) const {
  const auto* entry = find(type);
  if (!entry) {
    throw ParamError(fmt::format("unknown behavior type '{}' (known: {})", type, fmt::join(types(), ", ")));
  }
  Params params;
  for (const auto& [name, value] : given) {
    const auto spec = std::find_if(entry->params.begin(), entry->params.end(),
                                   [&name = name](const ParamSpec& s) { return s.name == name; });
    if (spec == entry->params.end()) {
      std::vector<std::string> known;
      for (const auto& s : entry->params) known.push_back(s.name);
      throw ParamError(fmt::format("{} has no parameter '{}' (it has: {})", type, name,
                                   known.empty() ? std::string("none") : fmt::format("{}", fmt::join(known, ", "))));
    }
    try {
      check_param(name, spec->type, value);
      if (spec->check) spec->check(value);
    } catch (const ParamError& e) {
      throw ParamError(fmt::format("{}: {}", type, e.what()));
    }
    params.set(name, value);
  }
  for (const auto& spec : entry->params) {
    if (params.has(spec.name)) continue;
    if (!spec.default_value) {
      throw ParamError(fmt::format("{} needs parameter '{}' ({}: {})", type, spec.name, to_string(spec.type), spec.doc));
    }
    params.set(spec.name, *spec.default_value);
  }
  return params;
}

std::unique_ptr<Behavior> BehaviorRegistry::create(
    std::string_view type, std::string name,
    const std::map<std::string, std::string, std::less<>>& given) const {
  auto params = check(type, given);
  auto behavior = find(type)->factory(params);
  behavior->set_identity(std::string(type), std::move(name));
  behavior->set_params(std::move(params));
  return behavior;
}

namespace {

class Wait final : public WaitBehavior {
 public:
  explicit Wait(const Params& p) : WaitBehavior(p.duration("duration")) {}
};

class Emit final : public EmitBehavior {
 public:
  explicit Emit(const Params& p) : EmitBehavior(Event(p.string("event")), p.duration("delay")) {}
};

}  // namespace

void register_generic_behaviors(BehaviorRegistry& registry) {
  registry.add<Wait>("Wait", "waits for a duration of simulated time, then succeeds",
                     {param("duration", ParamType::duration, std::nullopt, "how long")});
  registry.add<Emit>("Emit", "propagates one event, then succeeds",
                     {param("event", ParamType::string, std::nullopt, "the event's type").naming("event"),
                      param("delay", ParamType::duration, "0s", "wait this long first")});
  registry.declare_events("Wait", {});
  registry.declare_events("Emit", {});  // the one of its parameter `event`, without properties
}

}  // namespace icars::behavior
