#include "icars/sim/house.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <fstream>
#include <numbers>
#include <pugixml.hpp>
#include <set>
#include <sstream>

#include "icars/sim/planner.h"

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
std::string error_text(const std::string& source, std::size_t line, const std::string& problem) {
  if (line == 0) return fmt::format("{}: {}", source, problem);
  return fmt::format("{}:{}: {}", source, line, problem);
}
}  // namespace

HouseError::HouseError(std::string source, std::size_t line, const std::string& problem)
    : std::runtime_error(error_text(source, line, problem)),
      source_(std::move(source)),
      line_(line),
      problem_(problem) {}

// --- parsing ---------------------------------------------------------------------------------

namespace {

constexpr double kEpsilon = 1e-6;

std::string join(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& item : items) {
    if (!out.empty()) out += ", ";
    out += item;
  }
  return out;
}

std::string fmt_point(Point p) { return fmt::format("({:g}, {:g})", p.x, p.y); }

// Everything parsed, plus the line each item came from (for validation errors).
struct Lines {
  std::size_t house = 0;
  std::vector<std::size_t> rooms, doors, furniture, waypoints, devices, robots, users;
  std::vector<std::vector<std::size_t>> entries;  // per user
};

class Parser {
 public:
  Parser(std::string_view xml, std::string_view source) : xml_(xml), source_(source) {
    line_starts_.push_back(0);
    for (std::size_t i = 0; i < xml.size(); ++i) {
      if (xml[i] == '\n') line_starts_.push_back(i + 1);
    }
  }

  House parse();

 private:
  [[noreturn]] void fail(std::size_t line, const std::string& problem) const {
    throw HouseError(std::string(source_), line, problem);
  }
  std::size_t line_at(std::ptrdiff_t offset) const {
    if (offset < 0) return 1;
    const auto it = std::upper_bound(line_starts_.begin(), line_starts_.end(),
                                     static_cast<std::size_t>(offset));
    return static_cast<std::size_t>(it - line_starts_.begin());
  }
  std::size_t line(pugi::xml_node n) const { return line_at(n.offset_debug()); }

  // "<device id="tv">" — how errors name an element.
  static std::string describe(pugi::xml_node n) {
    for (const char* key : {"id", "name"}) {
      if (auto a = n.attribute(key)) return fmt::format("<{} {}=\"{}\">", n.name(), key, a.value());
    }
    return fmt::format("<{}>", n.name());
  }

  void check_attributes(pugi::xml_node n, const std::vector<std::string>& allowed) const {
    for (auto a : n.attributes()) {
      if (std::find(allowed.begin(), allowed.end(), a.name()) == allowed.end()) {
        fail(line(n), fmt::format("unknown attribute \"{}\" on {}, expected one of: {}", a.name(),
                                  describe(n), join(allowed)));
      }
    }
  }

  void check_children(pugi::xml_node n, const std::vector<std::string>& allowed) const {
    for (auto c : n.children()) {
      if (c.type() == pugi::node_pcdata || c.type() == pugi::node_cdata) {
        fail(
            line(c),
            fmt::format("unexpected text \"{}\" in {}, expected {}", c.value(), describe(n),
                        allowed.empty() ? std::string("no content") : "elements " + join(allowed)));
      }
      if (c.type() != pugi::node_element) continue;
      if (std::find(allowed.begin(), allowed.end(), c.name()) == allowed.end()) {
        fail(line(c), fmt::format("unknown element <{}> in {}, expected {}", c.name(), describe(n),
                                  allowed.empty() ? std::string("no child elements")
                                                  : "one of: " + join(allowed)));
      }
    }
  }

  std::string required(pugi::xml_node n, const char* key, std::string_view expected) const {
    const auto a = n.attribute(key);
    if (!a) {
      fail(line(n), fmt::format("{} is missing attribute \"{}\" ({})", describe(n), key, expected));
    }
    return a.value();
  }

  // Names become device ids and PLANET paths: keep them simple.
  std::string name(pugi::xml_node n, const char* key) const {
    auto value = required(n, key, "a name of letters, digits, '_', '-' or '.'");
    const bool ok = !value.empty() && std::all_of(value.begin(), value.end(), [](char c) {
      return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_' || c == '-' || c == '.';
    });
    if (!ok) {
      fail(line(n), fmt::format("{}=\"{}\" of <{}> is not a valid name, expected letters, digits, "
                                "'_', '-' or '.'",
                                key, value, n.name()));
    }
    return value;
  }

  double number(pugi::xml_node n, const char* key, std::optional<double> fallback,
                std::string_view unit) const {
    const auto a = n.attribute(key);
    if (!a) {
      if (fallback) return *fallback;
      fail(line(n),
           fmt::format("{} is missing attribute \"{}\" (a number in {})", describe(n), key, unit));
    }
    const std::string_view text = a.value();
    double value = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
    if (text.empty() || ec != std::errc{} || end != text.data() + text.size() ||
        !std::isfinite(value)) {
      fail(line(n), fmt::format("{}=\"{}\" of {} is not a number, expected a number in {}", key,
                                text, describe(n), unit));
    }
    return value;
  }

  double positive(pugi::xml_node n, const char* key, double fallback, std::string_view unit) const {
    const double value = number(n, key, fallback, unit);
    if (!(value > 0)) {
      fail(line(n), fmt::format("{}=\"{}\" of {} must be greater than 0 ({})", key,
                                n.attribute(key).value(), describe(n), unit));
    }
    return value;
  }

  double non_negative(pugi::xml_node n, const char* key, double fallback,
                      std::string_view unit) const {
    const double value = number(n, key, fallback, unit);
    if (value < 0) {
      fail(line(n), fmt::format("{}=\"{}\" of {} must not be negative ({})", key,
                                n.attribute(key).value(), describe(n), unit));
    }
    return value;
  }

  bool boolean(pugi::xml_node n, const char* key, bool fallback) const {
    const auto a = n.attribute(key);
    if (!a) return fallback;
    const std::string_view v = a.value();
    if (v == "true") return true;
    if (v == "false") return false;
    fail(line(n), fmt::format("{}=\"{}\" of {} is not a boolean, expected true or false", key, v,
                              describe(n)));
  }

  Time time_of_day(pugi::xml_node n, const char* key, std::optional<Time> fallback) const {
    const auto a = n.attribute(key);
    if (!a) {
      if (fallback) return *fallback;
      fail(line(n), fmt::format("{} is missing attribute \"{}\" (a time of day HH:MM or HH:MM:SS)",
                                describe(n), key));
    }
    const auto t = parse_time_of_day(a.value());
    if (!t) {
      fail(line(n),
           fmt::format("bad time \"{}\" in attribute \"{}\" of {}, expected HH:MM or HH:MM:SS "
                       "between 00:00 and 23:59:59",
                       a.value(), key, describe(n)));
    }
    return *t;
  }

  Rect rect(pugi::xml_node n) const {
    Rect r{{number(n, "x0", std::nullopt, "metres"), number(n, "y0", std::nullopt, "metres")},
           {number(n, "x1", std::nullopt, "metres"), number(n, "y1", std::nullopt, "metres")}};
    if (!(r.max.x > r.min.x) || !(r.max.y > r.min.y)) {
      fail(line(n), fmt::format("{} has an empty area {}-{}, expected x1 > x0 and y1 > y0",
                                describe(n), fmt_point(r.min), fmt_point(r.max)));
    }
    return r;
  }

  Point point(pugi::xml_node n) const {
    return {number(n, "x", std::nullopt, "metres"), number(n, "y", std::nullopt, "metres")};
  }

  double heading(pugi::xml_node n) const {
    return number(n, "heading", 0.0, "degrees") * std::numbers::pi / 180.0;
  }

  void claim(const std::string& name, std::string_view what, std::size_t at) {
    const auto [it, inserted] = names_.try_emplace(name, std::string(what), at);
    if (!inserted) {
      fail(at, fmt::format("duplicate name \"{}\", already used by the {} at line {}; names must "
                           "be unique across rooms, doors, furniture, waypoints, devices, robots "
                           "and users",
                           name, it->second.first, it->second.second));
    }
  }

  std::map<std::string, std::string> params(pugi::xml_node device) const {
    std::map<std::string, std::string> out;
    for (auto p : device.children("param")) {
      check_attributes(p, {"name", "value"});
      check_children(p, {});
      auto key = name(p, "name");
      auto value = required(p, "value", "any text");
      if (!out.emplace(key, value).second) {
        fail(line(p), fmt::format("duplicate parameter \"{}\" in {}", key, describe(device)));
      }
    }
    return out;
  }

  void parse_room(pugi::xml_node n, House& house);
  void parse_furniture(pugi::xml_node n, House& house);
  void parse_device(pugi::xml_node n, House& house);
  void parse_robot(pugi::xml_node n, House& house);
  void parse_user(pugi::xml_node n, House& house);
  void build_walls(House& house, const std::vector<Wall>& outline);
  void validate(House& house);
  std::string resolve_room(House& house, const std::string& room, Point at, std::size_t at_line,
                           std::string_view what);

  std::string_view xml_;
  std::string_view source_;
  std::vector<std::size_t> line_starts_;
  std::map<std::string, std::pair<std::string, std::size_t>> names_;  // name -> (what, line)
  Lines lines_;
};

House Parser::parse() {
  pugi::xml_document doc;
  const auto result =
      doc.load_buffer(xml_.data(), xml_.size(), pugi::parse_default, pugi::encoding_utf8);
  if (!result) {
    fail(line_at(result.offset),
         fmt::format("malformed XML: {}, expected a well-formed <house> document",
                     result.description()));
  }
  const auto root = doc.document_element();
  if (!root) fail(1, "empty document, expected a <house> element");
  if (std::string_view(root.name()) != "house") {
    fail(line(root), fmt::format("the root element is <{}>, expected <house>", root.name()));
  }
  check_attributes(root, {"name", "start", "seed", "resolution"});
  check_children(root,
                 {"room", "door", "wall", "furniture", "waypoint", "device", "robot", "user"});

  House house;
  lines_.house = line(root);
  house.name = name(root, "name");
  house.start_time = time_of_day(root, "start", Time{0});
  if (auto seed = root.attribute("seed")) {
    const std::string_view text = seed.value();
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), house.seed);
    if (text.empty() || ec != std::errc{} || end != text.data() + text.size()) {
      fail(line(root), fmt::format("seed=\"{}\" of <house> is not a number, expected an "
                                   "unsigned integer",
                                   text));
    }
  }
  house.resolution = number(root, "resolution", 0.05, "metres");
  if (house.resolution < 0.01 || house.resolution > 0.5) {
    fail(line(root), fmt::format("resolution=\"{}\" of <house> is out of range, expected 0.01 to "
                                 "0.5 metres",
                                 root.attribute("resolution").value()));
  }

  std::vector<Wall> walls;
  for (auto n : root.children()) {
    if (n.type() != pugi::node_element) continue;
    const std::string_view kind = n.name();
    if (kind == "room") {
      parse_room(n, house);
      if (boolean(n, "walls", true)) {
        const auto& a = house.rooms.back().area;
        walls.push_back({{a.min.x, a.min.y}, {a.max.x, a.min.y}});
        walls.push_back({{a.max.x, a.min.y}, {a.max.x, a.max.y}});
        walls.push_back({{a.max.x, a.max.y}, {a.min.x, a.max.y}});
        walls.push_back({{a.min.x, a.max.y}, {a.min.x, a.min.y}});
      }
    } else if (kind == "door") {
      check_attributes(n, {"name", "x0", "y0", "x1", "y1"});
      check_children(n, {});
      auto door_name = name(n, "name");
      claim(door_name, "door", line(n));
      Door door{door_name,
                {number(n, "x0", std::nullopt, "metres"), number(n, "y0", std::nullopt, "metres")},
                {number(n, "x1", std::nullopt, "metres"), number(n, "y1", std::nullopt, "metres")}};
      if (distance(door.a, door.b) < kEpsilon) {
        fail(line(n),
             fmt::format("{} has zero width, expected two different end points", describe(n)));
      }
      house.doors.push_back(door);
      lines_.doors.push_back(line(n));
    } else if (kind == "wall") {
      check_attributes(n, {"x0", "y0", "x1", "y1"});
      check_children(n, {});
      Wall wall{{number(n, "x0", std::nullopt, "metres"), number(n, "y0", std::nullopt, "metres")},
                {number(n, "x1", std::nullopt, "metres"), number(n, "y1", std::nullopt, "metres")}};
      if (distance(wall.a, wall.b) < kEpsilon) {
        fail(line(n), "<wall> has zero length, expected two different end points");
      }
      walls.push_back(wall);
    } else if (kind == "furniture") {
      parse_furniture(n, house);
    } else if (kind == "waypoint") {
      check_attributes(n, {"name", "room", "x", "y", "tags"});
      check_children(n, {});
      Waypoint w;
      w.name = name(n, "name");
      claim(w.name, "waypoint", line(n));
      w.room = n.attribute("room").value();
      w.at = point(n);
      std::istringstream tags(n.attribute("tags").value());
      for (std::string tag; tags >> tag;) w.tags.push_back(tag);
      house.waypoints.push_back(std::move(w));
      lines_.waypoints.push_back(line(n));
    } else if (kind == "device") {
      parse_device(n, house);
    } else if (kind == "robot") {
      parse_robot(n, house);
    } else if (kind == "user") {
      parse_user(n, house);
    }
  }
  if (house.rooms.empty()) fail(line(root), "the house has no <room>, expected at least one");
  build_walls(house, walls);
  validate(house);
  return house;
}

void Parser::parse_room(pugi::xml_node n, House& house) {
  check_attributes(n, {"name", "x0", "y0", "x1", "y1", "walls"});
  check_children(n, {});
  Room room{name(n, "name"), rect(n), std::nullopt};
  claim(room.name, "room", line(n));
  for (std::size_t i = 0; i < house.rooms.size(); ++i) {
    const auto& o = house.rooms[i].area;
    const auto& a = room.area;
    if (a.min.x < o.max.x - kEpsilon && o.min.x < a.max.x - kEpsilon &&
        a.min.y < o.max.y - kEpsilon && o.min.y < a.max.y - kEpsilon) {
      fail(line(n), fmt::format("room \"{}\" overlaps room \"{}\" (line {}), expected rooms that "
                                "at most share a side",
                                room.name, house.rooms[i].name, lines_.rooms[i]));
    }
  }
  house.rooms.push_back(std::move(room));
  lines_.rooms.push_back(line(n));
}

void Parser::parse_furniture(pugi::xml_node n, House& house) {
  check_attributes(
      n, {"name", "kind", "room", "x0", "y0", "x1", "y1", "blocks", "approach_x", "approach_y"});
  check_children(n, {});
  Furniture f;
  f.name = name(n, "name");
  claim(f.name, "furniture", line(n));
  f.kind = required(n, "kind", "what it is: sofa, bed, table, tv_stand, ...");
  if (f.kind.empty()) fail(line(n), fmt::format("{} has an empty kind", describe(n)));
  f.room = n.attribute("room").value();
  f.area = rect(n);
  f.blocks = boolean(n, "blocks", true);
  const bool ax = !n.attribute("approach_x").empty();
  const bool ay = !n.attribute("approach_y").empty();
  if (ax != ay) {
    fail(line(n), fmt::format("{} gives only one of approach_x and approach_y, expected both or "
                              "neither",
                              describe(n)));
  }
  if (ax) {
    f.approach = Point{number(n, "approach_x", std::nullopt, "metres"),
                       number(n, "approach_y", std::nullopt, "metres")};
  }
  house.furniture.push_back(std::move(f));
  lines_.furniture.push_back(line(n));
}

void Parser::parse_device(pugi::xml_node n, House& house) {
  check_attributes(n, {"id", "type", "room", "x", "y", "heading"});
  check_children(n, {"param"});
  DeviceSpec d;
  d.id = name(n, "id");
  claim(d.id, "device", line(n));
  d.type = name(n, "type");
  d.room = n.attribute("room").value();
  const auto at = point(n);
  d.pose = Pose{at.x, at.y, heading(n)};
  d.params = params(n);
  house.devices.push_back(std::move(d));
  lines_.devices.push_back(line(n));
}

void Parser::parse_robot(pugi::xml_node n, House& house) {
  check_attributes(n, {"id", "x", "y", "heading", "speed", "radius"});
  check_children(n, {"device"});
  RobotSpec r;
  r.id = name(n, "id");
  claim(r.id, "robot", line(n));
  const auto at = point(n);
  r.start = Pose{at.x, at.y, heading(n)};
  r.speed = positive(n, "speed", 0.5, "m/s");
  r.radius = positive(n, "radius", 0.25, "metres");
  for (auto c : n.children("device")) {
    check_attributes(c, {"id", "type"});
    check_children(c, {"param"});
    DeviceSpec d;
    d.id = name(c, "id");
    claim(d.id, "device", line(c));
    d.type = name(c, "type");
    d.carrier = r.id;
    d.pose = r.start;
    d.params = params(c);
    house.devices.push_back(std::move(d));
    lines_.devices.push_back(line(c));
  }
  house.robots.push_back(std::move(r));
  lines_.robots.push_back(line(n));
}

void Parser::parse_user(pugi::xml_node n, House& house) {
  check_attributes(
      n, {"id", "x", "y", "speed", "radius", "loudness", "jitter", "loudness_jitter", "repeat"});
  check_children(n, {"go_to", "sit", "lie", "stand", "say"});
  UserSpec u;
  u.id = name(n, "id");
  claim(u.id, "user", line(n));
  u.start = point(n);
  u.speed = positive(n, "speed", 1.0, "m/s");
  u.radius = positive(n, "radius", 0.2, "metres");
  u.loudness_db = number(n, "loudness", 60.0, "dB");
  u.time_jitter =
      std::chrono::milliseconds(std::llround(non_negative(n, "jitter", 0.0, "seconds") * 1000.0));
  u.loudness_jitter_db = non_negative(n, "loudness_jitter", 0.0, "dB");
  if (auto repeat = n.attribute("repeat")) {
    const std::string_view v = repeat.value();
    if (v != "daily" && v != "once") {
      fail(line(n),
           fmt::format("repeat=\"{}\" of {} is not known, expected daily or once", v, describe(n)));
    }
    u.daily = v == "daily";
  }
  std::vector<std::size_t> entry_lines;
  for (auto c : n.children()) {
    if (c.type() != pugi::node_element) continue;
    const std::string_view kind = c.name();
    ScheduleEntry e;
    check_children(c, {});
    if (kind == "go_to" || kind == "sit" || kind == "lie") {
      check_attributes(c, {"at", "target"});
      e.activity = kind == "go_to" ? Activity::go_to
                   : kind == "sit" ? Activity::sit
                                   : Activity::lie;
      e.target = required(
          c, "target",
          kind == "go_to" ? "a waypoint, a piece of furniture or a room" : "a piece of furniture");
    } else if (kind == "stand") {
      check_attributes(c, {"at"});
      e.activity = Activity::stand;
    } else {
      check_attributes(c, {"at", "text"});
      e.activity = Activity::say;
      e.text = required(c, "text", "what the user says");
      if (e.text.empty()) fail(line(c), "<say> has an empty text, expected what the user says");
    }
    e.at = time_of_day(c, "at", std::nullopt);
    if (!u.schedule.empty() && e.at < u.schedule.back().at) {
      fail(line(c), fmt::format("<{}> at {} comes before the previous entry (line {}) at {}, "
                                "expected schedule entries in time order",
                                kind, c.attribute("at").value(), entry_lines.back(),
                                format_time(u.schedule.back().at).substr(3)));
    }
    u.schedule.push_back(std::move(e));
    entry_lines.push_back(line(c));
  }
  house.users.push_back(std::move(u));
  lines_.users.push_back(line(n));
  lines_.entries.push_back(std::move(entry_lines));
}

// Cuts every door's gap out of the walls it lies on.
void Parser::build_walls(House& house, const std::vector<Wall>& outline) {
  std::vector<Wall> walls;
  for (const auto& w : outline) {  // rooms sharing a side give the same wall twice
    const bool duplicate = std::any_of(walls.begin(), walls.end(), [&](const Wall& o) {
      return (distance(o.a, w.a) < kEpsilon && distance(o.b, w.b) < kEpsilon) ||
             (distance(o.a, w.b) < kEpsilon && distance(o.b, w.a) < kEpsilon);
    });
    if (!duplicate) walls.push_back(w);
  }
  constexpr double kOnWall = 1e-3;  // m
  for (std::size_t d = 0; d < house.doors.size(); ++d) {
    const auto& door = house.doors[d];
    bool on_some_wall = false;
    std::vector<Wall> cut;
    for (const auto& w : walls) {
      const double dx = w.b.x - w.a.x;
      const double dy = w.b.y - w.a.y;
      const double len2 = dx * dx + dy * dy;
      const auto off_line = [&](Point p) {
        return std::abs((p.x - w.a.x) * dy - (p.y - w.a.y) * dx) / std::sqrt(len2);
      };
      const auto param = [&](Point p) { return ((p.x - w.a.x) * dx + (p.y - w.a.y) * dy) / len2; };
      double t0 = param(door.a);
      double t1 = param(door.b);
      if (t0 > t1) std::swap(t0, t1);
      if (off_line(door.a) > kOnWall || off_line(door.b) > kOnWall || t1 <= kEpsilon ||
          t0 >= 1 - kEpsilon) {
        cut.push_back(w);
        continue;
      }
      on_some_wall = true;
      const auto at = [&](double t) { return Point{w.a.x + t * dx, w.a.y + t * dy}; };
      if (t0 > kEpsilon) cut.push_back({w.a, at(t0)});
      if (t1 < 1 - kEpsilon) cut.push_back({at(t1), w.b});
    }
    if (!on_some_wall) {
      fail(lines_.doors[d], fmt::format("door \"{}\" from {} to {} does not lie on any wall, "
                                        "expected a segment along a room's side or a <wall>",
                                        door.name, fmt_point(door.a), fmt_point(door.b)));
    }
    walls = std::move(cut);
  }
  house.walls = std::move(walls);
}

std::string Parser::resolve_room(House& house, const std::string& room, Point at,
                                 std::size_t at_line, std::string_view what) {
  if (!room.empty()) {
    const auto* r = house.room(room);
    if (!r) {
      std::vector<std::string> known;
      for (const auto& k : house.rooms) known.push_back(k.name);
      fail(at_line,
           fmt::format("unknown room \"{}\" for {}, expected one of: {}", room, what, join(known)));
    }
    if (!r->area.contains(at)) {
      fail(at_line,
           fmt::format("{} at {} is not inside its room \"{}\"", what, fmt_point(at), room));
    }
    return room;
  }
  const auto* r = house.room_at(at);
  if (!r) fail(at_line, fmt::format("{} at {} is outside every room", what, fmt_point(at)));
  return r->name;
}

void Parser::validate(House& house) {
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
    f.room = resolve_room(house, f.room, f.area.center(), lines_.furniture[i], what);
    const auto& room = house.room(f.room)->area;
    if (!room.contains(f.area.min) || !room.contains(f.area.max)) {
      fail(lines_.furniture[i],
           fmt::format("{} from {} to {} does not fit inside room \"{}\"", what,
                       fmt_point(f.area.min), fmt_point(f.area.max), f.room));
    }
  }
  for (std::size_t i = 0; i < house.waypoints.size(); ++i) {
    auto& w = house.waypoints[i];
    w.room = resolve_room(house, w.room, w.at, lines_.waypoints[i],
                          fmt::format("waypoint \"{}\"", w.name));
  }
  for (std::size_t i = 0; i < house.devices.size(); ++i) {
    auto& d = house.devices[i];
    if (!d.carrier.empty()) continue;
    d.room = resolve_room(house, d.room, d.pose.position(), lines_.devices[i],
                          fmt::format("device \"{}\"", d.id));
  }
  for (std::size_t i = 0; i < house.robots.size(); ++i) {
    const auto& r = house.robots[i];
    resolve_room(house, "", r.start.position(), lines_.robots[i],
                 fmt::format("the start of robot \"{}\"", r.id));
  }
  for (std::size_t i = 0; i < house.users.size(); ++i) {
    const auto& u = house.users[i];
    resolve_room(house, "", u.start, lines_.users[i],
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
      fail(lines_.robots[i], fmt::format("robot \"{}\" starts at {}, too close to a wall or "
                                         "furniture for its radius {:g} m, expected a free spot",
                                         r.id, fmt_point(r.start.position()), r.radius));
    }
  }
  for (std::size_t i = 0; i < house.users.size(); ++i) {
    const auto& u = house.users[i];
    if (!grid_for(u.radius).free(u.start)) {
      fail(lines_.users[i], fmt::format("user \"{}\" starts at {}, too close to a wall or "
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
        fail(lines_.furniture[i],
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
        fail(lines_.waypoints[i], fmt::format("waypoint \"{}\" at {} is too close to a wall or "
                                              "furniture for robot \"{}\" (radius {:g} m), "
                                              "expected a free spot",
                                              w.name, fmt_point(w.at), r.id, r.radius));
      }
      if (!grid.connected(r.start.position(), w.at)) {
        fail(lines_.waypoints[i],
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
      const auto at_line = lines_.entries[i][k];
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

}  // namespace

House parse_house(std::string_view xml, std::string_view source_name) {
  return Parser(xml, source_name).parse();
}

House load_house(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) {
    throw HouseError(file.string(), 0, "cannot open the file, expected a readable house file");
  }
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw HouseError(file.string(), 0, "cannot read the file");
  return parse_house(text.str(), file.string());
}

}  // namespace icars::sim
