// `icars run --mqtt BROKER` on a house with MQTT devices (docs/house.md, "MQTT devices"): the
// embedded house serves them on the broker as zigbee2mqtt would (home::SimulatedMqttDevices),
// and an MQTT bridge in this process — its own MQTT client, PLANET link and device manager, as
// `icars-mqtt-bridge` runs elsewhere — brings them to the mediating server. In lock-step, a
// state on its way through the broker holds the clock until the bridge has handled it.
#pragma once

#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "icars/bridge/mqtt/client.h"
#include "icars/clock/activity.h"
#include "icars/clock/sim_clock.h"
#include "icars/device/device_manager.h"
#include "icars/home/mqtt/entity_devices.h"
#include "icars/home/sim/sim_mqtt_devices.h"
#include "icars/planet/communicator.h"
#include "icars/service/device_registry.h"
#include "icars/sim/house.h"

namespace icars::app {

struct EmbeddedMqttOptions {
  bridge::mqtt::ClientOptions broker;  // host, port, TLS, user: the bridge's; the house's copy
  std::string pun = "mqtt-bridge";     // the bridge's PLANET name
  std::string token;                   // authenticates it to the mediating server
  planet::TlsOptions tls;              // TLS to the mediating server
  std::shared_ptr<Activity> activity;  // lock-step; null: none
  std::shared_ptr<spdlog::logger> logger;
};

class EmbeddedMqttBridge {
 public:
  // `clock` stamps the sensor events; it must outlive the bridge.
  EmbeddedMqttBridge(const sim::House& house, SimClock& clock, EmbeddedMqttOptions options);
  ~EmbeddedMqttBridge();
  EmbeddedMqttBridge(const EmbeddedMqttBridge&) = delete;
  EmbeddedMqttBridge& operator=(const EmbeddedMqttBridge&) = delete;

  // Connects to the broker and to the mediating server; in lock-step, what the bridge handles
  // releases the states `house` published (null: nothing to release).
  void start(const std::string& host, std::uint16_t port, home::SimulatedMqttDevices* house);
  // Waits until every MQTT device of the house is registered with `registry`. False after
  // `timeout`, with what is missing in `why`.
  bool wait_registered(const service::DeviceRegistry& registry, std::chrono::milliseconds timeout, std::string& why);
  // Stops bridging: the broker link closes first, then the devices' PLANET link.
  void stop();

 private:
  std::vector<std::string> device_ids_;
  EmbeddedMqttOptions options_;
  home::SimulatedMqttDevices* house_ = nullptr;
  std::unique_ptr<bridge::mqtt::Client> client_;
  std::unique_ptr<planet::Communicator> communicator_;
  std::unique_ptr<device::DeviceManager> manager_;
  std::unique_ptr<home::mqtt::MqttDevices> devices_;
};

}  // namespace icars::app
