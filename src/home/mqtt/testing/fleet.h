// Test support: a small home's MQTT devices as zigbee2mqtt and Tasmota present them — their own
// MQTT client that publishes retained Home Assistant discovery configs, availability and states,
// and obeys the command topics by changing the device and publishing its new state (after a
// delay, or never, when told to).
//
// Devices (name: component, what it shows the bridge):
//   bedroom_lamp  light, json schema, brightness 0..255, area "Bedroom"; available when both
//                 zigbee2mqtt/bridge/state ({"state":"online"}) and its own topic say online
//   living_lamp   light, default schema (Tasmota, abbreviated keys), dimmer 0..100 on its own
//                 topics, area "Living Room", availability "Online"/"Offline"
//   kettle        switch (a plug), state {"state":"ON"} read by value_template, area "Kitchen"
//   bed_sensor    binary_sensor, device_class occupancy, state {"occupancy":true,...} read by
//                 value_template with payload_on true, area "Bedroom"
//   hall_motion   binary_sensor, device_class motion, plain "ON"/"OFF", area "Hallway"
//   bedroom_temp  sensor, device_class temperature in °C, state {"temperature":21.5,...} read by
//                 value_template, area "Bedroom"
//   living_blind  cover (ESPHome): "OPEN"/"CLOSE"/"STOP" commands, plain states "opening" then
//                 "open", "closing" then "closed"; starts closed; area "Living Room"
//   bedroom_fan   fan (ESPHome), plain "ON"/"OFF" on its command and state topics, area "Bedroom"
//   living_thermostat
//                 climate (a zigbee2mqtt radiator valve): modes off, heat and auto on
//                 .../set/system_mode, state {"system_mode":"off",...}; area "Living Room"
#pragma once

#include <asio/executor_work_guard.hpp>
#include <asio/io_context.hpp>
#include <chrono>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "icars/bridge/mqtt/client.h"

namespace mqtt_test {

inline constexpr const char* kFleetDevices[] = {"bedroom_lamp", "living_lamp", "kettle",
                                                "bed_sensor",   "hall_motion", "bedroom_temp",
                                                "living_blind", "bedroom_fan", "living_thermostat"};

class Fleet {
 public:
  explicit Fleet(int broker_port);
  ~Fleet();
  Fleet(const Fleet&) = delete;
  Fleet& operator=(const Fleet&) = delete;

  // Connects (throws std::runtime_error when it cannot within 20 s), subscribes to the command
  // topics and publishes every device's availability ("online"), state (off, unoccupied, no
  // motion) and discovery config, all retained.
  void start();

  // --- Knobs ---
  void set_delay(std::chrono::milliseconds delay);  // a command's new state is published this late
  void ignore_commands(bool ignore);                // counted, but neither obeyed nor answered
  void set_online(const std::string& device, bool online);  // its own availability topic
  void set_bridge_online(bool online);  // zigbee2mqtt/bridge/state (bedroom_lamp needs it too)
  void set_sensor(const std::string& device, bool on);            // bed_sensor or hall_motion
  void set_measurement(const std::string& device, double value);  // bedroom_temp
  void publish(const std::string& topic, const std::string& payload, bool retain = false);

  // --- What the devices are ---
  // nullopt: unknown device. A thermostat is on in any mode but "off"; a cover is never on.
  std::optional<bool> on(const std::string& device) const;
  std::string position(const std::string& device) const;  // a cover's: "open", "closed"
  std::string mode(const std::string& device) const;      // a thermostat's: "off", "heat"
  int brightness(const std::string& device) const;        // on the device's own scale
  int commands(const std::string& device) const;          // commands received
  static std::string unique_id(const std::string& device);
  static std::string config_topic(const std::string& device);
  static std::string config(const std::string& device);  // its discovery config (JSON)
  static std::string command_topic(const std::string& device);
  static std::string state_topic(const std::string& device);

 private:
  struct Device {
    bool on = false;
    int brightness = 0;
    int commands = 0;
    double value = 21.5;              // a sensor's reading
    std::string position = "closed";  // a cover's
    std::string mode = "off";         // a thermostat's
  };
  void on_command(const icars::bridge::mqtt::Message& m);
  // Publishes the device's state (retained), as that device shows it.
  void publish_state(const std::string& device);

  icars::bridge::mqtt::Client client_;
  asio::io_context io_;
  asio::executor_work_guard<asio::io_context::executor_type> work_;
  std::thread thread_;  // runs io_ (delayed state reports)
  mutable std::mutex mutex_;
  std::map<std::string, Device> devices_;
  std::chrono::milliseconds delay_{0};
  bool ignore_ = false;
};

}  // namespace mqtt_test
