// House files: the paper's house loads with everything in place, and every broken fixture in
// testdata/bad gives the error (and line) its first comment announces.
#include "icars/sim/house.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <numbers>
#include <sstream>

#include "fixture_expectation.h"
#include "icars/sim/planner.h"

namespace icars::sim {
namespace {

using namespace std::chrono_literals;

const std::filesystem::path kPaperHouse =
    std::filesystem::path(ICARS_HOUSES_DIR) / "paper_house.xml";
const std::filesystem::path kBad = std::filesystem::path(ICARS_SIM_TESTDATA) / "bad";

House paper_house() { return load_house(kPaperHouse); }

TEST(House, PaperHouseHasTheRoomsAndDevicesOfSection5) {
  const auto house = paper_house();
  EXPECT_EQ(house.name, "paper_house");
  EXPECT_EQ(house.start_time, Time(18h));
  EXPECT_EQ(house.seed, 42u);
  EXPECT_DOUBLE_EQ(house.resolution, 0.05);
  ASSERT_EQ(house.rooms.size(), 2u);
  EXPECT_EQ(house.rooms[0].name, "living_room");
  EXPECT_EQ(house.rooms[1].name, "bedroom");
  EXPECT_DOUBLE_EQ(house.bounds.max.x, 10.0);
  EXPECT_DOUBLE_EQ(house.bounds.max.y, 5.0);

  // Two static devices in each room (plus the sofa's occupancy sensor).
  const auto static_in = [&](std::string_view room) {
    std::vector<std::string> types;
    for (const auto& d : house.devices) {
      if (d.carrier.empty() && d.room == room) types.push_back(d.type);
    }
    std::sort(types.begin(), types.end());
    return types;
  };
  EXPECT_EQ(static_in("living_room"), (std::vector<std::string>{"Light", "SofaOccupancy", "TV"}));
  EXPECT_EQ(static_in("bedroom"), (std::vector<std::string>{"BedOccupancy", "Light"}));
  ASSERT_NE(house.device("tv"), nullptr);
  EXPECT_NEAR(house.device("tv")->pose.theta, std::numbers::pi / 2, 1e-9);
  EXPECT_EQ(house.device("bed_sensor")->params.at("furniture"), "bed");

  // One robot carrying four devices.
  ASSERT_EQ(house.robots.size(), 1u);
  const auto& robot = house.robots[0];
  EXPECT_EQ(robot.id, "robot1");
  EXPECT_DOUBLE_EQ(robot.speed, 0.5);
  EXPECT_NEAR(robot.start.theta, std::numbers::pi, 1e-9);
  std::vector<std::string> carried;
  for (const auto& d : house.devices) {
    if (d.carrier == "robot1") {
      carried.push_back(d.id + ":" + d.type);
      EXPECT_EQ(d.room, "");
      EXPECT_EQ(d.pose, robot.start);
    }
  }
  EXPECT_EQ(carried, (std::vector<std::string>{"robot1_wheels:Wheels", "robot1_mic:Microphone",
                                               "robot1_speaker:Speaker", "robot1_camera:Camera"}));
}

TEST(House, PaperHouseUserLivesTheRestAndSleepScenario) {
  const auto house = paper_house();
  ASSERT_EQ(house.users.size(), 1u);
  const auto& u = house.users[0];
  EXPECT_EQ(u.id, "user1");
  EXPECT_TRUE(u.daily);
  EXPECT_EQ(u.time_jitter, Time(20s));
  std::vector<std::string> said;
  bool sits_on_sofa = false;
  bool lies_on_bed = false;
  for (const auto& e : u.schedule) {
    if (e.activity == Activity::say) said.push_back(e.text);
    sits_on_sofa |= e.activity == Activity::sit && e.target == "sofa";
    lies_on_bed |= e.activity == Activity::lie && e.target == "bed";
  }
  EXPECT_EQ(said, (std::vector<std::string>{"turn on the TV", "channel 5", "volume up",
                                            "play music", "stop"}));
  EXPECT_TRUE(sits_on_sofa);
  EXPECT_TRUE(lies_on_bed);
  EXPECT_TRUE(std::is_sorted(u.schedule.begin(), u.schedule.end(),
                             [](const auto& a, const auto& b) { return a.at < b.at; }));
}

TEST(House, LookupsAndLocate) {
  const auto house = paper_house();
  EXPECT_EQ(house.room_at({1, 1})->name, "living_room");
  EXPECT_EQ(house.room_at({8, 1})->name, "bedroom");
  EXPECT_EQ(house.room_at({11, 1}), nullptr);
  for (const char* name : {"living_room_center", "sofa_side", "bedroom_center", "bed_side", "door",
                           "kitchen_corner", "entrance"}) {
    ASSERT_NE(house.waypoint(name), nullptr) << name;
    EXPECT_EQ(house.locate(name), house.waypoint(name)->at);
  }
  EXPECT_EQ(house.waypoint("bed_side")->room, "bedroom");  // derived from the position
  std::vector<std::string> patrol;
  for (const auto* w : house.waypoints_tagged("patrol")) patrol.push_back(w->name);
  EXPECT_EQ(patrol, (std::vector<std::string>{"entrance", "living_room_center", "kitchen_corner",
                                              "door", "bedroom_center", "bedroom_window"}));
  EXPECT_EQ(house.find_furniture("sofa")->kind, "sofa");
  EXPECT_EQ(house.find_furniture("bed")->room, "bedroom");
  EXPECT_EQ(house.robot("robot1")->id, "robot1");
  EXPECT_EQ(house.user("user1")->id, "user1");
  EXPECT_EQ(house.device("nobody"), nullptr);
  EXPECT_FALSE(house.locate("nowhere"));

  // Furniture is located by a free spot beside it, in its room, reachable by the robot.
  const OccupancyGrid grid(house, 0.25);
  const auto robot_start = house.robots[0].start.position();
  for (const auto& f : house.furniture) {
    const auto spot = house.locate(f.name);
    ASSERT_TRUE(spot) << f.name;
    if (!f.blocks) {
      EXPECT_EQ(*spot, f.area.center());
      continue;
    }
    EXPECT_FALSE(f.area.contains(*spot)) << f.name;
    EXPECT_EQ(house.room_at(*spot)->name, f.room) << f.name;
    EXPECT_TRUE(grid.connected(robot_start, *spot)) << f.name;
    const double dx = std::max({f.area.min.x - spot->x, 0.0, spot->x - f.area.max.x});
    const double dy = std::max({f.area.min.y - spot->y, 0.0, spot->y - f.area.max.y});
    EXPECT_LT(std::hypot(dx, dy), 0.5) << f.name << " spot is not beside it";
  }
  // The sofa is used from the front (the wall is behind it), the bed from its long free side.
  EXPECT_LT(house.locate("sofa")->y, house.find_furniture("sofa")->area.min.y);
  EXPECT_LT(house.locate("bed")->x, house.find_furniture("bed")->area.min.x);
  // A room is located by its centre when that is free.
  EXPECT_EQ(house.locate("living_room"), house.rooms[0].area.center());
  EXPECT_TRUE(grid.connected(robot_start, *house.locate("bedroom")));
}

TEST(House, DoorsCutGapsInTheWalls) {
  const auto house = paper_house();
  ASSERT_EQ(house.doors.size(), 1u);
  const Point middle{6.0, 2.5};
  const auto on_wall = [&](Point p) {
    return std::any_of(house.walls.begin(), house.walls.end(), [&](const Wall& w) {
      const double len = distance(w.a, w.b);
      return std::abs(distance(w.a, p) + distance(p, w.b) - len) < 1e-9;
    });
  };
  EXPECT_FALSE(on_wall(middle));
  EXPECT_TRUE(on_wall({6.0, 1.0}));
  EXPECT_TRUE(on_wall({6.0, 4.0}));
  EXPECT_TRUE(on_wall({3.0, 0.0}));   // outer walls
  EXPECT_TRUE(on_wall({10.0, 2.5}));  // no door to the outside
}

TEST(House, DefaultsOfAMinimalHouse) {
  const auto house = parse_house(R"(<house name="tiny">
      <room name="only" x0="0" y0="0" x1="3" y1="3"/>
      <robot id="r" x="1.5" y="1.5"/>
      <user id="u" x="1" y="1"/>
    </house>)",
                                 "tiny.xml");
  EXPECT_EQ(house.start_time, Time{0});
  EXPECT_EQ(house.seed, 1u);
  EXPECT_DOUBLE_EQ(house.resolution, 0.05);
  EXPECT_EQ(house.walls.size(), 4u);
  EXPECT_DOUBLE_EQ(house.robots[0].speed, 0.5);
  EXPECT_DOUBLE_EQ(house.robots[0].radius, 0.25);
  EXPECT_DOUBLE_EQ(house.robots[0].start.theta, 0.0);
  const auto& u = house.users[0];
  EXPECT_DOUBLE_EQ(u.speed, 1.0);
  EXPECT_DOUBLE_EQ(u.radius, 0.2);
  EXPECT_DOUBLE_EQ(u.loudness_db, 60.0);
  EXPECT_EQ(u.time_jitter, Time{0});
  EXPECT_TRUE(u.daily);
  EXPECT_TRUE(u.schedule.empty());
}

TEST(House, UnreadableFileIsAnErrorWithoutALine) {
  try {
    load_house(kBad / "no_such_file.xml");
    FAIL() << "expected a HouseError";
  } catch (const HouseError& e) {
    EXPECT_EQ(e.line(), 0u);
    EXPECT_NE(std::string(e.what()).find("no_such_file.xml: cannot open"), std::string::npos)
        << e.what();
  }
}

TEST(House, EveryBrokenFixtureGivesItsDocumentedError) {
  std::vector<std::string> seen;
  for (const auto& entry : std::filesystem::directory_iterator(kBad)) {
    if (entry.path().extension() != ".xml") continue;
    const auto name = entry.path().filename().string();
    seen.push_back(entry.path().stem().string());
    const auto expected = icars_test::expectation_of(entry.path());
    ASSERT_GT(expected.line, 0u) << name << " has no <!-- expect LINE: MESSAGE --> first line";
    try {
      load_house(entry.path());
      ADD_FAILURE() << name << " loaded without an error";
    } catch (const HouseError& e) {
      EXPECT_EQ(e.line(), expected.line) << name << ": " << e.what();
      EXPECT_NE(e.problem().find(expected.message), std::string::npos)
          << name << ": got \"" << e.problem() << "\", expected \"" << expected.message << "\"";
      EXPECT_EQ(e.source(), entry.path().string());
      // "file:line: " or, for malformed XML, "file:line:column: ".
      const auto where = e.column() == 0 ? std::to_string(expected.line)
                                         : std::to_string(expected.line) + ":" + std::to_string(e.column());
      EXPECT_EQ(std::string(e.what()).rfind(entry.path().string() + ":" + where + ": ", 0), 0u) << e.what();
    }
  }
  for (const char* required :
       {"malformed_xml", "unknown_room", "duplicate_id", "device_outside_rooms", "bad_time",
        "unknown_schedule_target", "negative_speed", "missing_attribute", "unreachable_waypoint"}) {
    EXPECT_NE(std::find(seen.begin(), seen.end(), required), seen.end())
        << "missing fixture " << required;
  }
}

TEST(House, ErrorsNameTheSourceGivenToParse) {
  try {
    parse_house(
        "<house name=\"x\">\n<room name=\"r\" x0=\"0\" y0=\"0\" x1=\"0\" y1=\"1\"/>\n</house>",
        "inline");
    FAIL() << "expected a HouseError";
  } catch (const HouseError& e) {
    EXPECT_EQ(std::string(e.what()),
              "inline:2: <room name=\"r\"> has an empty area (0, 0)-(0, 1), expected x1 > x0 and "
              "y1 > y0");
  }
  EXPECT_THROW(parse_house("", "empty"), HouseError);
  EXPECT_THROW(parse_house("<house name=\"no rooms\"/>", "x"), HouseError);  // bad name
  EXPECT_THROW(parse_house("<house name=\"norooms\"/>", "x"), HouseError);   // no room
}

TEST(House, TheExampleInTheFormatDocumentLoads) {
  std::ifstream in(std::filesystem::path(ICARS_DOCS_DIR) / "house.md");
  ASSERT_TRUE(in);
  std::stringstream text;
  text << in.rdbuf();
  const auto doc = text.str();
  const auto begin = doc.find("```xml\n");
  ASSERT_NE(begin, std::string::npos);
  const auto end = doc.find("```", begin + 7);
  const auto house = parse_house(doc.substr(begin + 7, end - begin - 7), "docs/house.md");
  EXPECT_EQ(house.name, "flat");
  EXPECT_EQ(house.rooms.size(), 2u);
  EXPECT_EQ(house.users.at(0).schedule.size(), 5u);
  // The kitchen's centre is under the table: the room is located by the free spot nearest it.
  const auto kitchen = house.locate("kitchen");
  ASSERT_TRUE(kitchen);
  EXPECT_FALSE(house.find_furniture("table")->area.contains(*kitchen));
  EXPECT_EQ(house.room_at(*kitchen)->name, "kitchen");
}

}  // namespace
}  // namespace icars::sim
