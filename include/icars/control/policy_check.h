// Checking a policy against what it will run with: the events its behaviors declare they
// propagate and the names of the world it runs in (a house's rooms, waypoints, furniture, ...).
//
// The Policy Parser checks what a policy file says by itself; check_policy goes on where a
// mistake would otherwise be found only while running, or never: a parameter naming a room,
// waypoint or device the world does not have, a condition reading a property that no event
// reaching it carries (`furnture == 'bed'`, never true), comparing `event` with an event type
// that cannot reach it, or comparing a property that holds a name (`furniture`, `room`) with a
// name the world does not have. Each problem is a Diagnostic at the node's line.
#pragma once

#include <vector>

#include "icars/behavior/registry.h"
#include "icars/behavior/vocabulary.h"
#include "icars/control/policy.h"

namespace icars::control {

// Every problem found (errors); empty when the policy fits. A kind of name the vocabulary does
// not list is not checked, so an empty vocabulary checks only the events.
std::vector<Diagnostic> check_policy(const Policy& policy, const behavior::BehaviorRegistry& registry,
                                     const behavior::Vocabulary& world);

}  // namespace icars::control
