#include "fleet.h"

#include <fmt/format.h>

#include <asio/post.hpp>
#include <asio/steady_timer.hpp>
#include <charconv>
#include <nlohmann/json.hpp>
#include <stdexcept>

namespace mqtt_test {

namespace bm = icars::bridge::mqtt;
using nlohmann::json;

namespace {

bm::ClientOptions options_for(int port) {
  bm::ClientOptions o;
  o.port = port;
  o.client_id = "test-fleet";
  return o;
}

std::string availability_topic(const std::string& device) {
  if (device == "living_lamp") return "tasmota/living_lamp/tele/LWT";
  return "zigbee2mqtt/" + device + "/availability";
}

constexpr const char* kBridgeState = "zigbee2mqtt/bridge/state";

// The discovery configs, as zigbee2mqtt and Tasmota write them.
json config_of(const std::string& device) {
  if (device == "bedroom_lamp") {
    return {{"name", "Bedroom lamp"},
            {"unique_id", Fleet::unique_id(device)},
            {"schema", "json"},
            {"brightness", true},
            {"brightness_scale", 255},
            {"state_topic", Fleet::state_topic(device)},
            {"command_topic", Fleet::command_topic(device)},
            {"availability_mode", "all"},
            {"availability",
             {{{"topic", kBridgeState}, {"value_template", "{{ value_json.state }}"}},
              {{"topic", availability_topic(device)}}}},
            {"device",
             {{"identifiers", {"zigbee2mqtt_0x0017880100000001"}},
              {"name", "bedroom_lamp"},
              {"suggested_area", "Bedroom"}}}};
  }
  if (device == "living_lamp") {  // Tasmota: abbreviated keys and a base topic
    return {{"name", "Living lamp"},
            {"uniq_id", Fleet::unique_id(device)},
            {"~", "tasmota/living_lamp/"},
            {"stat_t", "~stat/POWER"},
            {"cmd_t", "~cmnd/POWER"},
            {"bri_stat_t", "~stat/Dimmer"},
            {"bri_cmd_t", "~cmnd/Dimmer"},
            {"bri_scl", 100},
            {"pl_on", "ON"},
            {"pl_off", "OFF"},
            {"avty_t", "~tele/LWT"},
            {"pl_avail", "Online"},
            {"pl_not_avail", "Offline"},
            {"dev", {{"ids", {"A1B2C3"}}, {"name", "Living lamp"}, {"sa", "Living Room"}}}};
  }
  if (device == "kettle") {
    return {{"name", "Kettle"},
            {"unique_id", Fleet::unique_id(device)},
            {"state_topic", Fleet::state_topic(device)},
            {"value_template", "{{ value_json.state }}"},
            {"command_topic", Fleet::command_topic(device)},
            {"payload_on", "ON"},
            {"payload_off", "OFF"},
            {"availability", {{{"topic", availability_topic(device)}}}},
            {"device",
             {{"identifiers", {"zigbee2mqtt_0x0017880100000003"}}, {"suggested_area", "Kitchen"}}}};
  }
  if (device == "bed_sensor") {
    return {{"name", "Bed occupancy"},
            {"unique_id", Fleet::unique_id(device)},
            {"device_class", "occupancy"},
            {"state_topic", Fleet::state_topic(device)},
            {"value_template", "{{ value_json.occupancy }}"},
            {"payload_on", true},
            {"payload_off", false},
            {"availability", {{{"topic", availability_topic(device)}}}},
            {"device",
             {{"identifiers", {"zigbee2mqtt_0x0017880100000004"}}, {"suggested_area", "Bedroom"}}}};
  }
  if (device == "hall_motion") {
    return {{"name", "Hall motion"},
            {"unique_id", Fleet::unique_id(device)},
            {"device_class", "motion"},
            {"state_topic", Fleet::state_topic(device)},
            {"availability", {{{"topic", availability_topic(device)}}}},
            {"device", {{"identifiers", {"esp_hall"}}, {"suggested_area", "Hallway"}}}};
  }
  if (device == "bedroom_temp") {
    return {{"name", "Bedroom temperature"},
            {"unique_id", Fleet::unique_id(device)},
            {"device_class", "temperature"},
            {"state_class", "measurement"},
            {"unit_of_measurement", "°C"},
            {"state_topic", Fleet::state_topic(device)},
            {"value_template", "{{ value_json.temperature }}"},
            {"availability", {{{"topic", availability_topic(device)}}}},
            {"device",
             {{"identifiers", {"zigbee2mqtt_0x0017880100000005"}}, {"suggested_area", "Bedroom"}}}};
  }
  if (device == "living_blind") {  // ESPHome: Home Assistant's default payloads and states
    return {{"name", "Living blind"},
            {"unique_id", Fleet::unique_id(device)},
            {"device_class", "blind"},
            {"state_topic", Fleet::state_topic(device)},
            {"command_topic", Fleet::command_topic(device)},
            {"availability", {{{"topic", availability_topic(device)}}}},
            {"device", {{"identifiers", {"esp_blind"}}, {"suggested_area", "Living Room"}}}};
  }
  if (device == "bedroom_fan") {
    return {{"name", "Bedroom fan"},
            {"unique_id", Fleet::unique_id(device)},
            {"state_topic", Fleet::state_topic(device)},
            {"command_topic", Fleet::command_topic(device)},
            {"availability", {{{"topic", availability_topic(device)}}}},
            {"device", {{"identifiers", {"esp_fan"}}, {"suggested_area", "Bedroom"}}}};
  }
  if (device == "living_thermostat") {  // zigbee2mqtt's radiator valve, abbreviated keys
    return {{"name", "Living thermostat"},
            {"uniq_id", Fleet::unique_id(device)},
            {"mode_cmd_t", Fleet::command_topic(device)},
            {"mode_stat_t", Fleet::state_topic(device)},
            {"mode_stat_tpl", "{{ value_json.system_mode }}"},
            {"modes", {"off", "heat", "auto"}},
            {"avty", {{{"topic", availability_topic(device)}}}},
            {"dev", {{"ids", {"zigbee2mqtt_0x0017880100000009"}}, {"sa", "Living Room"}}}};
  }
  throw std::invalid_argument("the fleet has no device '" + device + "'");
}

}  // namespace

Fleet::Fleet(int broker_port)
    : client_(options_for(broker_port)),
      work_(asio::make_work_guard(io_)),
      thread_([this] { io_.run(); }) {
  for (const std::string device : kFleetDevices) devices_[device] = Device{};
  client_.on_message([this](const bm::Message& m) { on_command(m); });
}

Fleet::~Fleet() {
  client_.stop();
  work_.reset();
  io_.stop();
  thread_.join();
}

std::string Fleet::unique_id(const std::string& device) { return device + "_z2m"; }

std::string Fleet::config_topic(const std::string& device) {
  if (device == "living_lamp") return "homeassistant/light/living_lamp/config";
  if (device == "bedroom_lamp") return "homeassistant/light/0x0017880100000001/light/config";
  if (device == "kettle") return "homeassistant/switch/0x0017880100000003/switch/config";
  if (device == "bedroom_temp") return "homeassistant/sensor/0x0017880100000005/temperature/config";
  if (device == "living_blind") return "homeassistant/cover/living_blind/config";
  if (device == "bedroom_fan") return "homeassistant/fan/bedroom_fan/config";
  if (device == "living_thermostat")
    return "homeassistant/climate/0x0017880100000009/climate/config";
  return "homeassistant/binary_sensor/" + device + "/config";
}

std::string Fleet::config(const std::string& device) { return config_of(device).dump(); }

std::string Fleet::command_topic(const std::string& device) {
  if (device == "living_lamp") return "tasmota/living_lamp/cmnd/POWER";
  if (device == "living_blind" || device == "bedroom_fan") return "esphome/" + device + "/command";
  if (device == "living_thermostat") return "zigbee2mqtt/" + device + "/set/system_mode";
  return "zigbee2mqtt/" + device + "/set";
}

std::string Fleet::state_topic(const std::string& device) {
  if (device == "living_lamp") return "tasmota/living_lamp/stat/POWER";
  if (device == "hall_motion" || device == "living_blind" || device == "bedroom_fan")
    return "esphome/" + device + "/state";
  return "zigbee2mqtt/" + device;
}

void Fleet::start() {
  client_.subscribe("zigbee2mqtt/+/set");
  client_.subscribe("zigbee2mqtt/+/set/+");
  client_.subscribe("esphome/+/command");
  client_.subscribe("tasmota/living_lamp/cmnd/#");
  client_.start();
  if (!client_.wait_connected(std::chrono::seconds(20))) {
    throw std::runtime_error("the fleet could not connect to the broker: " + client_.last_error());
  }
  client_.publish(kBridgeState, R"({"state":"online"})", true);
  for (const std::string device : kFleetDevices) {
    client_.publish(availability_topic(device), device == "living_lamp" ? "Online" : "online",
                    true);
    publish_state(device);
    client_.publish(config_topic(device), config(device), true);
  }
}

void Fleet::set_delay(std::chrono::milliseconds delay) {
  std::lock_guard lock(mutex_);
  delay_ = delay;
}

void Fleet::ignore_commands(bool ignore) {
  std::lock_guard lock(mutex_);
  ignore_ = ignore;
}

void Fleet::set_online(const std::string& device, bool online) {
  const bool tasmota = device == "living_lamp";
  client_.publish(availability_topic(device),
                  online ? (tasmota ? "Online" : "online") : (tasmota ? "Offline" : "offline"),
                  true);
}

void Fleet::set_bridge_online(bool online) {
  client_.publish(kBridgeState, online ? R"({"state":"online"})" : R"({"state":"offline"})", true);
}

void Fleet::set_sensor(const std::string& device, bool on) {
  {
    std::lock_guard lock(mutex_);
    devices_.at(device).on = on;
  }
  publish_state(device);
}

void Fleet::set_measurement(const std::string& device, double value) {
  {
    std::lock_guard lock(mutex_);
    devices_.at(device).value = value;
  }
  publish_state(device);
}

void Fleet::publish(const std::string& topic, const std::string& payload, bool retain) {
  client_.publish(topic, payload, retain);
}

std::optional<bool> Fleet::on(const std::string& device) const {
  std::lock_guard lock(mutex_);
  const auto it = devices_.find(device);
  if (it == devices_.end()) return std::nullopt;
  return it->second.on;
}

std::string Fleet::position(const std::string& device) const {
  std::lock_guard lock(mutex_);
  return devices_.at(device).position;
}

std::string Fleet::mode(const std::string& device) const {
  std::lock_guard lock(mutex_);
  return devices_.at(device).mode;
}

int Fleet::brightness(const std::string& device) const {
  std::lock_guard lock(mutex_);
  return devices_.at(device).brightness;
}

int Fleet::commands(const std::string& device) const {
  std::lock_guard lock(mutex_);
  return devices_.at(device).commands;
}

void Fleet::publish_state(const std::string& device) {
  Device d;
  {
    std::lock_guard lock(mutex_);
    d = devices_.at(device);
  }
  const std::string on_off = d.on ? "ON" : "OFF";
  if (device == "bedroom_lamp") {
    client_.publish(state_topic(device),
                    json{{"state", on_off}, {"brightness", d.brightness}}.dump(), true);
  } else if (device == "living_lamp") {
    client_.publish("tasmota/living_lamp/stat/Dimmer", std::to_string(d.brightness), true);
    client_.publish(state_topic(device), on_off, true);
  } else if (device == "kettle") {
    client_.publish(state_topic(device), json{{"state", on_off}, {"power", d.on ? 1800 : 0}}.dump(),
                    true);
  } else if (device == "bed_sensor") {
    client_.publish(state_topic(device), json{{"occupancy", d.on}, {"battery", 90}}.dump(), true);
  } else if (device == "bedroom_temp") {
    client_.publish(state_topic(device),
                    json{{"temperature", d.value}, {"humidity", 45}, {"battery", 97}}.dump(), true);
  } else if (device == "living_blind") {
    client_.publish(state_topic(device), d.position, true);
  } else if (device == "living_thermostat") {
    client_.publish(state_topic(device),
                    json{{"system_mode", d.mode}, {"local_temperature", 20.5}}.dump(), true);
  } else {
    client_.publish(state_topic(device), on_off, true);
  }
}

// On the client's network thread.
void Fleet::on_command(const bm::Message& m) {
  std::string device;
  if (m.topic.starts_with("tasmota/living_lamp/cmnd/")) {
    device = "living_lamp";
  } else if (m.topic.starts_with("zigbee2mqtt/")) {  // zigbee2mqtt/<device>/set[/<attribute>]
    const auto set = m.topic.find("/set", 12);
    if (set != std::string::npos) device = m.topic.substr(12, set - 12);
  } else if (m.topic.starts_with("esphome/") && m.topic.ends_with("/command")) {
    device = m.topic.substr(8, m.topic.size() - 8 - 8);
  }
  std::chrono::milliseconds delay{0};
  {
    std::lock_guard lock(mutex_);
    const auto it = devices_.find(device);
    if (it == devices_.end()) return;
    Device& d = it->second;
    ++d.commands;
    if (ignore_) return;
    delay = delay_;
  }
  // The new state is decided now and reported after the delay, as a slow device would.
  const auto apply = [this, device, topic = m.topic, payload = m.payload] {
    std::string moving;  // a cover reports moving before it reports where it stopped
    {
      std::lock_guard lock(mutex_);
      Device& d = devices_.at(device);
      if (device == "living_blind") {
        if (payload == "OPEN") {
          moving = "opening";
          d.position = "open";
        } else if (payload == "CLOSE") {
          moving = "closing";
          d.position = "closed";
        } else if (payload != "STOP") {
          return;
        }
      } else if (device == "living_thermostat") {
        if (payload != "off" && payload != "heat" && payload != "auto") return;
        d.mode = payload;
        d.on = payload != "off";
      } else if (device == "bedroom_lamp") {
        const json command = json::parse(payload, nullptr, false);
        if (command.is_discarded()) return;
        if (const auto s = command.find("state"); s != command.end() && s->is_string())
          d.on = *s == "ON";
        if (const auto b = command.find("brightness");
            b != command.end() && b->is_number_integer()) {
          d.brightness = b->get<int>();
        }
      } else if (topic == "tasmota/living_lamp/cmnd/Dimmer") {
        int v = 0;
        if (std::from_chars(payload.data(), payload.data() + payload.size(), v).ec != std::errc())
          return;
        d.brightness = v;
        d.on = v > 0;  // Tasmota: a dimmer above 0 turns the light on
      } else if (payload == "ON" || payload == "OFF") {
        d.on = payload == "ON";
      } else {
        return;
      }
    }
    try {
      if (!moving.empty()) client_.publish(state_topic(device), moving, true);
      publish_state(device);
    } catch (const bm::Error&) {
      // The fleet is stopping: the broker no longer hears it, as with a device switched off.
    }
  };
  if (delay.count() == 0) {
    apply();
    return;
  }
  auto timer = std::make_shared<asio::steady_timer>(io_, delay);
  timer->async_wait([timer, apply](const std::error_code& ec) {
    if (!ec) apply();
  });
}

}  // namespace mqtt_test
