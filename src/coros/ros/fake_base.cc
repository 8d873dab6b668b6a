// coros_ros_fake_base: a stand-in ROS robot base for tests and demos. It takes goals on
// /<ns>/move_base_simple/goal (geometry_msgs/PoseStamped), drives straight towards the latest
// one at --speed, integrating at 50 Hz of wall time, and publishes /<ns>/odom
// (nav_msgs/Odometry) at 20 Hz. It prints "ready" once both topics are set up. No obstacles:
// planning around walls is the caller's job (RosRobot with a map sends the path's corners).
//
//   coros_ros_fake_base --ns robot1 --x 1 --y 2 --speed 2.0
#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Odometry.h>
#include <ros/ros.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <mutex>
#include <optional>
#include <thread>

namespace {

struct Goal {
  double x = 0;
  double y = 0;
};

nav_msgs::Odometry odometry(double x, double y, double theta, double speed) {
  nav_msgs::Odometry message;
  message.header.stamp = ros::Time::now();
  message.header.frame_id = "odom";
  message.child_frame_id = "base_link";
  message.pose.pose.position.x = x;
  message.pose.pose.position.y = y;
  message.pose.pose.orientation.z = std::sin(theta / 2);
  message.pose.pose.orientation.w = std::cos(theta / 2);
  message.twist.twist.linear.x = speed;
  return message;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"A fake ROS robot base: drives straight to goals and publishes odometry"};
  std::string ns = "robot1";
  double x = 0, y = 0, theta = 0, speed = 0.5;
  app.add_option("--ns", ns, "topic namespace: /<ns>/odom, /<ns>/move_base_simple/goal");
  app.add_option("--x", x, "start x (metres)");
  app.add_option("--y", y, "start y (metres)");
  app.add_option("--theta", theta, "start heading (radians)");
  app.add_option("--speed", speed, "driving speed (m/s)")->check(CLI::PositiveNumber);
  CLI11_PARSE(app, argc, argv);

  ros::init(ros::M_string{}, "fake_base_" + ns, ros::init_options::AnonymousName);
  ros::NodeHandle node("/" + ns);
  std::mutex mutex;
  std::optional<Goal> goal;
  ros::Publisher odom = node.advertise<nav_msgs::Odometry>("odom", 20);
  ros::Subscriber goals = node.subscribe<geometry_msgs::PoseStamped>(
      "move_base_simple/goal", 10, [&](const geometry_msgs::PoseStamped::ConstPtr& message) {
        std::lock_guard lock(mutex);
        goal = Goal{message->pose.position.x, message->pose.position.y};
      });
  ros::AsyncSpinner spinner(1);
  spinner.start();
  std::cout << "ready" << std::endl;

  using Clock = std::chrono::steady_clock;
  constexpr auto kStep = std::chrono::milliseconds(20);            // 50 Hz integration
  constexpr auto kOdometryPeriod = std::chrono::milliseconds(50);  // 20 Hz odometry
  auto last = Clock::now();
  auto next_odometry = last;
  while (ros::ok()) {
    std::this_thread::sleep_until(last + kStep);
    const auto now = Clock::now();
    const double dt = std::chrono::duration<double>(now - last).count();
    last = now;
    double velocity = 0;
    {
      std::lock_guard lock(mutex);
      if (goal) {
        const double dx = goal->x - x, dy = goal->y - y;
        const double left = std::hypot(dx, dy);
        const double step = std::min(left, speed * dt);
        if (left > 1e-9) {
          theta = std::atan2(dy, dx);
          x += dx / left * step;
          y += dy / left * step;
          velocity = speed;
        }
        if (step >= left) goal.reset();  // arrived
      }
    }
    if (now >= next_odometry) {
      odom.publish(odometry(x, y, theta, velocity));
      next_odometry = now + kOdometryPeriod;
    }
  }
  spinner.stop();
  return 0;
}
