// The SVG plot of a house and a run: a well-formed document that shows every room, waypoint
// and device by name, the robots' tracks as polylines in the house's frame (y up), tracks
// that go through doors and not walls between sparse positions, labels that do not cover one
// another and are escaped whatever they hold, the run's time span, and a write that fails
// loudly, naming the file.
#include "icars/sim/svg_plot.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <pugixml.hpp>
#include <set>
#include <sstream>

#include "icars/sim/world.h"

namespace icars::sim {
namespace {

using namespace std::chrono_literals;

House paper_house() {
  return load_house(std::filesystem::path(ICARS_HOUSES_DIR) / "paper_house.xml");
}

// Points of an SVG polyline or polygon "x,y x,y ...".
std::vector<Point> parse_points(const char* text) {
  std::vector<Point> points;
  std::istringstream in(text);
  Point p;
  char comma = 0;
  while (in >> p.x >> comma >> p.y) {
    EXPECT_EQ(comma, ',');
    points.push_back(p);
  }
  return points;
}

std::set<std::string> texts(const pugi::xml_document& doc) {
  std::set<std::string> out;
  for (const auto& node : doc.select_nodes("//*[local-name()='text']")) {
    out.insert(node.node().text().get());
  }
  return out;
}

// The element of `tag` and class `cls` whose data-name is `name`, or an empty node.
pugi::xml_node find(const pugi::xml_document& doc, std::string_view tag, std::string_view cls,
                    std::string_view name) {
  for (const auto& x : doc.select_nodes("//*[@data-name]")) {
    const auto n = x.node();
    if (n.name() == tag && n.attribute("class").value() == cls &&
        n.attribute("data-name").value() == name) {
      return n;
    }
  }
  return {};
}

PlotData evening_run() {
  PlotData data;
  data.title = "Paper house, evening";
  data.robots.push_back({"robot1",
                         {{at_time(0, 18, 0), {5.0, 2.4}},
                          {at_time(0, 18, 1), {3.0, 2.5}},
                          {at_time(0, 18, 2, 30), {3.1, 4.0}}}});
  data.users.push_back({"user1", {{at_time(0, 18, 0), {0.6, 2.0}}, {at_time(0, 18, 10), {1.6, 4.5}}}});
  data.marks.push_back({at_time(0, 18, 12), {1.6, 4.5}, "found <&> 'user1' \"here\""});
  return data;
}

TEST(SvgPlot, PaperHouseAndARunMakeAWellFormedPlotShowingEverything) {
  const auto house = paper_house();
  const auto data = evening_run();
  const std::string svg = render_svg(house, data);

  pugi::xml_document doc;
  const auto parsed = doc.load_string(svg.c_str());
  ASSERT_TRUE(parsed) << parsed.description() << " at offset " << parsed.offset;
  const auto root = doc.document_element();
  EXPECT_STREQ(root.name(), "svg");
  EXPECT_STREQ(root.attribute("xmlns").value(), "http://www.w3.org/2000/svg");
  EXPECT_GT(root.attribute("width").as_double(), 10 * kSvgPixelsPerMetre);

  const auto shown = texts(doc);
  EXPECT_TRUE(shown.contains("Paper house, evening"));
  for (const auto& r : house.rooms) EXPECT_TRUE(shown.contains(r.name)) << r.name;
  for (const auto& w : house.waypoints) EXPECT_TRUE(shown.contains(w.name)) << w.name;
  for (const auto& d : house.devices) {
    EXPECT_EQ(shown.contains(d.id), d.carrier.empty()) << d.id;  // static devices only
  }
  EXPECT_TRUE(shown.contains("sofa"));  // big furniture is labelled
  EXPECT_TRUE(shown.contains("robot1 d0 18:00:00"));  // the track's start and end times
  EXPECT_TRUE(shown.contains("d0 18:02:30"));
  EXPECT_TRUE(shown.contains("user1 d0 18:00:00"));
  EXPECT_TRUE(shown.contains("d0 18:10:00"));

  // The mark's label is escaped in the document and reads back as it was.
  EXPECT_NE(svg.find("found &lt;&amp;&gt; &apos;user1&apos; &quot;here&quot;"), std::string::npos);
  EXPECT_EQ(svg.find("<&>"), std::string::npos);
  EXPECT_TRUE(shown.contains("found <&> 'user1' \"here\""));

  // The robot's track: one point per position, at 80 px per metre, y flipped.
  const auto track = find(doc, "polyline", "robot-track", "robot1");
  ASSERT_TRUE(track);
  const auto points = parse_points(track.attribute("points").value());
  ASSERT_EQ(points.size(), data.robots[0].points.size());
  const Point first = data.robots[0].points[0].second;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Point p = data.robots[0].points[i].second;
    EXPECT_NEAR(points[i].x - points[0].x, (p.x - first.x) * kSvgPixelsPerMetre, 0.11) << i;
    EXPECT_NEAR(points[i].y - points[0].y, -(p.y - first.y) * kSvgPixelsPerMetre, 0.11) << i;
  }
  // ... in the same frame as the house: it starts on the dock's diamond.
  const auto dock = find(doc, "polygon", "waypoint", "dock");
  ASSERT_TRUE(dock);
  const auto diamond = parse_points(dock.attribute("points").value());
  ASSERT_EQ(diamond.size(), 4u);
  EXPECT_NEAR(points[0].x, diamond[0].x, 0.11);
  EXPECT_NEAR(points[0].y, (diamond[0].y + diamond[2].y) / 2, 0.11);
  EXPECT_TRUE(find(doc, "polygon", "waypoint patrol", "entrance"));  // patrol stands out
  // The user's track runs from the first position to the last, around the furniture to the
  // sofa; its dots mark the two positions.
  const auto user = find(doc, "polyline", "user-track", "user1");
  ASSERT_TRUE(user);
  const auto user_points = parse_points(user.attribute("points").value());
  ASSERT_GE(user_points.size(), 2u);
  const auto user_dots = doc.select_nodes("//g[@class='user-track-group']/circle[not(@class)]");
  ASSERT_EQ(user_dots.size(), 2u);
  for (const auto& [dot, point] : {std::pair{user_dots.first(), user_points.front()},
                                   std::pair{user_dots[1], user_points.back()}}) {
    EXPECT_NEAR(dot.node().attribute("cx").as_double(), point.x, 0.11);
    EXPECT_NEAR(dot.node().attribute("cy").as_double(), point.y, 0.11);
  }

  // Rooms: the bedroom is 6 m right of the living room, both 5 m high.
  const auto living = find(doc, "rect", "room", "living_room");
  const auto bedroom = find(doc, "rect", "room", "bedroom");
  ASSERT_TRUE(living && bedroom);
  EXPECT_NEAR(bedroom.attribute("x").as_double() - living.attribute("x").as_double(),
              6 * kSvgPixelsPerMetre, 0.11);
  EXPECT_NEAR(living.attribute("height").as_double(), 5 * kSvgPixelsPerMetre, 0.11);
  EXPECT_TRUE(find(doc, "line", "door", "bedroom_door"));
}

TEST(SvgPlot, EmptyTracksAndHostileNamesStillMakeAWellFormedPlot) {
  auto house = paper_house();
  house.rooms[0].name = "<living & \"dining\">";
  PlotData data;
  data.title = "a<b & 'c'";
  data.robots.push_back({"robot1", {}});
  data.users.push_back({"user&1", {{at_time(1, 7, 0), {0.6, 2.0}}}});
  data.marks.push_back({at_time(1, 7, 0), {0.6, 2.0}, "control \x01 char"});
  const std::string svg = render_svg(house, data);
  pugi::xml_document doc;
  const auto parsed = doc.load_string(svg.c_str());
  ASSERT_TRUE(parsed) << parsed.description() << " at offset " << parsed.offset;
  const auto shown = texts(doc);
  EXPECT_TRUE(shown.contains("a<b & 'c'"));
  EXPECT_TRUE(shown.contains("<living & \"dining\">"));
  EXPECT_TRUE(shown.contains("user&1 d1 07:00:00"));
  EXPECT_TRUE(shown.contains("robot1"));  // in the legend, though it never moved
  EXPECT_FALSE(find(doc, "polyline", "robot-track", "robot1"));

  // No data at all, and no title: the house's name is the title.
  const std::string bare = render_svg(paper_house(), PlotData{});
  pugi::xml_document bare_doc;
  ASSERT_TRUE(bare_doc.load_string(bare.c_str()));
  EXPECT_TRUE(texts(bare_doc).contains("paper_house"));
}

// Whether segments pq and ab cross: the ends of each lie strictly on both sides of the other.
bool crosses(Point p, Point q, Point a, Point b) {
  const auto side = [](Point o, Point u, Point v) {
    return (u.x - o.x) * (v.y - o.y) - (u.y - o.y) * (v.x - o.x);
  };
  const auto apart = [](double s, double t) { return (s > 0 && t < 0) || (s < 0 && t > 0); };
  return apart(side(a, b, p), side(a, b, q)) && apart(side(p, q, a), side(p, q, b));
}

// Every segment of a robot's or user's track in the plot that crosses one of the plot's walls
// (SVG pixels), as "name (x,y)-(x,y)".
std::vector<std::string> tracks_through_walls(const House& house, const pugi::xml_document& doc) {
  std::vector<std::pair<Point, Point>> walls;
  for (const auto& x : doc.select_nodes("//g[@class='walls']/line")) {
    const auto n = x.node();
    walls.push_back({{n.attribute("x1").as_double(), n.attribute("y1").as_double()},
                     {n.attribute("x2").as_double(), n.attribute("y2").as_double()}});
  }
  EXPECT_EQ(walls.size(), house.walls.size());
  std::vector<std::string> found;
  for (const auto& x : doc.select_nodes("//polyline[@class='robot-track' or @class='user-track']")) {
    const auto points = parse_points(x.node().attribute("points").value());
    for (std::size_t i = 0; i + 1 < points.size(); ++i) {
      for (const auto& [a, b] : walls) {
        if (crosses(points[i], points[i + 1], a, b)) {
          found.push_back(fmt::format("{} ({},{})-({},{})", x.node().attribute("data-name").value(),
                                      points[i].x, points[i].y, points[i + 1].x, points[i + 1].y));
        }
      }
    }
  }
  return found;
}

TEST(SvgPlot, TracksBetweenSparsePositionsGoThroughDoorsNotWalls) {
  const auto house = paper_house();
  PlotData data;
  // Far apart and in different rooms: straight lines between these cut through the wall
  // between the living room and the bedroom (the door is at x = 6, y 2..3).
  data.users.push_back({"user1",
                        {{at_time(0, 18, 0), {1.6, 4.5}},     // on the sofa
                         {at_time(0, 22, 30), {9.0, 3.9}},    // on the bed
                         {at_time(1, 7, 15), {4.7, 1.0}}}});  // at the dining table
  data.robots.push_back({"robot1",
                         {{at_time(0, 18, 0), {5.0, 2.4}},      // the dock
                          {at_time(0, 22, 0), {7.8, 3.6}},      // bed_side
                          {at_time(0, 22, 5), {5.3, 3.9}}}});   // kitchen_corner
  int straight_crossings = 0;
  for (const auto* track : {&data.users[0], &data.robots[0]}) {
    for (std::size_t i = 0; i + 1 < track->points.size(); ++i) {
      for (const auto& w : house.walls) {
        straight_crossings += crosses(track->points[i].second, track->points[i + 1].second, w.a, w.b);
      }
    }
  }
  ASSERT_GE(straight_crossings, 3);  // the positions alone would cut through walls

  const std::string svg = render_svg(house, data);
  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(svg.c_str()));
  EXPECT_EQ(tracks_through_walls(house, doc), std::vector<std::string>{});
  // The tracks still begin and end at the first and last positions.
  for (const auto& [kind, track] : {std::pair{"user-track", &data.users[0]},
                                    std::pair{"robot-track", &data.robots[0]}}) {
    const auto line = find(doc, "polyline", kind, track->name);
    ASSERT_TRUE(line) << kind;
    const auto points = parse_points(line.attribute("points").value());
    ASSERT_GT(points.size(), track->points.size()) << kind;  // detours were drawn
    const Point first = track->points.front().second;
    const Point last = track->points.back().second;
    EXPECT_NEAR(points.back().x - points.front().x, (last.x - first.x) * kSvgPixelsPerMetre, 0.11);
    EXPECT_NEAR(points.back().y - points.front().y, -(last.y - first.y) * kSvgPixelsPerMetre, 0.11);
  }
}

TEST(SvgPlot, TracksOfASimulatedEveningGoThroughDoorsNotWalls) {
  const auto house = paper_house();
  SimClock clock(house.start_time);
  World world(house, clock);
  PlotData data;
  data.robots.push_back({"robot1", {{clock.now(), house.robot("robot1")->start.position()}}});
  data.users.push_back({"user1", {{clock.now(), house.user("user1")->start}}});
  world.on_robot_pose([&](const std::string&, const Pose& pose, bool) {
    data.robots[0].points.emplace_back(clock.now(), pose.position());
  });
  world.on_user([&](const UserState& u) { data.users[0].points.emplace_back(clock.now(), u.at); });
  // The user's evening (sofa, dining table, sofa, bed) while the robot goes between the rooms.
  for (const auto& [at, target] : {std::pair{at_time(0, 18, 30), "bedroom_window"},
                                   std::pair{at_time(0, 19, 0), "kitchen_corner"},
                                   std::pair{at_time(0, 22, 35), "bed_side"}}) {
    clock.advance_to(at);
    ASSERT_TRUE(world.move_robot("robot1", *house.locate(target))) << target;
  }
  clock.advance_to(at_time(0, 23, 0));
  ASSERT_GT(data.users[0].points.size(), 10u);

  const std::string svg = render_svg(house, data);
  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(svg.c_str()));
  EXPECT_EQ(tracks_through_walls(house, doc), std::vector<std::string>{});
}

// The box a text element covers, estimated as the plot does (0.6 font sizes a character),
// from 0.8 font sizes above its baseline to 0.2 below.
struct TextBox {
  std::string text;
  double left, top, right, bottom;
};

std::vector<TextBox> text_boxes(const pugi::xml_document& doc, const char* xpath) {
  std::vector<TextBox> boxes;
  for (const auto& x : doc.select_nodes(xpath)) {
    const auto n = x.node();
    const double left = n.attribute("x").as_double();
    const double baseline = n.attribute("y").as_double();
    const double size = n.attribute("font-size").as_double();
    const std::string text = n.text().get();
    boxes.push_back({text, left, baseline - 0.8 * size,
                     left + 0.6 * size * static_cast<double>(text.size()), baseline + 0.2 * size});
  }
  return boxes;
}

TEST(SvgPlot, LabelsOfMarksAtTheSamePlaceAreStackedNotOverprinted) {
  const auto house = paper_house();
  PlotData data;
  data.robots.push_back({"robot1", {{at_time(0, 18, 0), {5.0, 2.4}},
                                    {at_time(0, 18, 5), {3.0, 2.5}},
                                    {at_time(0, 18, 6), {3.0, 2.5}}}});
  // States changing while the robot waits at the dock, then twice where it stopped.
  const std::vector<std::string> labels = {"18:00 Observation", "18:00 RestMode",
                                           "18:00 Observation", "18:00 SleepMode",
                                           "18:06 RestMode", "18:06 NightWatch"};
  for (std::size_t i = 0; i < labels.size(); ++i) {
    data.marks.push_back({at_time(0, 18, i < 4 ? 0 : 6), i < 4 ? Point{5.0, 2.4} : Point{3.0, 2.5},
                          labels[i]});
  }
  const std::string svg = render_svg(house, data);
  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(svg.c_str()));

  const auto marks = text_boxes(doc, "//g[@class='mark']/text");
  ASSERT_EQ(marks.size(), labels.size());
  for (std::size_t i = 0; i < labels.size(); ++i) EXPECT_EQ(marks[i].text, labels[i]);
  // Neither the marks' labels nor the track's time labels cover one another.
  auto boxes = marks;
  const auto times = text_boxes(doc, "//text[@class='time']");
  EXPECT_EQ(times.size(), 2u);  // the track's start and end
  boxes.insert(boxes.end(), times.begin(), times.end());
  for (std::size_t i = 0; i < boxes.size(); ++i) {
    for (std::size_t j = i + 1; j < boxes.size(); ++j) {
      const auto& a = boxes[i];
      const auto& b = boxes[j];
      EXPECT_FALSE(a.left < b.right && b.left < a.right && a.top < b.bottom && b.top < a.bottom)
          << "'" << a.text << "' at (" << a.left << ", " << a.bottom << ") covers '" << b.text
          << "' at (" << b.left << ", " << b.bottom << ")";
    }
  }
  // A label moved away from its pin is joined to it by a leader line.
  EXPECT_GE(doc.select_nodes("//g[@class='mark']/line[@class='leader']").size(), 4u);
}

TEST(SvgPlot, SubtitleShowsTheRunsStartAndEndNotJustTheMovements) {
  const auto house = paper_house();
  PlotData data;
  data.robots.push_back({"robot1", {{at_time(0, 18, 5), {5.0, 2.4}}, {at_time(0, 18, 7), {3.0, 2.5}}}});
  const auto subtitle = [&](const PlotData& d) {
    const std::string svg = render_svg(house, d);
    pugi::xml_document doc;
    EXPECT_TRUE(doc.load_string(svg.c_str()));
    return std::string(doc.select_node("//text[@class='subtitle']").node().text().get());
  };
  // Without the run's span: the time the data spans.
  EXPECT_EQ(subtitle(data), "house paper_house, d0 18:05:00 to d0 18:07:00");
  data.run_start = at_time(0, 18, 0);
  data.run_end = at_time(0, 23, 0);
  EXPECT_EQ(subtitle(data), "house paper_house, d0 18:00:00 to d0 23:00:00");
  PlotData quiet;  // a run in which nothing moved
  quiet.run_start = at_time(0, 18, 0);
  quiet.run_end = at_time(0, 18, 30);
  EXPECT_EQ(subtitle(quiet), "house paper_house, d0 18:00:00 to d0 18:30:00");
}

TEST(SvgPlot, WriteSvgWritesTheDocumentOrThrowsNamingThePath) {
  const auto house = paper_house();
  const auto data = evening_run();
  const auto path = std::filesystem::path(::testing::TempDir()) / "icars_svg_plot_test.svg";
  write_svg(path.string(), house, data);
  std::ifstream in(path, std::ios::binary);
  std::ostringstream written;
  written << in.rdbuf();
  EXPECT_EQ(written.str(), render_svg(house, data));
  std::filesystem::remove(path);

  for (const std::string& bad : {std::string("/nonexistent-icars-dir/plot.svg"),
                                std::filesystem::temp_directory_path().string()}) {
    try {
      write_svg(bad, house, data);
      FAIL() << "wrote to " << bad;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("\"" + bad + "\""), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace icars::sim
