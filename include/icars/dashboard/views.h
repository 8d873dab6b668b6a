// What the dashboard draws, as the JSON its page reads (docs/dashboard.md, "API"): a house's
// plan and a policy's statechart with its tasks' behavior trees.
#pragma once

#include <nlohmann/json.hpp>

#include "icars/control/policy.h"
#include "icars/sim/house.h"

namespace icars::dashboard {

// Rooms, walls, doors, furniture, waypoints, devices (with their carrier), robots and users at
// their start, and the bounds, in metres.
nlohmann::json house_view(const sim::House& house);

// {"name", "statechart": the state tree (name, kind, task, children, transitions), "tasks": each
// task's behavior tree (name, type, children)}.
nlohmann::json policy_view(const control::Policy& policy);

}  // namespace icars::dashboard
