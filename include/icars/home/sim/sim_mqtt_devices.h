// A simulated house's MQTT devices (the <device>s with an `mqtt` unique_id, docs/house.md):
// the lights and sensors of the simulated world served on an MQTT broker the way zigbee2mqtt
// serves real ones — retained Home Assistant discovery configs, JSON states, command topics and
// an availability topic with a last will — so that the house reaches the mediating server
// through an MQTT bridge (home::mqtt::MqttDevices) exactly as a real home does. It is what
// `icars run --mqtt` and `icars-device-manager --mqtt` run.
//
//   SimulatedMqttDevices sim(world, mqtt_devices(house), effects, options);
//   sim.start();                  // connects, publishes configs and states
//   ...
//   bridge_options.handled = [&](const auto& m) { sim.handled(m); };   // lock-step
//
// Topics, for a device `living_light` under base topic `icars-sim`:
//   icars-sim/living_light            its state, retained: {"state":"ON","brightness":254} or
//                                     {"occupancy":true}
//   icars-sim/living_light/set        commands to a light: {"state":"ON","brightness":N}
//   icars-sim/bridge/state            "online" while the house runs, "offline" (the last will)
//   homeassistant/light/icars-sim/living_light/config   (binary_sensor/... for sensors)
//
// Device types: Light (a `light`, json schema, brightness 0..254), BedOccupancy, SofaOccupancy
// and Occupancy (a `binary_sensor` of device_class occupancy), MotionSensor (device_class
// motion). A light's commands change it and are reported as the house's effects ("power",
// "intensity"), as the simulated Light reports its PLANET commands.
#pragma once

#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "icars/bridge/mqtt/client.h"
#include "icars/clock/activity.h"
#include "icars/home/mqtt/entity_devices.h"
#include "icars/home/sim/sim_devices.h"
#include "icars/sim/house.h"
#include "icars/sim/world.h"

namespace spdlog {
class logger;
}

namespace icars::home {

// The device types SimulatedMqttDevices can serve.
bool simulated_over_mqtt(const std::string& type);

// The house's MQTT devices (those with an `mqtt` unique_id). Throws sim::HouseError at the
// line of one whose type cannot be simulated over MQTT.
std::vector<const sim::DeviceSpec*> mqtt_devices(const sim::House& house);

// The bridge's placements for the house's MQTT devices: each unique_id as the house's device
// id, room and (for occupancy sensors) furniture, so policies use the house's names.
mqtt::PlacementTable mqtt_placements(const sim::House& house);

struct SimulatedMqttOptions {
  bridge::mqtt::ClientOptions broker;  // client_id default: "icars-sim-<house name>"
  std::string discovery_prefix = "homeassistant";
  std::string base_topic = "icars-sim";
  // Lock-step (icars/clock/activity.h): a state published holds this activity until an MQTT
  // bridge of this process has handled it (handled()). Null: nothing is held.
  std::shared_ptr<Activity> activity;
  std::shared_ptr<spdlog::logger> logger;  // default: stderr, named "sim-mqtt"
};

class SimulatedMqttDevices {
 public:
  // `devices` are the house's (mqtt_devices()); the world must outlive this object. Throws
  // std::invalid_argument for a type it cannot serve or bad broker options.
  SimulatedMqttDevices(sim::World& world, std::vector<const sim::DeviceSpec*> devices, EffectObserver effects,
                       SimulatedMqttOptions options);
  ~SimulatedMqttDevices();  // stop()
  SimulatedMqttDevices(const SimulatedMqttDevices&) = delete;
  SimulatedMqttDevices& operator=(const SimulatedMqttDevices&) = delete;

  // Connects, waiting up to `timeout`; on this and every later connection publishes every
  // device's discovery config, its state and the availability, all retained. Throws
  // bridge::mqtt::Error when the broker cannot be reached or refuses the house.
  void start(std::chrono::milliseconds timeout = std::chrono::seconds(20));
  // Marks the devices offline (their configs stay, as zigbee2mqtt's do) and disconnects.
  // Idempotent.
  void stop();

  // An MQTT bridge of this process handled `message`: in lock-step, the states it published on
  // that topic are done (a retained message, delivered on subscribing, stands for all of them).
  void handled(const bridge::mqtt::Message& message);

  std::string state_topic(const std::string& device_id) const;
  std::string command_topic(const std::string& device_id) const;
  std::string availability_topic() const;
  std::size_t held() const;  // states published and not yet handled by a bridge (lock-step)

 private:
  struct Device;
  void on_command(const bridge::mqtt::Message& message);
  void on_user(const sim::UserState& user);
  void publish_all();
  void publish_state(Device& device);

  sim::World& world_;
  EffectObserver effects_;
  SimulatedMqttOptions options_;
  std::shared_ptr<spdlog::logger> log_;
  std::unique_ptr<bridge::mqtt::Client> client_;
  std::vector<std::unique_ptr<Device>> devices_;
  std::map<std::string, Device*> by_command_topic_;
  std::uint64_t world_listener_ = 0;
  mutable std::mutex mutex_;  // the devices' states and holds_
  std::map<std::string, std::deque<Activity::Hold>> holds_;  // by state topic
  bool started_ = false;
};

}  // namespace icars::home
