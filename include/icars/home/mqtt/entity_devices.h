// A real home's MQTT devices as ICARS devices: the entities that zigbee2mqtt, Tasmota, ESPHome
// or Shelly announce through Home Assistant's MQTT discovery become DF devices whose
// capabilities implement the home's interfaces (idl/home.idl), served and registered with the
// mediating server by a DeviceManager — so policies written for the simulated house run on
// them unchanged.
//
//   bridge::mqtt::Client client(options);               // not started yet
//   device::DeviceManager manager(communicator);
//   home::mqtt::MqttDevices devices(client, manager, {.placements = table});
//   client.start();
//   manager.connect(host, port);
//
// One device per discovered entity, by component:
//   light (default and json schemas)     capability `light`      home::Light  (intensity in
//                                                                percent of brightness_scale)
//   switch                               capability `switch`     home::Light  (on/off only)
//   binary_sensor, class occupancy or presence
//                                        capability `occupancy`  home::OccupancySensor
//   binary_sensor, class motion          capability `motion`     home::MotionSensor
//   sensor, class temperature, humidity, illuminance, pressure, carbon_dioxide, ...
//                                        capability `measurement` home::MeasurementSensor
//                                        (quantity: the device class; unit: unit_of_measurement)
//   cover                                capability `cover`      home::Cover
//   fan                                  capability `fan`        home::PowerSwitch
//   climate (modes with "off" and another)
//                                        capability `climate`    home::PowerSwitch (by its mode:
//                                        "off", or the mode it last ran in)
// Any other entity is logged once (its config topic and why) and left out.
//
// A command is published to the entity's command topic and acknowledged only when its state
// topic reports the wanted state; without that within `command_timeout` the call fails with
// planet::Error(timeout) naming the entity, the command topic and the timeout. A command for an
// entity that is offline, or while the client is not connected to the broker, fails at once
// (planet::Error(failed)) with the reason. A cover's open and close are confirmed once it
// reports moving that way (or being there), its stop once it reports not moving. An entity
// without a state topic is optimistic: its commands are acknowledged once published. Sensors
// publish an event on every change of their state topic; a state that contradicts the entity's
// config (a reading that is not a number, an unknown mode) is logged once and ignored. An entity
// whose availability says offline is unregistered from the server (its services leave the
// container) and registered again when it is back online.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "icars/bridge/mqtt/client.h"
#include "icars/clock/activity.h"
#include "icars/device/device_manager.h"

namespace spdlog {
class logger;
}

namespace icars::home::mqtt {

// A name made of `text` for MQTT topic levels, unique ids and device ids: letters, digits, '_'
// and '-' kept, anything else '_' ("0x00:17/light" → "0x00_17_light").
std::string name_of(std::string_view text);

// Where an entity stands in the house.
struct Placement {
  std::string device_id;  // the ICARS device id
  std::string room;       // "bedroom"
  std::string furniture;  // what an occupancy sensor watches: "bed", "sofa"
};

// Placements by the entity's unique_id. An entity without one gets its unique id as device id
// (characters other than letters, digits, '_' and '-' become '_') and its config's area as
// room, lower-cased with spaces as '_' ("Living Room" → "living_room").
using PlacementTable = std::map<std::string, Placement>;

struct MqttDevicesOptions {
  std::string discovery_prefix = "homeassistant";
  std::chrono::milliseconds command_timeout{5000};  // for the state topic to confirm a command
  PlacementTable placements;
  // Time stamps of sensor events, in ms; default: the system clock since the epoch.
  std::function<std::int64_t()> now_ms;
  std::shared_ptr<spdlog::logger> logger;  // default: a stderr logger named "mqtt-devices"
  // Told after each message from the broker was handled (the device events it caused
  // published), on the client's network thread, also for messages the bridge had no use for.
  // A simulated house in lock-step in this process waits for it before its clock moves
  // (home::SimulatedMqttDevices::handled).
  std::function<void(const bridge::mqtt::Message&)> handled;
  // Lock-step (icars/clock/activity.h): a command waiting for its device to confirm it holds
  // this activity, so a simulated clock of this process does not move meanwhile. Null: none.
  std::shared_ptr<Activity> activity;
};

// One entity the bridge made a device of.
struct EntityDevice {
  std::string unique_id;
  std::string device_id;
  // "Light", "Switch", "Occupancy", "MotionSensor", "MeasurementSensor", "Cover", "Fan",
  // "Climate"
  std::string type;
  std::string room;
  std::string config_topic;
  bool online = false;  // registered with the server (or to be, once the link is up)
};

class MqttDevices {
 public:
  // Takes the client's message callback and subscribes to the discovery topics
  // (`<prefix>/+/+/config`, `<prefix>/+/+/+/config`): construct it before client.start(). The
  // client and the manager must outlive it; afterwards the capabilities it made fail every
  // command with "the MQTT bridge is closed".
  MqttDevices(bridge::mqtt::Client& client, device::DeviceManager& manager,
              MqttDevicesOptions options = {});
  ~MqttDevices();
  MqttDevices(const MqttDevices&) = delete;
  MqttDevices& operator=(const MqttDevices&) = delete;

  std::vector<EntityDevice> devices() const;
  // What was logged as a problem, each once: "<topic>: <why>" (configs left out, states that
  // contradict their entity's schema, availability payloads of neither kind); at most 1024.
  std::vector<std::string> problems() const;

  class Core;  // shared with the capabilities and the client's callback

 private:
  std::shared_ptr<Core> core_;
};

}  // namespace icars::home::mqtt
