#include "icars/sim/planner.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <numbers>
#include <numeric>
#include <queue>
#include <stdexcept>

namespace icars::sim {

namespace {

double segment_distance(Point p, Point a, Point b) {
  const double dx = b.x - a.x;
  const double dy = b.y - a.y;
  const double len2 = dx * dx + dy * dy;
  double t = len2 > 0 ? ((p.x - a.x) * dx + (p.y - a.y) * dy) / len2 : 0.0;
  t = std::clamp(t, 0.0, 1.0);
  return distance(p, {a.x + t * dx, a.y + t * dy});
}

double rect_distance(Point p, const Rect& r) {
  const double dx = std::max({r.min.x - p.x, 0.0, p.x - r.max.x});
  const double dy = std::max({r.min.y - p.y, 0.0, p.y - r.max.y});
  return std::hypot(dx, dy);
}

Rect bounds_of(const House& house) {
  if (house.bounds.max.x > house.bounds.min.x && house.bounds.max.y > house.bounds.min.y) {
    return house.bounds;
  }
  Rect b{{0, 0}, {0, 0}};
  bool first = true;
  for (const auto& r : house.rooms) {
    if (first) {
      b = r.area;
      first = false;
    }
    b.min.x = std::min(b.min.x, r.area.min.x);
    b.min.y = std::min(b.min.y, r.area.min.y);
    b.max.x = std::max(b.max.x, r.area.max.x);
    b.max.y = std::max(b.max.y, r.area.max.y);
  }
  return b;
}

// The 8 neighbour offsets; diagonals are allowed only when both orthogonal cells are free.
constexpr int kDx[8] = {1, -1, 0, 0, 1, 1, -1, -1};
constexpr int kDy[8] = {0, 0, 1, -1, 1, -1, 1, -1};

}  // namespace

OccupancyGrid::OccupancyGrid(const House& house, double inflate_radius)
    : resolution_(house.resolution > 0 ? house.resolution : 0.05),
      inflate_radius_(std::max(0.0, inflate_radius)) {
  const auto b = bounds_of(house);
  origin_ = b.min;
  width_ = std::max(1, static_cast<int>(std::ceil((b.max.x - b.min.x) / resolution_ - 1e-9)));
  height_ = std::max(1, static_cast<int>(std::ceil((b.max.y - b.min.y) / resolution_ - 1e-9)));
  free_.assign(static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_), 0);
  // Half a cell diagonal more than the radius: a wall of zero thickness still blocks every
  // cell it passes through, and a sampled segment cannot slip between blocked cells.
  const double clearance = inflate_radius_ + resolution_ * std::numbers::sqrt2 / 2;
  for (int y = 0; y < height_; ++y) {
    for (int x = 0; x < width_; ++x) {
      const Point c = center_of({x, y});
      bool ok = std::any_of(house.rooms.begin(), house.rooms.end(),
                            [&](const Room& r) { return r.area.contains(c); });
      for (const auto& w : house.walls) {
        if (!ok) break;
        ok = segment_distance(c, w.a, w.b) >= clearance;
      }
      for (const auto& f : house.furniture) {
        if (!ok) break;
        ok = !f.blocks || rect_distance(c, f.area) >= clearance;
      }
      free_[index({x, y})] = ok ? 1 : 0;
    }
  }
  label_components();
}

void OccupancyGrid::label_components() {
  component_.assign(free_.size(), -1);
  int next = 0;
  std::deque<Cell> queue;
  for (int y = 0; y < height_; ++y) {
    for (int x = 0; x < width_; ++x) {
      if (!free(Cell{x, y}) || component_[index({x, y})] >= 0) continue;
      component_[index({x, y})] = next;
      queue.push_back({x, y});
      while (!queue.empty()) {
        const Cell c = queue.front();
        queue.pop_front();
        for (int k = 0; k < 8; ++k) {
          const Cell n{c.x + kDx[k], c.y + kDy[k]};
          if (!free(n) || component_[index(n)] >= 0) continue;
          if (k >= 4 && (!free(Cell{n.x, c.y}) || !free(Cell{c.x, n.y}))) continue;
          component_[index(n)] = next;
          queue.push_back(n);
        }
      }
      ++next;
    }
  }
}

std::optional<Cell> OccupancyGrid::cell_of(Point p) const {
  const double fx = std::floor((p.x - origin_.x) / resolution_);
  const double fy = std::floor((p.y - origin_.y) / resolution_);
  if (!(fx >= 0 && fy >= 0 && fx < width_ && fy < height_)) return std::nullopt;
  return Cell{static_cast<int>(fx), static_cast<int>(fy)};
}

Point OccupancyGrid::center_of(Cell c) const {
  return {origin_.x + (c.x + 0.5) * resolution_, origin_.y + (c.y + 0.5) * resolution_};
}

bool OccupancyGrid::free(Cell c) const { return inside(c) && free_[index(c)] != 0; }

bool OccupancyGrid::free(Point p) const {
  const auto c = cell_of(p);
  return c && free(*c);
}

int OccupancyGrid::component(Cell c) const { return inside(c) ? component_[index(c)] : -1; }

OccupancyGrid OccupancyGrid::with_discs(const std::vector<Disc>& discs) const {
  OccupancyGrid out = *this;
  if (discs.empty()) return out;
  const double half_diagonal = resolution_ * std::numbers::sqrt2 / 2;
  for (const auto& d : discs) {
    const double clear = d.radius + inflate_radius_ + half_diagonal;
    const auto lo = cell_of({d.at.x - clear, d.at.y - clear});
    const auto hi = cell_of({d.at.x + clear, d.at.y + clear});
    const int x0 = lo ? lo->x : 0, y0 = lo ? lo->y : 0;
    const int x1 = hi ? hi->x : width_ - 1, y1 = hi ? hi->y : height_ - 1;
    for (int y = std::max(0, y0); y <= std::min(height_ - 1, y1); ++y) {
      for (int x = std::max(0, x0); x <= std::min(width_ - 1, x1); ++x) {
        const Point c = center_of({x, y});
        if (std::hypot(c.x - d.at.x, c.y - d.at.y) < clear) out.free_[out.index({x, y})] = 0;
      }
    }
  }
  out.label_components();
  return out;
}

std::size_t OccupancyGrid::free_cells() const {
  return static_cast<std::size_t>(std::count(free_.begin(), free_.end(), std::uint8_t{1}));
}

bool OccupancyGrid::segment_free(Point a, Point b) const {
  const double len = distance(a, b);
  const auto steps = static_cast<int>(std::ceil(len / (resolution_ / 4)));
  for (int i = 0; i <= steps; ++i) {
    const double t = steps == 0 ? 0.0 : static_cast<double>(i) / steps;
    if (!free(Point{a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t})) return false;
  }
  return true;
}

bool OccupancyGrid::connected(Point a, Point b) const {
  const auto ca = cell_of(a);
  const auto cb = cell_of(b);
  return ca && cb && free(*ca) && free(*cb) && component(*ca) == component(*cb);
}

std::optional<Point> OccupancyGrid::nearest_free(Point p, double max_distance,
                                                 std::optional<Point> reachable_from) const {
  int wanted = -1;
  if (reachable_from) {
    const auto near_from = nearest_free(*reachable_from, inflate_radius_ + resolution_);
    if (!near_from) return std::nullopt;
    wanted = component(*cell_of(*near_from));
  }
  const auto ok = [&](Cell c) { return free(c) && (wanted < 0 || component(c) == wanted); };
  if (const auto c = cell_of(p); c && ok(*c)) return p;
  const int reach = static_cast<int>(std::ceil(max_distance / resolution_)) + 1;
  const double fx = std::floor((p.x - origin_.x) / resolution_);
  const double fy = std::floor((p.y - origin_.y) / resolution_);
  if (!std::isfinite(fx) || !std::isfinite(fy)) return std::nullopt;
  const int cx = static_cast<int>(std::clamp(fx, -1e6, 1e6));
  const int cy = static_cast<int>(std::clamp(fy, -1e6, 1e6));
  std::optional<Point> best;
  double best_distance = max_distance;
  for (int y = std::max(0, cy - reach); y <= std::min(height_ - 1, cy + reach); ++y) {
    for (int x = std::max(0, cx - reach); x <= std::min(width_ - 1, cx + reach); ++x) {
      if (!ok(Cell{x, y})) continue;
      const auto c = center_of({x, y});
      const double d = distance(c, p);
      if (d <= best_distance) {
        if (best && d == best_distance) continue;  // keep the first of equals: deterministic
        best = c;
        best_distance = d;
      }
    }
  }
  return best;
}

namespace {

// The cell a path from `from` starts on, with `points` holding its first points (`from`, and
// the point it steps out to when it stands off the free space); nullopt when there is none.
std::optional<Cell> path_start(const OccupancyGrid& grid, Point from, std::vector<Point>& points) {
  points.push_back(from);
  auto start = grid.cell_of(from);
  if (!start || !grid.free(*start)) {  // a body that stopped against an obstacle steps out
    const auto out = grid.nearest_free(from, grid.inflate_radius() + grid.resolution());
    if (!out) return std::nullopt;
    start = grid.cell_of(*out);
    points.push_back(*out);
  }
  return start;
}

// Line-of-sight shortcuts: from each kept point, go as far along as is visible.
std::vector<Point> shortcut(const OccupancyGrid& grid, const std::vector<Point>& points, Point to) {
  std::vector<Point> path{points.front()};
  std::size_t i = 0;
  while (i + 1 < points.size()) {
    std::size_t j = i + 1;
    while (j + 1 < points.size() && grid.segment_free(points[i], points[j + 1])) ++j;
    if (distance(points[j], path.back()) > 1e-9) path.push_back(points[j]);
    i = j;
  }
  if (path.size() == 1) path.push_back(to);  // from == to
  return path;
}

}  // namespace

std::optional<std::vector<Point>> plan_path(const OccupancyGrid& grid, Point from, Point to) {
  const auto goal = grid.cell_of(to);
  if (!goal || !grid.free(*goal)) return std::nullopt;

  std::vector<Point> points;
  const auto start = path_start(grid, from, points);
  if (!start || grid.component(*start) != grid.component(*goal)) return std::nullopt;

  if (*start != *goal) {
    const auto w = static_cast<std::size_t>(grid.width_);
    const auto n = grid.free_.size();
    const auto idx = [&](Cell c) { return grid.index(c); };
    const auto heuristic = [&](Cell c) {
      const double dx = std::abs(c.x - goal->x);
      const double dy = std::abs(c.y - goal->y);
      return (dx + dy + (std::numbers::sqrt2 - 2) * std::min(dx, dy)) * grid.resolution_;
    };
    std::vector<double> g(n, std::numeric_limits<double>::infinity());
    std::vector<std::size_t> parent(n, n);
    std::vector<std::uint8_t> closed(n, 0);
    using Entry = std::pair<double, std::size_t>;  // (f, cell index)
    std::priority_queue<Entry, std::vector<Entry>, std::greater<>> open;
    g[idx(*start)] = 0;
    open.emplace(heuristic(*start), idx(*start));
    const auto goal_index = idx(*goal);
    while (!open.empty()) {
      const auto [f, i] = open.top();
      open.pop();
      if (closed[i]) continue;
      closed[i] = 1;
      if (i == goal_index) break;
      const Cell c{static_cast<int>(i % w), static_cast<int>(i / w)};
      for (int k = 0; k < 8; ++k) {
        const Cell nb{c.x + kDx[k], c.y + kDy[k]};
        if (!grid.free(nb)) continue;
        if (k >= 4 && (!grid.free(Cell{nb.x, c.y}) || !grid.free(Cell{c.x, nb.y}))) continue;
        const auto j = idx(nb);
        if (closed[j]) continue;
        const double step = (k >= 4 ? std::numbers::sqrt2 : 1.0) * grid.resolution_;
        if (g[i] + step < g[j]) {
          g[j] = g[i] + step;
          parent[j] = i;
          open.emplace(g[j] + heuristic(nb), j);
        }
      }
    }
    if (!closed[goal_index]) return std::nullopt;  // cannot happen: same component
    std::vector<Point> cells;
    for (auto i = parent[goal_index]; i != n && i != idx(*start); i = parent[i]) {
      cells.push_back(grid.center_of({static_cast<int>(i % w), static_cast<int>(i / w)}));
    }
    points.insert(points.end(), cells.rbegin(), cells.rend());
  }
  points.push_back(to);
  return shortcut(grid, points, to);
}

namespace {

// The field's moves: every (dx, dy) with |dx|, |dy| <= 3 and no common factor (32 directions),
// so that its distances are within 1% of the straight-line length in open space (8
// directions: up to 8%). A move is allowed when every cell its segment between the centres
// touches is free (for a diagonal step: both side cells, as plan_path).
struct Move {
  int dx, dy;
  double length;            // in cells
  std::vector<Cell> cells;  // offsets of the cells the segment touches, the end cell included
};

std::vector<Move> make_moves() {
  std::vector<Move> moves;
  for (int dx = -3; dx <= 3; ++dx) {
    for (int dy = -3; dy <= 3; ++dy) {
      if ((dx == 0 && dy == 0) || std::gcd(dx, dy) != 1) continue;
      Move m{dx, dy, std::hypot(dx, dy), {}};
      // Cells are unit squares around integer centres: sample the segment finely and take
      // every cell a sample is within a hair of (a segment through a corner touches all four).
      constexpr int kSamples = 256;
      constexpr double kHair = 1e-9;
      for (int i = 0; i <= kSamples; ++i) {
        const double x = dx * static_cast<double>(i) / kSamples;
        const double y = dy * static_cast<double>(i) / kSamples;
        for (const double ex : {-kHair, kHair}) {
          for (const double ey : {-kHair, kHair}) {
            const Cell c{static_cast<int>(std::floor(x + 0.5 + ex)), static_cast<int>(std::floor(y + 0.5 + ey))};
            if ((c.x != 0 || c.y != 0) && std::find(m.cells.begin(), m.cells.end(), c) == m.cells.end()) {
              m.cells.push_back(c);
            }
          }
        }
      }
      moves.push_back(std::move(m));
    }
  }
  return moves;
}

const std::vector<Move>& moves() {
  static const std::vector<Move> all = make_moves();
  return all;
}

bool move_free(const OccupancyGrid& grid, Cell c, const Move& m) {
  for (const Cell& o : m.cells) {
    if (!grid.free(Cell{c.x + o.x, c.y + o.y})) return false;
  }
  return true;
}

// The goal's cell, which must be free.
Cell free_goal_cell(const OccupancyGrid& grid, Point goal) {
  const auto cell = grid.cell_of(goal);
  if (!cell || !grid.free(*cell)) {
    throw std::invalid_argument(fmt::format("({:.2f}, {:.2f}) is not free space: no distances to it", goal.x, goal.y));
  }
  return *cell;
}

}  // namespace

DistanceField::DistanceField(const OccupancyGrid& grid, Point goal, std::vector<float> distances)
    : grid_(grid),
      goal_(goal),
      goal_cell_(free_goal_cell(grid, goal)),
      distance_(std::move(distances)) {
  if (distance_.size() != grid.free_.size()) {
    throw std::invalid_argument(fmt::format("a distance field of {} cells for a grid of {} cells",
                                            distance_.size(), grid.free_.size()));
  }
}

DistanceField::DistanceField(const OccupancyGrid& grid, Point goal)
    : grid_(grid), goal_(goal), goal_cell_(free_goal_cell(grid, goal)) {
  const auto w = static_cast<std::size_t>(grid.width_);
  const auto n = grid.free_.size();
  std::vector<double> d(n, std::numeric_limits<double>::infinity());
  using Entry = std::pair<double, std::size_t>;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<>> open;
  // The cells around the goal that see it start with the straight distance of their centre.
  const auto seed = [&](Cell c) {
    if (!grid.free(c) || !grid.segment_free(grid.center_of(c), goal)) return;
    const auto i = grid.index(c);
    d[i] = distance(grid.center_of(c), goal);
    open.emplace(d[i], i);
  };
  seed(goal_cell_);
  for (const auto& m : moves()) seed(Cell{goal_cell_.x + m.dx, goal_cell_.y + m.dy});
  while (!open.empty()) {
    const auto [di, i] = open.top();
    open.pop();
    if (di > d[i]) continue;
    const Cell c{static_cast<int>(i % w), static_cast<int>(i / w)};
    // Every move is allowed both ways, so the distance from the goal is the distance to it.
    for (const auto& m : moves()) {
      if (!move_free(grid, c, m)) continue;
      const auto j = grid.index(Cell{c.x + m.dx, c.y + m.dy});
      const double via = di + m.length * grid.resolution_;
      if (via < d[j]) {
        d[j] = via;
        open.emplace(via, j);
      }
    }
  }
  distance_.assign(d.begin(), d.end());
}

std::optional<DistanceField::Start> DistanceField::start_of(Point from, std::vector<Point>& points) const {
  const auto start = path_start(grid_, from, points);
  if (!start) return std::nullopt;
  // Where the path first heads for: the goal itself when in sight, else the cell around the
  // start (the start's own, or one a move away) in sight whose distance plus the way to it is
  // least.
  const Point at = points.back();
  if (grid_.segment_free(at, goal_)) return Start{*start, true, distance(at, goal_)};
  Start best{*start, false, std::numeric_limits<double>::infinity()};
  const auto consider = [&](Cell c) {
    if (!grid_.free(c)) return;
    const double rest = distance_[grid_.index(c)];
    if (!std::isfinite(rest)) return;
    const Point centre = grid_.center_of(c);
    const double via = distance(at, centre) + rest;
    if (via < best.length && grid_.segment_free(at, centre)) best = Start{c, false, via};
  };
  consider(*start);
  for (const auto& m : moves()) consider(Cell{start->x + m.dx, start->y + m.dy});
  if (!std::isfinite(best.length)) return std::nullopt;
  return best;
}

std::optional<double> DistanceField::length_from(Point from) const {
  std::vector<Point> points;  // `from`, and where it steps out to when off the free space
  const auto start = start_of(from, points);
  if (!start) return std::nullopt;
  return distance(from, points.back()) + start->length;
}

std::optional<std::vector<Point>> DistanceField::path_from(Point from) const {
  const auto& grid = grid_;
  std::vector<Point> points;
  const auto start = start_of(from, points);
  if (!start) return std::nullopt;
  if (start->sees_goal) {
    points.push_back(goal_);
    return shortcut(grid, points, goal_);
  }
  // Down the field: each move to the cell whose distance plus the move is least (on a
  // shortest path that is the cell's own distance), until a cell that sees the goal.
  Cell c = start->cell;
  points.push_back(grid.center_of(c));
  const std::size_t limit = distance_.size();
  for (std::size_t steps = 0; !grid.segment_free(grid.center_of(c), goal_); ++steps) {
    if (steps > limit) return std::nullopt;  // cannot happen: the distances only fall
    Cell best = c;
    double best_cost = std::numeric_limits<double>::infinity();
    for (const auto& m : moves()) {
      if (!move_free(grid, c, m)) continue;
      const Cell nb{c.x + m.dx, c.y + m.dy};
      const double cost = distance_[grid.index(nb)] + m.length * grid.resolution_;
      if (cost < best_cost) {
        best_cost = cost;
        best = nb;
      }
    }
    if (best == c) return std::nullopt;
    c = best;
    points.push_back(grid.center_of(c));
  }
  points.push_back(goal_);
  return shortcut(grid, points, goal_);
}

double path_length(const std::vector<Point>& path) {
  double total = 0;
  for (std::size_t i = 1; i < path.size(); ++i) total += distance(path[i - 1], path[i]);
  return total;
}

Pose point_along(const std::vector<Point>& path, double along) {
  if (path.empty()) return {};
  if (path.size() == 1) return {path[0].x, path[0].y, 0.0};
  double theta = 0;
  for (std::size_t i = 1; i < path.size(); ++i) {
    const double len = distance(path[i - 1], path[i]);
    if (len <= 0) continue;
    theta = std::atan2(path[i].y - path[i - 1].y, path[i].x - path[i - 1].x);
    if (along <= len || i + 1 == path.size()) {
      const double t = std::clamp(along / len, 0.0, 1.0);
      return {path[i - 1].x + (path[i].x - path[i - 1].x) * t,
              path[i - 1].y + (path[i].y - path[i - 1].y) * t, theta};
    }
    along -= len;
  }
  return {path.back().x, path.back().y, theta};
}

}  // namespace icars::sim
