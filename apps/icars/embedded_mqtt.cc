#include "embedded_mqtt.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <thread>

namespace icars::app {

EmbeddedMqttBridge::EmbeddedMqttBridge(const sim::House& house, SimClock& clock, EmbeddedMqttOptions options)
    : options_(std::move(options)) {
  for (const auto* spec : home::mqtt_devices(house)) device_ids_.push_back(spec->id);
  auto broker = options_.broker;
  broker.client_id = "icars-mqtt-bridge-" + house.name;
  client_ = std::make_unique<bridge::mqtt::Client>(broker);
  planet::CommunicatorOptions comm;
  comm.name = "mqtt-bridge";
  comm.pun = options_.pun;
  comm.tls = options_.tls;
  comm.token = options_.token;
  comm.logger = options_.logger;
  comm.connection.activity = options_.activity;
  communicator_ = std::make_unique<planet::Communicator>(comm);
  manager_ = std::make_unique<device::DeviceManager>(*communicator_);
  home::mqtt::MqttDevicesOptions devices;
  devices.placements = home::mqtt_placements(house);
  devices.now_ms = [&clock] { return static_cast<std::int64_t>(clock.now().count()); };
  devices.logger = options_.logger;
  devices.activity = options_.activity;
  devices.handled = [this](const bridge::mqtt::Message& m) {
    if (house_) house_->handled(m);
  };
  devices_ = std::make_unique<home::mqtt::MqttDevices>(*client_, *manager_, std::move(devices));
}

EmbeddedMqttBridge::~EmbeddedMqttBridge() { stop(); }

void EmbeddedMqttBridge::start(const std::string& host, std::uint16_t port, home::SimulatedMqttDevices* house) {
  house_ = house;
  client_->start();
  manager_->connect(host, port);
}

bool EmbeddedMqttBridge::wait_registered(const service::DeviceRegistry& registry, std::chrono::milliseconds timeout,
                                         std::string& why) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    std::vector<std::string> missing;
    for (const auto& id : device_ids_) {
      if (!registry.holder(id)) missing.push_back(id);
    }
    if (missing.empty()) return true;
    if (std::chrono::steady_clock::now() >= until) {
      const auto broker = client_->connected() ? std::string("connected")
                                               : "not connected: " + client_->last_error();
      why = fmt::format("the house's MQTT devices {} did not come through the MQTT bridge (broker {}:{} {}; "
                        "problems: {})",
                        fmt::join(missing, ", "), options_.broker.host, options_.broker.port, broker,
                        devices_->problems().empty() ? "none" : fmt::format("{}", fmt::join(devices_->problems(), "; ")));
      return false;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

void EmbeddedMqttBridge::stop() {
  if (!client_) return;
  client_->stop();
  devices_.reset();
  manager_.reset();
  communicator_.reset();
  client_.reset();
}

}  // namespace icars::app
