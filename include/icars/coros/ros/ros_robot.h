// COROS Robot Control over ROS 1 (COROS 4.2, the paper's Robot with its Turtlebot): a robot
// base that reports odometry and takes navigation goals, driven through the Robot interface.
//
//   in:  /<ns>/odom                    nav_msgs/Odometry     pose, and the odometer (the sum
//                                                            of steps between odometry poses)
//   out: /<ns>/move_base_simple/goal   geometry_msgs/PoseStamped in frame "map"
//
// navigate_to() with a map plans over it and sends the path's corners one goal at a time, the
// next once odometry shows the robot within `tolerance` of the current one; without a map it
// sends the target as one goal (the base's own planner, move_base, plans). Every callback and
// timer runs on the robot's own ROS spinner thread; the public functions may be called from
// any thread.
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "icars/coros/knowledge.h"
#include "icars/coros/robot.h"

namespace icars::coros {

struct RosRobotOptions {
  std::string id;
  std::string ns;          // topic namespace, "robot1" for /robot1/odom ("" = id)
  double tolerance = 0.1;  // metres: a goal counts as reached this close
  // A navigation with no odometry progress (2 cm) for this long ends unarrived, and the robot
  // is failed while its odometry is older than this.
  std::chrono::milliseconds progress_timeout{10000};
  std::string goal_frame = "map";
};

class RosRobot : public Robot {
 public:
  // Subscribes and advertises at once; ros_layer::init() must have run (throws CorosError).
  // `map` may be null: targets then go to the base as single goals.
  RosRobot(RosRobotOptions options, std::shared_ptr<const MapPlanner> map);
  // Ends a navigation in progress (its callback hears "robot shut down") and unsubscribes.
  ~RosRobot() override;
  RosRobot(const RosRobot&) = delete;
  RosRobot& operator=(const RosRobot&) = delete;

  const std::string& id() const override { return options_.id; }
  sim::Pose pose() const override;  // the last odometry pose; (0, 0, 0) before the first
  RobotStatus status() const override;
  // `done` runs exactly once on the robot's spinner thread, never inside this call: arrived;
  // or not, when stop(), a newer navigate_to() or the destructor ends it, when there is no
  // path on the map, or when odometry shows no progress for progress_timeout. Before the
  // first odometry message the navigation waits for it (the timeout runs meanwhile).
  void navigate_to(sim::Point target, std::function<void(NavigationResult)> done) override;
  // Ends the navigation in progress (arrived = false, "stopped") and holds the base where it
  // is by sending its current pose as the goal.
  void stop() override;
  double odometer() const override;
  double clock_seconds() const override;  // wall seconds since construction

  bool has_odometry() const;
  std::string odom_topic() const;
  std::string goal_topic() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  RosRobotOptions options_;
};

// The robot of a COROS agent whose robot_kind is "ros": RosRobot with ns = config.ros_namespace
// (the agent id when empty). Calls ros_layer::init() with a node name from the id if needed.
std::shared_ptr<Robot> make_ros_robot(const AgentConfiguration& config,
                                      std::shared_ptr<const MapPlanner> map);

}  // namespace icars::coros
