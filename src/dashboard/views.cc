#include "icars/dashboard/views.h"

#include <functional>

namespace icars::dashboard {

using nlohmann::json;

namespace {

json rect(const sim::Rect& r) { return {{"x0", r.min.x}, {"y0", r.min.y}, {"x1", r.max.x}, {"y1", r.max.y}}; }
json segment(sim::Point a, sim::Point b) { return {{"x0", a.x}, {"y0", a.y}, {"x1", b.x}, {"y1", b.y}}; }

std::string_view kind_name(control::StateSpec::Kind k) {
  switch (k) {
    case control::StateSpec::Kind::state:
      return "state";
    case control::StateSpec::Kind::parallel:
      return "parallel";
    case control::StateSpec::Kind::region:
      return "region";
    case control::StateSpec::Kind::final:
      return "final";
  }
  return "state";
}

json state_view(const control::StateSpec& s, const std::string& fallback_name) {
  json transitions = json::array();
  for (const auto& t : s.transitions) {
    transitions.push_back({{"event", t.event},
                           {"target", t.target},
                           {"after_ms", t.after ? json(t.after->count()) : json(nullptr)},
                           {"line", t.line}});
  }
  json children = json::array();
  for (const auto& c : s.children) children.push_back(state_view(c, c.name));
  return {{"name", s.name.empty() ? fallback_name : s.name},
          {"kind", kind_name(s.kind)},
          {"task", s.task},
          {"children", std::move(children)},
          {"transitions", std::move(transitions)},
          {"line", s.line}};
}

json node_view(const control::NodeSpec& n) {
  json children = json::array();
  for (const auto& c : n.children) children.push_back(node_view(c));
  json params = json::object();
  for (const auto& [k, v] : n.params) params[k] = v;
  return {{"name", n.name}, {"type", n.type}, {"params", std::move(params)}, {"children", std::move(children)},
          {"line", n.line}};
}

}  // namespace

json house_view(const sim::House& house) {
  json rooms = json::array(), walls = json::array(), doors = json::array(), furniture = json::array(),
       waypoints = json::array(), devices = json::array(), robots = json::array(), users = json::array();
  for (const auto& r : house.rooms) {
    auto j = rect(r.area);
    j["name"] = r.name;
    rooms.push_back(std::move(j));
  }
  for (const auto& w : house.walls) walls.push_back(segment(w.a, w.b));
  for (const auto& d : house.doors) {
    auto j = segment(d.a, d.b);
    j["name"] = d.name;
    doors.push_back(std::move(j));
  }
  for (const auto& f : house.furniture) {
    auto j = rect(f.area);
    j["name"] = f.name;
    j["kind"] = f.kind;
    j["room"] = f.room;
    j["blocks"] = f.blocks;
    furniture.push_back(std::move(j));
  }
  for (const auto& w : house.waypoints) {
    waypoints.push_back({{"name", w.name}, {"room", w.room}, {"x", w.at.x}, {"y", w.at.y}, {"tags", w.tags}});
  }
  for (const auto& d : house.devices) {
    devices.push_back({{"id", d.id}, {"type", d.type}, {"room", d.room}, {"x", d.pose.x}, {"y", d.pose.y},
                       {"carrier", d.carrier}, {"mqtt", !d.mqtt.empty()}});
  }
  for (const auto& r : house.robots) {
    robots.push_back({{"id", r.id}, {"x", r.start.x}, {"y", r.start.y}, {"theta", r.start.theta},
                      {"radius", r.radius}});
  }
  for (const auto& u : house.users) {
    users.push_back({{"id", u.id}, {"x", u.start.x}, {"y", u.start.y}, {"radius", u.radius}});
  }
  return {{"name", house.name},   {"bounds", rect(house.bounds)}, {"rooms", rooms},
          {"walls", walls},       {"doors", doors},               {"furniture", furniture},
          {"waypoints", waypoints}, {"devices", devices},         {"robots", robots},
          {"users", users},       {"start_ms", house.start_time.count()}};
}

json policy_view(const control::Policy& policy) {
  json tasks = json::object();
  for (const auto& t : policy.tasks) tasks[t.name] = node_view(t.root);
  return {{"name", policy.name},
          {"file", policy.file},
          {"description", policy.description},
          {"statechart", state_view(policy.root, policy.name)},
          {"tasks", std::move(tasks)}};
}

}  // namespace icars::dashboard
