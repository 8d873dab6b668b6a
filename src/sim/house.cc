#include "icars/sim/house.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>

namespace icars::sim {

double distance(Point a, Point b) { return std::hypot(a.x - b.x, a.y - b.y); }

bool Rect::contains(Point p) const {
  return p.x >= min.x && p.x <= max.x && p.y >= min.y && p.y <= max.y;
}

Point Rect::center() const { return {(min.x + max.x) / 2, (min.y + max.y) / 2}; }

std::string_view to_string(Activity activity) {
  switch (activity) {
    case Activity::go_to:
      return "go_to";
    case Activity::sit:
      return "sit";
    case Activity::lie:
      return "lie";
    case Activity::stand:
      return "stand";
    case Activity::say:
      return "say";
  }
  return "?";
}

// --- lookups ---------------------------------------------------------------------------------

namespace {
template <typename T, typename Key>
const T* find_by(const std::vector<T>& items, std::string_view name, Key key) {
  for (const auto& item : items) {
    if (item.*key == name) return &item;
  }
  return nullptr;
}
}  // namespace

const Room* House::room(std::string_view n) const { return find_by(rooms, n, &Room::name); }

const Room* House::room_at(Point p) const {
  for (const auto& r : rooms) {
    if (r.area.contains(p)) return &r;
  }
  return nullptr;
}

const Waypoint* House::waypoint(std::string_view n) const {
  return find_by(waypoints, n, &Waypoint::name);
}

std::vector<const Waypoint*> House::waypoints_tagged(std::string_view tag) const {
  std::vector<const Waypoint*> out;
  for (const auto& w : waypoints) {
    if (std::find(w.tags.begin(), w.tags.end(), tag) != w.tags.end()) out.push_back(&w);
  }
  return out;
}

const Furniture* House::find_furniture(std::string_view n) const {
  return find_by(furniture, n, &Furniture::name);
}

const DeviceSpec* House::device(std::string_view id) const {
  return find_by(devices, id, &DeviceSpec::id);
}

const RobotSpec* House::robot(std::string_view id) const {
  return find_by(robots, id, &RobotSpec::id);
}

const UserSpec* House::user(std::string_view id) const { return find_by(users, id, &UserSpec::id); }

std::optional<Point> House::locate(std::string_view target) const {
  if (const auto* w = waypoint(target)) return w->at;
  if (const auto* f = find_furniture(target)) {
    if (f->approach) return f->approach;
    if (!f->blocks) return f->area.center();
    return std::nullopt;
  }
  if (const auto* r = room(target)) return r->anchor.value_or(r->area.center());
  return std::nullopt;
}

// --- errors ----------------------------------------------------------------------------------

namespace {
std::string error_text(const std::string& source, std::size_t line, std::size_t column,
                       const std::string& problem) {
  if (line == 0) return fmt::format("{}: {}", source, problem);
  if (column == 0) return fmt::format("{}:{}: {}", source, line, problem);
  return fmt::format("{}:{}:{}: {}", source, line, column, problem);
}
}  // namespace

HouseError::HouseError(std::string source, std::size_t line, const std::string& problem)
    : HouseError(std::move(source), line, 0, problem) {}

HouseError::HouseError(std::string source, std::size_t line, std::size_t column, const std::string& problem)
    : std::runtime_error(error_text(source, line, column, problem)),
      source_(std::move(source)),
      line_(line),
      column_(column),
      problem_(problem) {}

}  // namespace icars::sim
