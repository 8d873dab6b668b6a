#include "icars/home/sim/house_vocabulary.h"

#include "icars/home/sim/sim_devices.h"

namespace icars::home {

behavior::Vocabulary house_vocabulary(const sim::House& house) {
  behavior::Vocabulary v;
  v.source = house.source;
  auto& names = v.names;
  for (const auto& r : house.rooms) names["room"].insert(r.name);
  for (const auto& w : house.waypoints) names["waypoint"].insert(w.name);
  for (const auto& f : house.furniture) names["furniture"].insert(f.name);
  for (const auto& d : house.devices) names["device"].insert(d.id);
  for (const auto id : {kSpeechEngineId, kVisionEngineId, kSimulatorId}) names["device"].insert(std::string(id));
  for (const auto& u : house.users) names["user"].insert(u.id);
  for (const auto& r : house.robots) names["robot"].insert(r.id);
  // robot="any": the robot market chooses (docs/distribution.md, "Robots").
  if (!house.robots.empty()) names["robot"].insert("any");
  // Every kind is listed, also when the house has none of it: a name of it is then wrong.
  for (const char* kind : {"room", "waypoint", "furniture", "device", "user", "robot"}) names[kind];
  auto& place = names["place"];
  for (const char* kind : {"waypoint", "furniture", "room"}) place.insert(names[kind].begin(), names[kind].end());
  // The properties of the home's events that hold such names (idl/home.idl, home/services.h).
  v.property_kinds = {{"room", "room"},     {"furniture", "furniture"}, {"device", "device"},
                      {"robot", "robot"},   {"user", "user"},           {"person", "user"},
                      {"waypoint", "waypoint"}};
  return v;
}

}  // namespace icars::home
