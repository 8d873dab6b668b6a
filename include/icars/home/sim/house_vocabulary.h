// The names a policy may use in a house, for checking it before it runs (icars validate
// --world, icars run): rooms, waypoints, furniture, devices, users and robots, and which event
// properties hold such names.
#pragma once

#include "icars/behavior/vocabulary.h"
#include "icars/sim/house.h"

namespace icars::home {

// Kinds: "room", "waypoint", "furniture", "device", "user", "robot", and "place" (where a robot
// can be sent: a waypoint, furniture or room). The source is house.source.
behavior::Vocabulary house_vocabulary(const sim::House& house);

}  // namespace icars::home
