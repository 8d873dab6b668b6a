#include "icars/coros/ros/ros_robot.h"

#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Odometry.h>
#include <ros/steady_timer.h>

#include <cmath>
#include <cstdint>
#include <sstream>

#include "icars/coros/ros/ros_layer.h"

namespace icars::coros {

namespace {

using SteadyClock = std::chrono::steady_clock;

constexpr double kProgressStep = 0.02;  // metres of odometry that count as progress
constexpr auto kWatchdogPeriod = std::chrono::milliseconds(100);

std::string describe(sim::Point p) {
  std::ostringstream out;
  out.precision(2);
  out << std::fixed << "(" << p.x << ", " << p.y << ")";
  return out.str();
}

double seconds(SteadyClock::duration d) { return std::chrono::duration<double>(d).count(); }

std::string topic_namespace(const RosRobotOptions& options) {
  std::string ns = options.ns.empty() ? ros_layer::ros_name(options.id) : options.ns;
  return ns.starts_with('/') ? ns : "/" + ns;
}

}  // namespace

struct RosRobot::Impl {
  struct Navigation {
    sim::Point target;
    std::function<void(NavigationResult)> done;
    bool planned = false;
    std::vector<sim::Point> goals;  // the path's corners after the start; the target last
    std::size_t next = 0;           // the goal sent to the base
    double odometer_at_start = 0;
    double progress_mark = 0;  // odometer when progress was last seen
    SteadyClock::time_point progress_time{};
    SteadyClock::time_point resent{};  // when the current goal was last sent again
  };

  Impl(const RosRobotOptions& o, std::shared_ptr<const MapPlanner> m)
      : options(o), map(std::move(m)), started(SteadyClock::now()), node(topic_namespace(o)) {
    // Latched: a base whose subscription connects after the goal was sent still gets it.
    publishers.add<geometry_msgs::PoseStamped>("goal", "move_base_simple/goal", 10, true);
    subscribers.add<nav_msgs::Odometry>(
        "odom", "odom", [this](const nav_msgs::Odometry& odometry) { on_odometry(odometry); }, 20);
    watchdog =
        node.handle().createSteadyTimer(ros::WallDuration(seconds(kWatchdogPeriod)),
                                        [this](const ros::SteadyTimerEvent&) { check_progress(); });
  }

  // --- on the spinner thread ---

  void on_odometry(const nav_msgs::Odometry& odometry) {
    const auto& p = odometry.pose.pose.position;
    const auto& q = odometry.pose.pose.orientation;
    const double yaw =
        std::atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z));
    std::lock_guard lock(mutex);
    if (have_odometry) odometer += sim::distance(pose.position(), {p.x, p.y});
    have_odometry = true;
    pose = {p.x, p.y, yaw};
    last_odometry = SteadyClock::now();
    if (!navigation) return;
    if (odometer - navigation->progress_mark >= kProgressStep) {
      navigation->progress_mark = odometer;
      navigation->progress_time = last_odometry;
    }
    if (navigation->planned) {
      advance();
    } else {
      plan();
    }
  }

  void check_progress() {
    std::lock_guard lock(mutex);
    if (!navigation) return;
    const auto now = SteadyClock::now();
    if (now - navigation->progress_time < options.progress_timeout) {
      // No progress for a while: send the current goal again (a goal published while the
      // base's subscription was still connecting is lost to it).
      if (navigation->planned && now - navigation->progress_time >= std::chrono::seconds(1) &&
          now - navigation->resent >= std::chrono::seconds(1)) {
        navigation->resent = now;
        const auto& nav = *navigation;
        send_goal(nav.goals.at(nav.next), nav.next > 0 ? nav.goals[nav.next - 1] : pose.position());
      }
      return;
    }
    const auto waited = std::to_string(options.progress_timeout.count()) + " ms";
    if (!have_odometry) {
      finish(false, "no odometry on " + subscribers.topic("odom") + " for " + waited);
    } else {
      finish(false, "no odometry progress for " + waited + " (last goal " +
                        describe(navigation->goals.at(navigation->next)) + ", at " +
                        describe(pose.position()) + ")");
    }
  }

  // --- with the mutex held ---

  // Plans from the current pose (odometry has arrived) and sends the first goal.
  void plan() {
    Navigation& nav = *navigation;
    const sim::Point from = pose.position();
    if (map) {
      std::optional<std::vector<sim::Point>> path;
      try {
        path = map->path(from, nav.target);
      } catch (const std::exception& e) {
        finish(false, "cannot plan from " + describe(from) + " to " + describe(nav.target) + ": " +
                          e.what());
        return;
      }
      if (!path || path->empty()) {
        finish(false, "no path on the map from " + describe(from) + " to " + describe(nav.target));
        return;
      }
      nav.goals.assign(path->begin() + 1, path->end());  // the path starts where we stand
      if (nav.goals.empty()) nav.goals.push_back(nav.target);
    } else {
      nav.goals = {nav.target};
    }
    nav.planned = true;
    nav.next = 0;
    send_goal(nav.goals.front(), from);
    advance();
  }

  // Moves on past the goals odometry shows reached; finishes at the last one.
  void advance() {
    Navigation& nav = *navigation;
    const std::size_t before = nav.next;
    while (sim::distance(pose.position(), nav.goals[nav.next]) <= options.tolerance) {
      if (nav.next + 1 == nav.goals.size()) {
        finish(true, "");
        return;
      }
      ++nav.next;
    }
    if (nav.next != before) send_goal(nav.goals[nav.next], nav.goals[nav.next - 1]);
  }

  void send_goal(sim::Point goal, sim::Point from) {
    const double yaw = sim::distance(from, goal) > 1e-6
                           ? std::atan2(goal.y - from.y, goal.x - from.x)
                           : pose.theta;
    geometry_msgs::PoseStamped message;
    message.header.stamp = ros::Time::now();
    message.header.frame_id = options.goal_frame;
    message.pose.position.x = goal.x;
    message.pose.position.y = goal.y;
    message.pose.orientation.z = std::sin(yaw / 2);
    message.pose.orientation.w = std::cos(yaw / 2);
    publishers.publish("goal", message);
  }

  // Ends the navigation; its callback runs on the spinner thread, never in the caller.
  void finish(bool arrived, std::string detail) {
    NavigationResult result{arrived, odometer - navigation->odometer_at_start, std::move(detail)};
    node.post([done = std::move(navigation->done), result = std::move(result)] { done(result); });
    navigation.reset();
  }

  const RosRobotOptions options;
  const std::shared_ptr<const MapPlanner> map;
  const SteadyClock::time_point started;
  // Declared first, destroyed last: its destructor runs completions still queued.
  ros_layer::Node node;
  ros_layer::PublishersManager publishers{node};
  ros_layer::SubscribersManager subscribers{node};
  ros::SteadyTimer watchdog;

  mutable std::mutex mutex;
  bool have_odometry = false;
  sim::Pose pose;
  double odometer = 0;
  SteadyClock::time_point last_odometry{};
  std::optional<Navigation> navigation;
};

RosRobot::RosRobot(RosRobotOptions options, std::shared_ptr<const MapPlanner> map)
    : options_(std::move(options)) {
  impl_ = std::make_unique<Impl>(options_, std::move(map));
}

RosRobot::~RosRobot() {
  impl_->watchdog.stop();             // waits for a running check
  impl_->subscribers.remove("odom");  // waits for a running odometry callback
  {
    std::lock_guard lock(impl_->mutex);
    if (impl_->navigation) impl_->finish(false, "robot shut down");
  }
  impl_.reset();  // the node runs the completions still queued
}

sim::Pose RosRobot::pose() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->pose;
}

RobotStatus RosRobot::status() const {
  std::lock_guard lock(impl_->mutex);
  const auto heard = impl_->have_odometry ? impl_->last_odometry : impl_->started;
  if (SteadyClock::now() - heard >= options_.progress_timeout) return RobotStatus::failed;
  return impl_->navigation ? RobotStatus::moving : RobotStatus::idle;
}

void RosRobot::navigate_to(sim::Point target, std::function<void(NavigationResult)> done) {
  std::lock_guard lock(impl_->mutex);
  if (impl_->navigation) impl_->finish(false, "superseded by a navigation to " + describe(target));
  Impl::Navigation nav;
  nav.target = target;
  nav.done = std::move(done);
  nav.odometer_at_start = impl_->odometer;
  nav.progress_mark = impl_->odometer;
  nav.progress_time = SteadyClock::now();
  impl_->navigation = std::move(nav);
  if (impl_->have_odometry) impl_->plan();
}

void RosRobot::stop() {
  std::lock_guard lock(impl_->mutex);
  if (impl_->navigation) impl_->finish(false, "stopped");
  if (impl_->have_odometry) impl_->send_goal(impl_->pose.position(), impl_->pose.position());
}

double RosRobot::odometer() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->odometer;
}

double RosRobot::clock_seconds() const { return seconds(SteadyClock::now() - impl_->started); }

bool RosRobot::has_odometry() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->have_odometry;
}

std::string RosRobot::odom_topic() const { return impl_->subscribers.topic("odom"); }
std::string RosRobot::goal_topic() const { return impl_->publishers.topic("goal"); }

std::shared_ptr<Robot> make_ros_robot(const AgentConfiguration& config,
                                      std::shared_ptr<const MapPlanner> map) {
  if (!ros_layer::initialized()) ros_layer::init("coros_" + config.id);
  RosRobotOptions options;
  options.id = config.id;
  options.ns = config.ros_namespace;
  return std::make_shared<RosRobot>(std::move(options), std::move(map));
}

}  // namespace icars::coros
