#include "house_validation.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>

#include "icars/sim/planner.h"

namespace icars::sim::detail {

std::string fmt_point(Point p) { return fmt::format("({:g}, {:g})", p.x, p.y); }

std::string join(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& item : items) {
    if (!out.empty()) out += ", ";
    out += item;
  }
  return out;
}

void house_error(std::string_view source, std::size_t line, const std::string& problem) {
  throw HouseError(std::string(source), line, problem);
}

namespace {

std::string resolve_room(House& house, const std::string& room, Point at, std::size_t at_line,
                         std::string_view what, std::string_view source) {
  if (!room.empty()) {
    const auto* r = house.room(room);
    if (!r) {
      std::vector<std::string> known;
      for (const auto& k : house.rooms) known.push_back(k.name);
      house_error(source, at_line,
           fmt::format("unknown room \"{}\" for {}, expected one of: {}", room, what, join(known)));
    }
    if (!r->area.contains(at)) {
      house_error(source, at_line,
           fmt::format("{} at {} is not inside its room \"{}\"", what, fmt_point(at), room));
    }
    return room;
  }
  const auto* r = house.room_at(at);
  if (!r) house_error(source, at_line, fmt::format("{} at {} is outside every room", what, fmt_point(at)));
  return r->name;
}

}  // namespace

void validate_house(House& house, const HouseLines& lines, std::string_view source) {
  const auto fail = [&](std::size_t line, const std::string& problem) { house_error(source, line, problem); };
  const auto resolve = [&](const std::string& room, Point at, std::size_t at_line, std::string_view what) {
    return resolve_room(house, room, at, at_line, what, source);
  };
  house.bounds = house.rooms.front().area;
  for (const auto& r : house.rooms) {
    house.bounds.min.x = std::min(house.bounds.min.x, r.area.min.x);
    house.bounds.min.y = std::min(house.bounds.min.y, r.area.min.y);
    house.bounds.max.x = std::max(house.bounds.max.x, r.area.max.x);
    house.bounds.max.y = std::max(house.bounds.max.y, r.area.max.y);
  }

  // Everything placed is inside a room (the named one, when named).
  for (std::size_t i = 0; i < house.furniture.size(); ++i) {
    auto& f = house.furniture[i];
    const auto what = fmt::format("furniture \"{}\"", f.name);
    f.room = resolve(f.room, f.area.center(), lines.furniture[i], what);
    const auto& room = house.room(f.room)->area;
    if (!room.contains(f.area.min) || !room.contains(f.area.max)) {
      fail(lines.furniture[i],
           fmt::format("{} from {} to {} does not fit inside room \"{}\"", what,
                       fmt_point(f.area.min), fmt_point(f.area.max), f.room));
    }
  }
  for (std::size_t i = 0; i < house.waypoints.size(); ++i) {
    auto& w = house.waypoints[i];
    w.room = resolve(w.room, w.at, lines.waypoints[i],
                          fmt::format("waypoint \"{}\"", w.name));
  }
  for (std::size_t i = 0; i < house.devices.size(); ++i) {
    auto& d = house.devices[i];
    if (!d.carrier.empty()) continue;
    d.room = resolve(d.room, d.pose.position(), lines.devices[i],
                          fmt::format("device \"{}\"", d.id));
  }
  for (std::size_t i = 0; i < house.robots.size(); ++i) {
    const auto& r = house.robots[i];
    resolve("", r.start.position(), lines.robots[i],
                 fmt::format("the start of robot \"{}\"", r.id));
  }
  for (std::size_t i = 0; i < house.users.size(); ++i) {
    const auto& u = house.users[i];
    resolve("", u.start, lines.users[i],
                 fmt::format("the start of user \"{}\"", u.id));
  }

  // Free space: robots and users start free; spots beside furniture and room anchors are
  // computed for the widest body so that everyone fits there.
  double widest = 0.0;
  for (const auto& r : house.robots) widest = std::max(widest, r.radius);
  for (const auto& u : house.users) widest = std::max(widest, u.radius);
  if (widest == 0.0) widest = 0.25;
  std::map<double, OccupancyGrid> grids;
  const auto grid_for = [&](double radius) -> const OccupancyGrid& {
    auto it = grids.find(radius);
    if (it == grids.end()) it = grids.emplace(radius, OccupancyGrid(house, radius)).first;
    return it->second;
  };
  for (std::size_t i = 0; i < house.robots.size(); ++i) {
    const auto& r = house.robots[i];
    if (!grid_for(r.radius).free(r.start.position())) {
      fail(lines.robots[i], fmt::format("robot \"{}\" starts at {}, too close to a wall or "
                                         "furniture for its radius {:g} m, expected a free spot",
                                         r.id, fmt_point(r.start.position()), r.radius));
    }
  }
  for (std::size_t i = 0; i < house.users.size(); ++i) {
    const auto& u = house.users[i];
    if (!grid_for(u.radius).free(u.start)) {
      fail(lines.users[i], fmt::format("user \"{}\" starts at {}, too close to a wall or "
                                        "furniture for radius {:g} m, expected a free spot",
                                        u.id, fmt_point(u.start), u.radius));
    }
  }

  const auto& wide = grid_for(widest);
  std::optional<Point> home;  // the free space everything must be reachable from
  if (!house.robots.empty()) {
    home = house.robots.front().start.position();
  } else if (!house.users.empty()) {
    home = house.users.front().start;
  }
  // A spot is usable when free and reachable; when nothing reachable exists, a free spot is
  // still chosen so that the error reported later is "unreachable", not "no spot".
  const auto free_in = [&](Point p, const Room& room) {
    return room.area.contains(p) && wide.free(p);
  };
  const auto usable = [&](Point p, const Room& room) {
    return free_in(p, room) && (!home || wide.connected(*home, p));
  };
  for (auto& room : house.rooms) {
    const auto c = room.area.center();
    const double reach = std::max(room.area.width(), room.area.height());
    if (usable(c, room)) {
      room.anchor = c;
    } else if (auto p = wide.nearest_free(c, reach, home); p && room.area.contains(*p)) {
      room.anchor = p;
    } else if (auto q = wide.nearest_free(c, reach); q && room.area.contains(*q)) {
      room.anchor = q;
    }
  }
  for (std::size_t i = 0; i < house.furniture.size(); ++i) {
    auto& f = house.furniture[i];
    const auto& room = *house.room(f.room);
    if (f.approach) {
      if (!usable(*f.approach, room)) {
        fail(lines.furniture[i],
             fmt::format("the approach spot {} of furniture \"{}\" is not a free, reachable spot "
                         "in room \"{}\" (clearance {:g} m), expected one beside the furniture",
                         fmt_point(*f.approach), f.name, f.room, widest));
      }
      continue;
    }
    if (!f.blocks) {
      f.approach = f.area.center();
      continue;
    }
    // The nearest free spot straight out from the middle of a side; long sides first (one sits
    // on a sofa's long side, gets into bed from its side), then a quarter along each side.
    struct Side {
      Point mid;
      Point normal;
      double along_x, along_y, length;
    };
    const auto& a = f.area;
    std::vector<Side> sides = {
        {{a.center().x, a.min.y}, {0, -1}, 1, 0, a.width()},
        {{a.center().x, a.max.y}, {0, 1}, 1, 0, a.width()},
        {{a.min.x, a.center().y}, {-1, 0}, 0, 1, a.height()},
        {{a.max.x, a.center().y}, {1, 0}, 0, 1, a.height()},
    };
    std::stable_sort(sides.begin(), sides.end(),
                     [](const Side& s, const Side& t) { return s.length > t.length + kEpsilon; });
    const double step = house.resolution / 2;
    const auto search = [&](const auto& ok) -> std::optional<Point> {
      for (const double shift : {0.0, -0.25, 0.25}) {
        std::optional<std::pair<double, Point>> best;
        for (const auto& s : sides) {
          const Point base{s.mid.x + s.along_x * shift * s.length,
                           s.mid.y + s.along_y * shift * s.length};
          for (double d = widest; d <= widest + 1.0; d += step) {
            const Point p{base.x + s.normal.x * d, base.y + s.normal.y * d};
            if (ok(p, room)) {
              if (!best || d < best->first - kEpsilon) best = std::pair{d, p};
              break;
            }
          }
        }
        if (best) return best->second;
      }
      return std::nullopt;
    };
    f.approach = search(usable);
    if (!f.approach) f.approach = search(free_in);
  }

  // Waypoints: every robot can reach every waypoint.
  for (std::size_t i = 0; i < house.waypoints.size(); ++i) {
    const auto& w = house.waypoints[i];
    for (const auto& r : house.robots) {
      const auto& grid = grid_for(r.radius);
      if (!grid.free(w.at)) {
        fail(lines.waypoints[i], fmt::format("waypoint \"{}\" at {} is too close to a wall or "
                                              "furniture for robot \"{}\" (radius {:g} m), "
                                              "expected a free spot",
                                              w.name, fmt_point(w.at), r.id, r.radius));
      }
      if (!grid.connected(r.start.position(), w.at)) {
        fail(lines.waypoints[i],
             fmt::format("waypoint \"{}\" at {} is unreachable for robot "
                         "\"{}\" from its start {}, expected a spot joined "
                         "to it by a free path (check doors)",
                         w.name, fmt_point(w.at), r.id, fmt_point(r.start.position())));
      }
    }
  }

  // Schedules: targets known, of the right kind, and reachable from the user's start.
  for (std::size_t i = 0; i < house.users.size(); ++i) {
    const auto& u = house.users[i];
    const auto& grid = grid_for(u.radius);
    for (std::size_t k = 0; k < u.schedule.size(); ++k) {
      const auto& e = u.schedule[k];
      const auto at_line = lines.entries[i][k];
      if (e.activity == Activity::stand || e.activity == Activity::say) continue;
      const auto* f = house.find_furniture(e.target);
      if (e.activity == Activity::sit || e.activity == Activity::lie) {
        if (!f) {
          fail(at_line, fmt::format("unknown target \"{}\" for <{}> of user \"{}\", expected a "
                                    "piece of furniture",
                                    e.target, to_string(e.activity), u.id));
        }
      } else if (!f && !house.waypoint(e.target) && !house.room(e.target)) {
        fail(at_line, fmt::format("unknown target \"{}\" for <go_to> of user \"{}\", expected a "
                                  "waypoint, a piece of furniture or a room",
                                  e.target, u.id));
      }
      const auto spot = house.locate(e.target);
      if (!spot) {
        fail(at_line, fmt::format("no free spot to stand beside \"{}\" for <{}> of user \"{}\"; "
                                  "give the furniture approach_x and approach_y",
                                  e.target, to_string(e.activity), u.id));
      }
      if (!grid.connected(u.start, *spot)) {
        fail(at_line, fmt::format("target \"{}\" at {} of <{}> is unreachable for user \"{}\" "
                                  "from the start {}, expected a spot joined to it by a free path",
                                  e.target, fmt_point(*spot), to_string(e.activity), u.id,
                                  fmt_point(u.start)));
      }
    }
  }
}

}  // namespace icars::sim::detail
