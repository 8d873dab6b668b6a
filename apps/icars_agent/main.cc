// icars-agent: runs one COROS agent from a configuration file (docs/coros.md).
//
//   icars-agent robot1.json             a robot: discovery + courier bids and deliveries
//   icars-agent user.json               a user: discovery + auctions its deliveries
//   icars-agent monitor.json            a monitor: prints the neighbourhood and task tables
//
// Events go to stdout as JSON lines ({"event":"awarded",...}), for scripts and the scenario
// command; the monitor's tables go to stderr, as do warnings (datagrams dropped for failing
// authentication, an insecure agent). The configuration must hold the fleet key ('key_file' or
// 'key') or say 'insecure'. SIGINT/SIGTERM stop the agent cleanly; a user with exit_when_done
// stops after its last delivery.
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <mutex>
#include <thread>

#include "icars/coros/agent.h"
#include "icars/coros/courier.h"
#include "icars/coros/discovery.h"
#include "icars/coros/monitor.h"
#include "icars/coros/robot.h"
#ifdef ICARS_WITH_ROS
#include "icars/coros/ros/ros_layer.h"
#include "icars/coros/ros/ros_robot.h"
#endif

namespace {

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) { g_stop = true; }

using namespace icars::coros;

void write_track(const std::string& path, const std::string& id, const SimRobot& robot) {
  nlohmann::json points = nlohmann::json::array();
  for (const auto& [t, p] : robot.track()) {
    points.push_back({std::chrono::duration<double>(t).count(), p.x, p.y});
  }
  const nlohmann::json doc = {{"robot", id}, {"distance", robot.odometer()}, {"points", points}};
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp);
    out << doc.dump() << "\n";
  }
  std::rename(tmp.c_str(), path.c_str());
}

int run(const std::string& config_file, int monitor_ms) {
  const AgentConfiguration config = AgentConfiguration::load(config_file);
  std::shared_ptr<const MapPlanner> map;
  if (!config.map.empty()) {
    map = MapPlanner::load(config.map.string(), config.radius, config.field_cache);
  }

  Agent agent(config);
  std::mutex out_mutex;
  std::atomic<bool> done{false};
  agent.set_event_sink([&](const nlohmann::json& event) {
    {
      std::lock_guard lock(out_mutex);
      std::cout << event.dump() << std::endl;
    }
    if (event.value("event", "") == "all_done" && config.exit_when_done) done = true;
  });
  agent.add_operator(std::make_shared<DiscoveryOperator>());

  std::shared_ptr<Robot> robot;
  std::shared_ptr<SimRobot> sim_robot;
#ifdef ICARS_WITH_ROS
  std::unique_ptr<ros_layer::KnowledgePublisher> knowledge;
#endif
  if (config.role == "robot") {
    if (config.robot_kind == "ros") {
#ifdef ICARS_WITH_ROS
      ros_layer::init("icars_agent_" + config.id);
      robot = make_ros_robot(config, map);
#else
      throw CorosError("this icars-agent was built without ROS; robot kind 'ros' is unavailable");
#endif
    } else {
      SimRobotOptions o;
      o.id = config.id;
      const std::string start = config.start.empty() ? "0,0" : config.start;
      const icars::sim::Point p = map->locate(start);
      o.start = icars::sim::Pose{p.x, p.y, 0};
      o.speed = config.speed;
      o.radius = config.radius;
      o.speedup = config.speedup;
      sim_robot = std::make_shared<SimRobot>(map->house(), o);
      robot = sim_robot;
    }
    agent.add_operator(std::make_shared<CourierRobotOperator>(robot, map));
  } else if (config.role == "user") {
    if (!map) throw CorosError(config_file + ": a user needs a 'map' to place its deliveries");
    agent.add_operator(std::make_shared<CourierUserOperator>(map));
  } else {
    agent.add_operator(std::make_shared<TaskObserverOperator>());
  }
#ifdef ICARS_WITH_ROS
  if (config.robot_kind == "ros")
    knowledge = std::make_unique<ros_layer::KnowledgePublisher>(agent);
#endif

  agent.start();
  if (sim_robot && !config.track_file.empty()) {
    write_track(config.track_file.string(), config.id, *sim_robot);  // even if killed soon
  }
  auto last_track = std::chrono::steady_clock::now();
  auto last_table = last_track;
  while (!g_stop && !done) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const auto now = std::chrono::steady_clock::now();
    if (sim_robot && !config.track_file.empty() && now - last_track > std::chrono::seconds(2)) {
      write_track(config.track_file.string(), config.id, *sim_robot);
      last_track = now;
    }
    if (config.role == "monitor" && now - last_table > std::chrono::milliseconds(monitor_ms)) {
      last_table = now;
      const std::string table = agent.call([&] {
        return render_neighbors(agent.neighbors(), Clock::now()) + "\n" +
               render_tasks(agent.tasks()) + "\n" + render_datagram_stats(agent.stats());
      });
      std::lock_guard lock(out_mutex);
      std::cerr << "\n" << table << std::flush;
    }
  }
  agent.stop();
  if (sim_robot && !config.track_file.empty()) {
    write_track(config.track_file.string(), config.id, *sim_robot);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"icars-agent: one COROS agent (robot, user or monitor) from a JSON configuration"};
  std::string config;
  int monitor_ms = 1000;
  app.add_option("config", config, "the agent's configuration (docs/coros.md)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--monitor-interval", monitor_ms, "monitor: milliseconds between tables")
      ->check(CLI::Range(50, 600000));
  CLI11_PARSE(app, argc, argv);
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  try {
    return run(config, monitor_ms);
  } catch (const std::exception& e) {
    std::cerr << "icars-agent: " << e.what() << "\n";
    return 2;
  }
}
