// Reading a house file: the XML of docs/house.md into a House, with the line of each element,
// which house_validation.cc then checks and completes.
#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <fstream>
#include <numbers>
#include <set>
#include <sstream>

#include "house_validation.h"
#include "icars/sim/house.h"
#include "icars/xml/xml_text.h"

namespace icars::sim {

namespace {

using detail::fmt_point;
using detail::join;
using detail::kEpsilon;


class Parser {
 public:
  Parser(std::string_view xml, std::string_view source) : text_(xml), source_(source) {}

  House parse();

 private:
  [[noreturn]] void fail(std::size_t line, const std::string& problem) const {
    throw HouseError(std::string(source_), line, problem);
  }
  std::size_t line(pugi::xml_node n) const { return text_.line(n); }

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

  xml::XmlText text_;
  std::string_view source_;
  std::map<std::string, std::pair<std::string, std::size_t>> names_;  // name -> (what, line)
  detail::HouseLines lines_;
};

House Parser::parse() {
  pugi::xml_document doc;
  if (const auto problem = text_.load(doc)) {
    throw HouseError(std::string(source_), problem->at.line, problem->at.column, problem->message);
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
  detail::validate_house(house, lines_, source_);
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
  check_attributes(n, {"id", "type", "room", "x", "y", "heading", "mqtt"});
  check_children(n, {"param"});
  DeviceSpec d;
  d.id = name(n, "id");
  claim(d.id, "device", line(n));
  d.type = name(n, "type");
  d.room = n.attribute("room").value();
  const auto at = point(n);
  d.pose = Pose{at.x, at.y, heading(n)};
  d.params = params(n);
  d.line = line(n);
  if (const auto a = n.attribute("mqtt")) {
    // A Home Assistant unique_id: any printable text without spaces; MQTT topics are made from
    // it, so no wildcards or separators either.
    const std::string id = a.value();
    const bool ok = !id.empty() && std::all_of(id.begin(), id.end(), [](char c) {
      return std::isgraph(static_cast<unsigned char>(c)) != 0 && c != '+' && c != '#' && c != '/';
    });
    if (!ok) {
      fail(line(n), fmt::format("mqtt=\"{}\" of <device> is not an MQTT unique_id, expected "
                                "printable characters without spaces, '+', '#' or '/'",
                                id));
    }
    for (const auto& other : house.devices) {
      if (other.mqtt == id) {
        fail(line(n), fmt::format("mqtt=\"{}\" is the unique_id of device \"{}\" at line {} "
                                  "too; one entity is one device",
                                  id, other.id, other.line));
      }
    }
    d.mqtt = id;
  }
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
    d.line = line(c);
    house.devices.push_back(std::move(d));
    lines_.devices.push_back(line(c));
  }
  house.robots.push_back(std::move(r));
  lines_.robots.push_back(line(n));
}

void Parser::parse_user(pugi::xml_node n, House& house) {
  check_attributes(
      n, {"id", "x", "y", "speed", "radius", "loudness", "jitter", "loudness_jitter", "repeat", "voice"});
  check_children(n, {"go_to", "sit", "lie", "stand", "say"});
  UserSpec u;
  u.id = name(n, "id");
  claim(u.id, "user", line(n));
  u.start = point(n);
  u.speed = positive(n, "speed", 1.0, "m/s");
  u.radius = positive(n, "radius", 0.2, "metres");
  u.loudness_db = number(n, "loudness", 60.0, "dB");
  if (auto voice = n.attribute("voice")) {
    u.voice = voice.value();
    if (u.voice.empty() || u.voice.find_first_of(" \t\n") != std::string::npos) {
      fail(line(n), fmt::format("voice=\"{}\" of {} is not a voice name, expected an espeak-ng voice such as en-us or en-us+f3",
                                u.voice, describe(n)));
    }
  }
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

}  // namespace

House parse_house(std::string_view xml, std::string_view source_name) {
  auto house = Parser(xml, source_name).parse();
  house.source = std::string(source_name);
  return house;
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
