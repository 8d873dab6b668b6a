// The SVG plot of a house and a run: a well-formed document that shows every room, waypoint
// and device by name, the robots' tracks as polylines in the house's frame (y up), labels
// escaped whatever they hold, and a write that fails loudly, naming the file.
#include "icars/sim/svg_plot.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <pugixml.hpp>
#include <set>
#include <sstream>

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
  const auto user = find(doc, "polyline", "user-track", "user1");
  ASSERT_TRUE(user);
  EXPECT_EQ(parse_points(user.attribute("points").value()).size(), 2u);

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
