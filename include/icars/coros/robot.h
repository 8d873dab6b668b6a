// COROS robot control (COROS 4.2, Robot Control): one interface for every robot an agent can
// drive, and the map that robots and auctioneers plan on.
//
// Robot is what agent code sees: its pose, its status, navigate_to(target) with a completion
// callback, stop(), and an odometer. Implementations:
//   SimRobot  the simulated robot of icars::sim, driving planned paths over the map in
//             accelerated simulated time (its own SimClock and RealTimeDriver);
//   RosRobot  a ROS 1 robot base (include/icars/coros/ros/ros_robot.h, built with ROS):
//             odometry in, navigation goals out.
// Completion callbacks may run on any thread (the simulation's or ROS's); agents post them to
// their own io_context.
#pragma once

#include <filesystem>
#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "icars/clock/sim_clock.h"
#include "icars/coros/field_cache.h"
#include "icars/sim/house.h"
#include "icars/sim/planner.h"
#include "icars/sim/world.h"

namespace icars::coros {

enum class RobotStatus { idle, moving, failed };
std::string_view to_string(RobotStatus status);

struct NavigationResult {
  bool arrived = false;
  double distance = 0;  // metres driven during this navigation
  std::string detail;   // why not arrived
};

class Robot {
 public:
  virtual ~Robot() = default;
  virtual const std::string& id() const = 0;
  virtual sim::Pose pose() const = 0;
  virtual RobotStatus status() const = 0;
  // Starts driving to `target`, ending a navigation in progress (whose callback hears
  // arrived = false). `done` runs exactly once, on any thread.
  virtual void navigate_to(sim::Point target, std::function<void(NavigationResult)> done) = 0;
  virtual void stop() = 0;
  virtual double odometer() const = 0;  // metres driven since start
  // Simulated seconds since the robot started (wall seconds for a real robot).
  virtual double clock_seconds() const = 0;
};

// The map every agent plans on: the house/office XML, its occupancy grid for a robot radius,
// and path costs. Immutable after construction, so it may be shared between threads.
class MapPlanner {
 public:
  // With a `field_cache` directory, the fields are shared with the other agents of this host
  // that plan on the same map (FieldCache); without one, each MapPlanner computes its own.
  // Throws CorosError when the directory cannot be created.
  MapPlanner(sim::House house, double robot_radius, const std::filesystem::path& field_cache = {});
  static std::shared_ptr<const MapPlanner> load(const std::string& file, double robot_radius,
                                                const std::filesystem::path& field_cache = {});

  const sim::House& house() const { return house_; }
  const sim::OccupancyGrid& grid() const { return grid_; }
  // A place by name (waypoint, furniture, room) or "x,y"; throws CorosError when unknown.
  sim::Point locate(const std::string& name) const;
  // The length of a path from `from` to `to` around the walls, nullopt when there is none
  // (never straight-line): a look-up in the distance field of `to` (sim::DistanceField), which
  // is computed (or read from the field cache) the first time `to` is asked about and kept (the
  // most recently used fields, up to kFieldBytes), so a bid costs microseconds, not a search of
  // the map. Safe to call from several threads.
  std::optional<double> path_cost(sim::Point from, sim::Point to) const;
  // The path itself, down the same field.
  std::optional<std::vector<sim::Point>> path(sim::Point from, sim::Point to) const;
  // The fields kept, for tests and footprint figures.
  std::size_t fields() const;

  static constexpr std::size_t kFieldBytes = std::size_t{32} << 20;

 private:
  std::shared_ptr<const sim::DistanceField> field(sim::Point to) const;

  sim::House house_;
  sim::OccupancyGrid grid_;
  std::unique_ptr<const FieldCache> cache_;  // null without a field_cache directory
  mutable std::mutex mutex_;
  mutable std::list<std::shared_ptr<const sim::DistanceField>> fields_;  // most recently used first
};

struct SimRobotOptions {
  std::string id;
  sim::Pose start;
  double speed = 0.5;
  double radius = 0.25;
  double speedup = 10.0;  // simulated seconds per wall second
};

// A simulated robot alone on the map (each process simulates its own robot; robots do not
// see each other). Its clock starts running at construction.
class SimRobot : public Robot {
 public:
  SimRobot(sim::House map, SimRobotOptions options);
  ~SimRobot() override;

  const std::string& id() const override { return options_.id; }
  sim::Pose pose() const override;
  RobotStatus status() const override;
  void navigate_to(sim::Point target, std::function<void(NavigationResult)> done) override;
  void stop() override;
  double odometer() const override;
  double clock_seconds() const override;

  // Every pose reported while driving, with simulated time: the robot's track for plots.
  std::vector<std::pair<Time, sim::Point>> track() const;

 private:
  SimRobotOptions options_;
  SimClock clock_;
  std::unique_ptr<sim::World> world_;
  std::unique_ptr<RealTimeDriver> driver_;
  mutable std::mutex mutex_;
  double odometer_ = 0;
  sim::Point last_{};
  std::vector<std::pair<Time, sim::Point>> track_;
  std::uint64_t listener_ = 0;
};

}  // namespace icars::coros
