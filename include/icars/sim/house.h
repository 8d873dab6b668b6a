// The house description: rooms, walls and doors, furniture, waypoints, devices, robots and
// users with their daily schedules — the experimental house of ICARS section 5 and any other.
//
// A house is written as an XML file (format: docs/house.md) and loaded with load_house(),
// which validates everything a running simulation relies on — names unique and known,
// devices inside rooms, waypoints and schedule targets reachable — and reports the first
// problem as a HouseError "file:line: what was wrong, expected what". Coordinates are metres
// in a right-handed plan view (x to the right, y up); headings are radians in memory and
// degrees in the file.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "icars/clock/time.h"

namespace icars::sim {

struct Point {
  double x = 0;
  double y = 0;
  friend bool operator==(const Point&, const Point&) = default;
};

struct Pose {
  double x = 0;
  double y = 0;
  double theta = 0;  // heading in radians, counter-clockwise from +x
  Point position() const { return {x, y}; }
  friend bool operator==(const Pose&, const Pose&) = default;
};

double distance(Point a, Point b);

struct Rect {
  Point min, max;
  bool contains(Point p) const;  // borders included
  Point center() const;
  double width() const { return max.x - min.x; }
  double height() const { return max.y - min.y; }
};

struct Room {
  std::string name;
  Rect area;
  std::optional<Point> anchor;  // free spot that stands for the room (its centre when free)
};

struct Wall {
  Point a, b;
};

// A named opening in the walls; the walls it lies on have a gap where it is.
struct Door {
  std::string name;
  Point a, b;
};

struct Furniture {
  std::string name, kind, room;  // kind: sofa, bed, table, tv_stand, ... (free text)
  Rect area;
  bool blocks = true;             // robots and users walk around it
  std::optional<Point> approach;  // free spot beside it, where one stands to use it
};

struct Waypoint {
  std::string name, room;
  Point at;
  std::vector<std::string> tags;  // e.g. "patrol"
};

struct DeviceSpec {
  std::string id, type, room;  // room is "" for devices a robot carries
  std::string carrier;         // robot id, or "" for a static device
  Pose pose;                   // a carried device: the robot's start pose
  std::map<std::string, std::string> params;
  std::size_t line = 0;  // of its element in the house file; 0 when not read from a file
  // Set: the device is an MQTT entity with this Home Assistant unique_id, brought in by an MQTT
  // bridge instead of the house's device manager (docs/house.md, "MQTT devices").
  std::string mqtt;
};

struct RobotSpec {
  std::string id;
  Pose start;
  double speed = 0.5;    // m/s
  double radius = 0.25;  // m, for path planning
};

enum class Activity { go_to, sit, lie, stand, say };
std::string_view to_string(Activity activity);

struct ScheduleEntry {
  Time at;  // time of day
  Activity activity = Activity::stand;
  std::string target;  // go_to: waypoint, furniture or room; sit, lie: furniture
  std::string text;    // say
};

struct UserSpec {
  std::string id;
  Point start;
  double speed = 1.0;         // m/s walking
  double radius = 0.2;        // m, for path planning
  double loudness_db = 60.0;  // speech level at 1 m
  std::string voice = "en-us";  // the espeak-ng voice the simulated microphones hear it speak with
  Time time_jitter{0};     // each activity starts up to this much early or late
  double loudness_jitter_db = 0.0;
  bool daily = true;                    // the schedule repeats every day; false: day 0 only
  std::vector<ScheduleEntry> schedule;  // in time order
};

struct House {
  std::string name;
  std::string source;        // the file it was read from (the source name given to parse_house)
  Rect bounds;               // the rooms' bounding box
  double resolution = 0.05;  // m per planning grid cell
  Time start_time{0};     // when the simulation starts (day 0)
  std::uint64_t seed = 1;
  std::vector<Room> rooms;
  std::vector<Wall> walls;  // after the doors' gaps were cut
  std::vector<Door> doors;
  std::vector<Furniture> furniture;
  std::vector<Waypoint> waypoints;
  std::vector<DeviceSpec> devices;  // static and carried
  std::vector<RobotSpec> robots;
  std::vector<UserSpec> users;

  const Room* room(std::string_view name) const;
  const Room* room_at(Point p) const;  // the first room (in file order) containing p
  const Waypoint* waypoint(std::string_view name) const;
  std::vector<const Waypoint*> waypoints_tagged(std::string_view tag) const;  // file order
  const Furniture* find_furniture(std::string_view name) const;
  const DeviceSpec* device(std::string_view id) const;
  const RobotSpec* robot(std::string_view id) const;
  const UserSpec* user(std::string_view id) const;
  // Where to go for a target: a waypoint's point, a furniture's approach spot (beside it), a
  // room's anchor (its centre, or the free spot nearest to it). nullopt for unknown names.
  std::optional<Point> locate(std::string_view target) const;
};

// A house file that cannot be used. what() is "source:line: problem", or
// "source:line:column: problem" when the column is known (malformed XML); line is 0 when the
// problem is not on a line (an unreadable file).
class HouseError : public std::runtime_error {
 public:
  HouseError(std::string source, std::size_t line, const std::string& problem);
  HouseError(std::string source, std::size_t line, std::size_t column, const std::string& problem);
  const std::string& source() const noexcept { return source_; }
  std::size_t line() const noexcept { return line_; }
  std::size_t column() const noexcept { return column_; }  // 0: not known
  const std::string& problem() const noexcept { return problem_; }

 private:
  std::string source_;
  std::size_t line_;
  std::size_t column_;
  std::string problem_;
};

House load_house(const std::filesystem::path& file);
// Parses and validates a house; `source_name` names it in errors (usually the file path).
House parse_house(std::string_view xml, std::string_view source_name);

}  // namespace icars::sim
