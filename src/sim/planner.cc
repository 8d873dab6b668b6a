#include "icars/sim/planner.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <numbers>
#include <queue>

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

std::optional<std::vector<Point>> plan_path(const OccupancyGrid& grid, Point from, Point to) {
  const auto goal = grid.cell_of(to);
  if (!goal || !grid.free(*goal)) return std::nullopt;

  std::vector<Point> points{from};
  auto start = grid.cell_of(from);
  if (!start || !grid.free(*start)) {  // a body that stopped against an obstacle steps out
    const auto out = grid.nearest_free(from, grid.inflate_radius() + grid.resolution());
    if (!out) return std::nullopt;
    start = grid.cell_of(*out);
    points.push_back(*out);
  }
  if (grid.component(*start) != grid.component(*goal)) return std::nullopt;

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

  // Line-of-sight shortcuts: from each kept point, go as far along as is visible.
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
