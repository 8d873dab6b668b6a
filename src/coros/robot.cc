#include "icars/coros/robot.h"

#include <fmt/format.h>

#include <charconv>

#include "icars/coros/messages.h"

namespace icars::coros {

std::string_view to_string(RobotStatus status) {
  switch (status) {
    case RobotStatus::idle:
      return "idle";
    case RobotStatus::moving:
      return "moving";
    case RobotStatus::failed:
      return "failed";
  }
  return "unknown";
}

// --- MapPlanner ----------------------------------------------------------------------------

MapPlanner::MapPlanner(sim::House house, double robot_radius,
                       const std::filesystem::path& field_cache)
    : house_(std::move(house)),
      grid_(house_, robot_radius),
      cache_(field_cache.empty() ? nullptr
                                 : std::make_unique<const FieldCache>(field_cache, grid_)) {}

std::shared_ptr<const MapPlanner> MapPlanner::load(const std::string& file, double robot_radius,
                                                   const std::filesystem::path& field_cache) {
  try {
    return std::make_shared<const MapPlanner>(sim::load_house(file), robot_radius, field_cache);
  } catch (const sim::HouseError& e) {
    throw CorosError(std::string("map: ") + e.what());
  }
}

namespace {
std::optional<sim::Point> parse_xy(const std::string& text) {
  const auto comma = text.find(',');
  if (comma == std::string::npos) return std::nullopt;
  sim::Point p;
  const char* b = text.data();
  const char* e = b + text.size();
  auto r1 = std::from_chars(b, b + comma, p.x);
  auto r2 = std::from_chars(b + comma + 1, e, p.y);
  if (r1.ec != std::errc{} || r1.ptr != b + comma || r2.ec != std::errc{} || r2.ptr != e) {
    return std::nullopt;
  }
  return p;
}
}  // namespace

sim::Point MapPlanner::locate(const std::string& name) const {
  if (auto p = parse_xy(name)) {
    if (!grid_.free(*p)) {
      throw CorosError(fmt::format("place {} is not free space on map '{}'", name, house_.name));
    }
    return *p;
  }
  if (auto p = house_.locate(name)) return *p;
  throw CorosError(
      fmt::format("no place '{}' on map '{}' (expected a waypoint, furniture, room "
                  "or \"x,y\")",
                  name, house_.name));
}

std::shared_ptr<const sim::DistanceField> MapPlanner::field(sim::Point to) const {
  std::lock_guard lock(mutex_);
  for (auto it = fields_.begin(); it != fields_.end(); ++it) {
    if ((*it)->goal() == to) {
      fields_.splice(fields_.begin(), fields_, it);
      return fields_.front();
    }
  }
  // Computed (or read from the cache) under the lock: robots asking for the same place at once
  // wait for one field rather than each computing its own.
  auto made = cache_ ? cache_->field(to) : std::make_shared<const sim::DistanceField>(grid_, to);
  fields_.push_front(made);
  std::size_t bytes = 0;
  for (auto it = fields_.begin(); it != fields_.end(); ++it) {
    bytes += (*it)->memory();
    if (bytes > kFieldBytes && it != fields_.begin()) {
      fields_.erase(it, fields_.end());
      break;
    }
  }
  return made;
}

std::size_t MapPlanner::fields() const {
  std::lock_guard lock(mutex_);
  return fields_.size();
}

std::optional<std::vector<sim::Point>> MapPlanner::path(sim::Point from, sim::Point to) const {
  if (!grid_.free(to)) return std::nullopt;
  return field(to)->path_from(from);
}

std::optional<double> MapPlanner::path_cost(sim::Point from, sim::Point to) const {
  if (!grid_.free(to)) return std::nullopt;
  return field(to)->length_from(from);
}

// --- SimRobot ------------------------------------------------------------------------------

namespace {
sim::House alone_on(sim::House map, const SimRobotOptions& o) {
  map.robots = {sim::RobotSpec{o.id, o.start, o.speed, o.radius}};
  map.users.clear();
  map.devices.clear();
  return map;
}
}  // namespace

SimRobot::SimRobot(sim::House map, SimRobotOptions options)
    : options_(std::move(options)), clock_(map.start_time), last_(options_.start.position()) {
  sim::WorldOptions world_options;
  world_options.report_every = Time{200};
  world_ = std::make_unique<sim::World>(alone_on(std::move(map), options_), clock_, world_options);
  track_.emplace_back(clock_.now(), last_);
  listener_ = world_->on_robot_pose([this](const std::string&, const sim::Pose& pose, bool) {
    std::lock_guard lock(mutex_);
    odometer_ += sim::distance(last_, pose.position());
    last_ = pose.position();
    track_.emplace_back(clock_.now(), last_);
  });
  driver_ = std::make_unique<RealTimeDriver>(clock_, options_.speedup);
  driver_->start();
}

SimRobot::~SimRobot() {
  driver_->stop();
  world_->remove_listener(listener_);
  world_.reset();
}

sim::Pose SimRobot::pose() const { return world_->robot_pose(options_.id); }

RobotStatus SimRobot::status() const {
  return world_->robot_moving(options_.id) ? RobotStatus::moving : RobotStatus::idle;
}

void SimRobot::navigate_to(sim::Point target, std::function<void(NavigationResult)> done) {
  const double start = odometer();
  auto path = world_->move_robot(options_.id, target, [this, start, done](bool arrived) {
    const sim::Point now = world_->robot_pose(options_.id).position();
    double driven = 0;
    {
      std::lock_guard lock(mutex_);
      odometer_ += sim::distance(last_, now);
      last_ = now;
      driven = odometer_ - start;
    }
    done(NavigationResult{arrived, driven, arrived ? "" : "stopped before arriving"});
  });
  if (!path) {
    done(NavigationResult{false, 0,
                          fmt::format("no path from ({:.2f}, {:.2f}) to ({:.2f}, {:.2f})", pose().x,
                                      pose().y, target.x, target.y)});
  }
}

void SimRobot::stop() { world_->stop_robot(options_.id); }

double SimRobot::odometer() const {
  std::lock_guard lock(mutex_);
  return odometer_;
}

double SimRobot::clock_seconds() const {
  return std::chrono::duration<double>(clock_.now() - world_->house().start_time).count();
}

std::vector<std::pair<Time, sim::Point>> SimRobot::track() const {
  std::lock_guard lock(mutex_);
  return track_;
}

}  // namespace icars::coros
