// What a policy's behaviors can refer to, for checking a policy before it runs (as
// BehaviorTree.CPP checks ports): the events behaviors propagate, with their properties, and the
// names of a world — rooms, waypoints, furniture, devices, users, robots — by kind. Behavior
// types declare what they propagate (BehaviorRegistry::declare_events) and which parameters name
// something of the world (ParamSpec::names); a world (a house) fills a Vocabulary.
#pragma once

#include <map>
#include <set>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include "icars/planet/event.h"

namespace icars::behavior {

// An event a behavior may propagate: its type (without namespace, as conditions see it) and
// the properties it carries.
struct EventSpec {
  std::string type;
  std::vector<std::string> properties;
};

// The EventSpec of a typed event (planet-idl's `event`, or PLANET_EVENT).
template <planet::TypedEvent T>
EventSpec event_spec() {
  std::string_view type = planet::TypeName<T>::value;
  if (const auto colon = type.rfind("::"); colon != std::string_view::npos) type.remove_prefix(colon + 2);
  EventSpec spec{std::string(type), {}};
  std::apply([&](const auto&... field) { (spec.properties.emplace_back(field.name), ...); },
             planet::EventFields<T>::value);
  return spec;
}

struct Vocabulary {
  std::string source;  // where the names come from (a house file), for messages
  // kind ("room", "waypoint", "place", ...) -> the names of that kind. A kind absent here is
  // not checked (a policy validated without a world).
  std::map<std::string, std::set<std::string>, std::less<>> names;
  // event property -> the kind of name its value is ("furniture" -> "furniture"): a condition
  // comparing the property with a string compares it with such a name.
  std::map<std::string, std::string, std::less<>> property_kinds;
};

}  // namespace icars::behavior
