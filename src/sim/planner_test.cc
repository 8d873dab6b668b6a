// Path planning: paths go through doors and never through walls or furniture, unreachable
// targets have no path, and paths are close to the shortest on open maps.
#include "icars/sim/planner.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>

namespace icars::sim {
namespace {

const std::filesystem::path kPaperHouse =
    std::filesystem::path(ICARS_HOUSES_DIR) / "paper_house.xml";

bool segments_cross(Point p1, Point p2, Point q1, Point q2) {
  const auto cross = [](Point o, Point a, Point b) {
    return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
  };
  const double d1 = cross(q1, q2, p1);
  const double d2 = cross(q1, q2, p2);
  const double d3 = cross(p1, p2, q1);
  const double d4 = cross(p1, p2, q2);
  return ((d1 > 0) != (d2 > 0)) && ((d3 > 0) != (d4 > 0));
}

// Every segment is free on the grid and crosses no wall of the house.
void expect_clear(const House& house, const OccupancyGrid& grid, const std::vector<Point>& path) {
  ASSERT_GE(path.size(), 2u);
  for (std::size_t i = 1; i < path.size(); ++i) {
    EXPECT_TRUE(grid.segment_free(path[i - 1], path[i]))
        << "segment " << i << " (" << path[i - 1].x << "," << path[i - 1].y << ")-(" << path[i].x
        << "," << path[i].y << ") leaves the free space";
    for (const auto& w : house.walls) {
      EXPECT_FALSE(segments_cross(path[i - 1], path[i], w.a, w.b))
          << "segment " << i << " crosses the wall (" << w.a.x << "," << w.a.y << ")-(" << w.b.x
          << "," << w.b.y << ")";
    }
  }
}

House open_room(double size) {
  House h;
  h.name = "open";
  h.rooms = {{"room", {{0, 0}, {size, size}}, std::nullopt}};
  h.walls = {{{0, 0}, {size, 0}},
             {{size, 0}, {size, size}},
             {{size, size}, {0, size}},
             {{0, size}, {0, 0}}};
  return h;
}

TEST(Planner, PathGoesThroughTheDoorAndNeverThroughAWall) {
  const auto house = load_house(kPaperHouse);
  const OccupancyGrid grid(house, 0.25);
  const auto from = *house.locate("living_room_center");
  const auto to = *house.locate("bedroom_center");
  const auto path = plan_path(grid, from, to);
  ASSERT_TRUE(path);
  EXPECT_EQ(path->front(), from);
  EXPECT_EQ(path->back(), to);
  expect_clear(house, grid, *path);
  // It crosses x = 6 (the wall between the rooms) inside the door, 2 < y < 3.
  int crossings = 0;
  for (std::size_t i = 1; i < path->size(); ++i) {
    const auto a = (*path)[i - 1];
    const auto b = (*path)[i];
    if ((a.x < 6) != (b.x < 6)) {
      const double y = a.y + (b.y - a.y) * (6 - a.x) / (b.x - a.x);
      EXPECT_GT(y, 2.0 + 0.25);
      EXPECT_LT(y, 3.0 - 0.25);
      ++crossings;
    }
  }
  EXPECT_EQ(crossings, 1);
  // Not much longer than the two straight legs via the door's middle.
  const double via_door = distance(from, {6, 2.5}) + distance({6, 2.5}, to);
  EXPECT_LT(path_length(*path), via_door * 1.05);
}

TEST(Planner, PathsBetweenRandomFreePointsStayClear) {
  const auto house = load_house(kPaperHouse);
  const OccupancyGrid grid(house, 0.25);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> x(0, 10);
  std::uniform_real_distribution<double> y(0, 5);
  int planned = 0;
  while (planned < 40) {
    const Point a{x(rng), y(rng)};
    const Point b{x(rng), y(rng)};
    if (!grid.free(a) || !grid.free(b)) continue;
    const auto path = plan_path(grid, a, b);
    ASSERT_EQ(path.has_value(), grid.connected(a, b));
    if (!path) continue;
    expect_clear(house, grid, *path);
    EXPECT_GE(path_length(*path), distance(a, b) - 1e-9);
    ++planned;
  }
}

// Two 4 m rooms side by side, a wall between them and no door.
House two_rooms_without_a_door() {
  House h = open_room(4);
  h.rooms.push_back({"other", {{4, 0}, {8, 4}}, std::nullopt});
  h.walls.push_back({{4, 0}, {8, 0}});
  h.walls.push_back({{8, 0}, {8, 4}});
  h.walls.push_back({{8, 4}, {4, 4}});
  return h;
}

TEST(Planner, UnreachableTargetsHaveNoPath) {
  const House h = two_rooms_without_a_door();
  const OccupancyGrid grid(h, 0.25);
  EXPECT_FALSE(plan_path(grid, {2, 2}, {6, 2}));
  EXPECT_FALSE(grid.connected({2, 2}, {6, 2}));
  EXPECT_TRUE(plan_path(grid, {1, 1}, {3, 3}));
  EXPECT_FALSE(plan_path(grid, {2, 2}, {4.05, 2}));  // target in the wall's inflation
  EXPECT_FALSE(plan_path(grid, {2, 2}, {20, 2}));    // target off the map
  EXPECT_FALSE(plan_path(grid, {2, 2}, {-1, 2}));

  // A target inside furniture is not reachable either.
  const auto house = load_house(kPaperHouse);
  const OccupancyGrid paper(house, 0.25);
  EXPECT_FALSE(
      plan_path(paper, *house.locate("entrance"), house.find_furniture("sofa")->area.center()));
}

TEST(Planner, StraightLineOnAnOpenMap) {
  const House h = open_room(10);
  const OccupancyGrid grid(h, 0.25);
  const auto path = plan_path(grid, {1, 1}, {9, 7});
  ASSERT_TRUE(path);
  EXPECT_EQ(path->size(), 2u);
  EXPECT_NEAR(path_length(*path), 10.0, 1e-9);
  const auto same = plan_path(grid, {2, 2}, {2, 2});
  ASSERT_TRUE(same);
  EXPECT_DOUBLE_EQ(path_length(*same), 0.0);
}

TEST(Planner, NearlyShortestAroundAnObstacle) {
  // A wall from the top down to y = 2 in the middle of a 10 m room: the shortest way from left
  // to right goes round its end, keeping the clearance.
  House h = open_room(10);
  h.walls.push_back({{5, 2}, {5, 10}});
  const OccupancyGrid grid(h, 0.25);
  const Point a{2, 8};
  const Point b{8, 8};
  const auto path = plan_path(grid, a, b);
  ASSERT_TRUE(path);
  expect_clear(h, grid, *path);
  const double clearance = 0.25 + 0.05 * std::sqrt(2.0) / 2;
  const Point corner{5, 2 - clearance};
  const double optimal = distance(a, corner) + distance(corner, b);
  EXPECT_GT(path_length(*path), optimal * 0.99);
  EXPECT_LT(path_length(*path), optimal * 1.03);
}

TEST(Planner, GridKeepsTheRadiusFromWallsAndFurniture) {
  const auto house = load_house(kPaperHouse);
  const double radius = 0.25;
  const OccupancyGrid grid(house, radius);
  EXPECT_EQ(grid.width(), 200);
  EXPECT_EQ(grid.height(), 100);
  for (int y = 0; y < grid.height(); ++y) {
    for (int x = 0; x < grid.width(); ++x) {
      if (!grid.free(Cell{x, y})) continue;
      const auto c = grid.center_of({x, y});
      for (const auto& f : house.furniture) {
        if (!f.blocks) continue;
        const double dx = std::max({f.area.min.x - c.x, 0.0, c.x - f.area.max.x});
        const double dy = std::max({f.area.min.y - c.y, 0.0, c.y - f.area.max.y});
        ASSERT_GE(std::hypot(dx, dy), radius) << f.name;
      }
      ASSERT_NE(house.room_at(c), nullptr);
    }
  }
  // A smaller body has more room.
  EXPECT_GT(OccupancyGrid(house, 0.2).free_cells(), grid.free_cells());
}

TEST(Planner, StartSlightlyInsideTheInflationStepsOut) {
  const House h = open_room(4);
  const OccupancyGrid grid(h, 0.25);
  const Point from{0.2, 2};  // 0.2 m from the wall: too close for a 0.25 m body
  ASSERT_FALSE(grid.free(from));
  const auto path = plan_path(grid, from, {3, 2});
  ASSERT_TRUE(path);
  EXPECT_EQ(path->front(), from);
  EXPECT_TRUE(grid.free((*path)[1]));
  EXPECT_LT(distance(from, (*path)[1]), 0.35);
  EXPECT_FALSE(plan_path(grid, {0.01, 2}, {3, 2}));  // more than a cell too deep: no
  EXPECT_FALSE(plan_path(grid, {-3, 2}, {3, 2}));    // off the map: no
}

TEST(Planner, NearestFreeFindsTheClosestReachableSpot) {
  const auto house = load_house(kPaperHouse);
  const OccupancyGrid grid(house, 0.25);
  const auto sofa = house.find_furniture("sofa")->area;
  const auto spot = grid.nearest_free(sofa.center(), 1.5, house.robots[0].start.position());
  ASSERT_TRUE(spot);
  EXPECT_TRUE(grid.free(*spot));
  EXPECT_LT(spot->y, sofa.min.y);  // in front of it; behind it is the wall
  EXPECT_LT(distance(*spot, sofa.center()), 0.8);
  EXPECT_FALSE(grid.nearest_free(sofa.center(), 0.3));  // nothing free that close
  const Point free_point = *house.locate("door");
  EXPECT_EQ(grid.nearest_free(free_point, 1.0), free_point);
}

TEST(Planner, PointAlongAPath) {
  const std::vector<Point> path{{0, 0}, {3, 0}, {3, 4}};
  EXPECT_DOUBLE_EQ(path_length(path), 7.0);
  const auto start = point_along(path, 0);
  EXPECT_EQ(start.position(), (Point{0, 0}));
  EXPECT_DOUBLE_EQ(start.theta, 0.0);
  const auto mid = point_along(path, 5);
  EXPECT_NEAR(mid.x, 3, 1e-12);
  EXPECT_NEAR(mid.y, 2, 1e-12);
  EXPECT_NEAR(mid.theta, std::acos(0.0), 1e-12);
  EXPECT_EQ(point_along(path, 100).position(), (Point{3, 4}));
  EXPECT_EQ(point_along(path, -1).position(), (Point{0, 0}));
}

}  // namespace
}  // namespace icars::sim

namespace icars::sim {
namespace {

// A distance field gives the paths plan_path gives: clear of walls, from and to the same
// points, as long within a little (both are shortest over the cells; paths of the same length over
// the cells shortcut differently: a few percent either way, nothing on the whole), and none where plan_path finds none.
TEST(DistanceField, PathsDownTheFieldAreThoseOfTheSearch) {
  const auto house = load_house(kPaperHouse);
  const OccupancyGrid grid(house, 0.25);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> x(-0.5, 10.5);
  std::uniform_real_distribution<double> y(-0.5, 5.5);
  for (const auto* goal_name : {"bedroom_center", "entrance", "kitchen_corner"}) {
    const Point goal = *house.locate(goal_name);
    const DistanceField field(grid, goal);
    EXPECT_EQ(field.goal(), goal);
    int planned = 0, refused = 0;
    double total_walked = 0, total_searched = 0, total_length = 0;
    for (int i = 0; i < 300; ++i) {
      const Point from{x(rng), y(rng)};
      const auto searched = plan_path(grid, from, goal);
      const auto walked = field.path_from(from);
      ASSERT_EQ(walked.has_value(), searched.has_value()) << from.x << "," << from.y << " to " << goal_name;
      if (!walked) {
        ++refused;
        continue;
      }
      ++planned;
      EXPECT_EQ(walked->front(), from);
      EXPECT_EQ(walked->back(), goal);
      if (grid.free(from)) expect_clear(house, grid, *walked);  // else its first step is out of a wall's margin
      EXPECT_NEAR(path_length(*walked), path_length(*searched), 0.06 * path_length(*searched) + 0.1)
          << from.x << "," << from.y << " to " << goal_name;
      total_walked += path_length(*walked);
      total_searched += path_length(*searched);
      const auto length = field.length_from(from);
      ASSERT_TRUE(length);
      // Never much longer than the search's path; at times shorter (its greedy shortcuts
      // are not the shortest way either).
      EXPECT_LE(*length, path_length(*searched) * 1.03 + 0.05) << from.x << "," << from.y << " to " << goal_name;
      EXPECT_GE(*length, path_length(*searched) * 0.93 - 0.05) << from.x << "," << from.y << " to " << goal_name;
      EXPECT_GE(*length, distance(from, goal) - 1e-6);
      total_length += *length;
    }
    EXPECT_GT(planned, 100);
    EXPECT_GT(refused, 10);  // points off the map, in walls or furniture
    // Neither is longer on the whole.
    EXPECT_NEAR(total_walked / total_searched, 1.0, 0.01) << goal_name;
    EXPECT_NEAR(total_length / total_searched, 1.0, 0.01) << goal_name;
    std::printf("%s: %d paths, walked / searched %.4f, field length / searched %.4f\n", goal_name, planned,
                total_walked / total_searched, total_length / total_searched);
    EXPECT_FALSE(field.length_from({20, 2}));
  }
}

TEST(DistanceField, AGoalOffTheFreeSpaceIsRefusedAndAnUnreachableStartHasNoPath) {
  const House h = two_rooms_without_a_door();
  const OccupancyGrid grid(h, 0.25);
  EXPECT_THROW(DistanceField(grid, {4.05, 2}), std::invalid_argument);
  EXPECT_THROW(DistanceField(grid, {20, 2}), std::invalid_argument);
  const DistanceField field(grid, {2, 2});
  EXPECT_FALSE(field.path_from({6, 2}));   // the other room: no door
  EXPECT_FALSE(field.path_from({20, 2}));  // off the map
  EXPECT_FALSE(field.length_from({6, 2}));
  EXPECT_NEAR(*field.length_from({3, 2}), 1.0, 0.03);
  const auto same = field.path_from({2, 2});
  ASSERT_TRUE(same);
  EXPECT_EQ(path_length(*same), 0);
  EXPECT_GT(field.memory(), 0u);
}

}  // namespace
}  // namespace icars::sim
