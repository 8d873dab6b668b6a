// The mediating server as Home Assistant sees it: what a Home Assistant user wants to see and do
// with the robotic mediator, published over MQTT with Home Assistant's discovery convention —
// the way back of the MQTT bridge (docs/mqtt.md, "Home Assistant's view").
//
//   HomeAssistantPublisher ha(server, broker, {.node_id = "icars_paper_house", .devices = ...});
//   ha.start();   // connects; configs and states retained, availability with a last will
//   ...
//   ha.stop();    // removes every config and state it published, says offline
//
// Entities, all under one Home Assistant device (`node_id`), with `<base>` = base_topic/node_id:
//   select  Policy          the running policy, chosen from the policy repository; choosing one
//                           runs it (MediatingServer::run_policy); a policy that does not load
//                           keeps the old one running, and its file:line errors show in
//   sensor  Policy error    (<base>/policy/error)
//   sensor  State           the active states, innermost last (<base>/policy/state), with the
//                           configuration, the tasks and the last transition as attributes
//   sensor  Task            the running tasks
//   button  one per event the policy's transitions wait for ("Time to sleep" for TimeToSleep):
//                           pressing it raises the event in the policy (MediatingServer::raise)
//   sensor  <robot> room, <robot> activity   where each robot is (room, x, y) and what it does
//   sensor  <device>        each device's state from what it did (power, channel, playing, ...)
// What the server does reaches the publisher through its trace (behavior::Trace); publishing
// runs on the publisher's own thread, so a slow or absent broker never slows the mediator
// (robot positions are sent at most every `position_interval`).
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "icars/bridge/mqtt/client.h"
#include "icars/server/mediating_server.h"

namespace spdlog {
class logger;
}

namespace icars::home::mqtt {

struct HomeAssistantOptions {
  std::string node_id = "icars";  // the Home Assistant device; prefixes every unique_id
  std::string name = "ICARS mediator";
  std::string discovery_prefix = "homeassistant";
  std::string base_topic = "icars";  // states and commands under <base_topic>/<node_id>/
  struct Device {
    std::string id, type, room;
    std::string carrier;  // the robot carrying it ("" for a static device)
  };
  std::vector<Device> devices;      // shown as sensors (ICARS's own devices)
  struct Robot {
    std::string id;
    double x = 0, y = 0;  // where it starts
  };
  std::vector<Robot> robots;  // shown as room and activity sensors
  std::function<std::string(double x, double y)> room_at;  // the room at a point; empty: unknown
  std::chrono::milliseconds position_interval{500};
  std::shared_ptr<spdlog::logger> logger;  // default: stderr, named "home-assistant"
};

class HomeAssistantPublisher {
 public:
  // Attaches to the server's trace; nothing is published before start(). The server must
  // outlive the publisher. Throws std::invalid_argument for a node_id that is not a name
  // (letters, digits, '_', '-') and for bad broker options.
  HomeAssistantPublisher(server::MediatingServer& server, bridge::mqtt::ClientOptions broker,
                         HomeAssistantOptions options);
  ~HomeAssistantPublisher();  // stop()
  HomeAssistantPublisher(const HomeAssistantPublisher&) = delete;
  HomeAssistantPublisher& operator=(const HomeAssistantPublisher&) = delete;

  // Connects (bridge::mqtt::Error when the broker cannot be reached within `timeout` or refuses
  // the publisher) and publishes everything; again on every later connection.
  void start(std::chrono::milliseconds timeout = std::chrono::seconds(20));
  // Removes every config and state it published (empty retained messages), publishes offline
  // and disconnects. Idempotent.
  void stop();

  std::string availability_topic() const;
  std::string topic(const std::string& path) const;  // <base_topic>/<node_id>/<path>
  std::uint64_t published() const;  // messages published so far
  std::vector<std::string> problems() const;  // commands refused, each once: "<topic>: <why>"

  struct State;  // shared with the trace sink, which may outlive the publisher

 private:
  std::shared_ptr<State> state_;
};

}  // namespace icars::home::mqtt
