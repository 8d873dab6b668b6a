#include "icars/home/sim/sim_mqtt_devices.h"

#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <stdexcept>

namespace icars::home {

namespace bm = icars::bridge::mqtt;
using nlohmann::json;

namespace {

enum class Kind { light, occupancy, motion };

constexpr int kBrightnessScale = 254;  // zigbee2mqtt's

std::optional<Kind> kind_of(const std::string& type) {
  if (type == "Light") return Kind::light;
  if (type == "BedOccupancy" || type == "SofaOccupancy" || type == "Occupancy") return Kind::occupancy;
  if (type == "MotionSensor") return Kind::motion;
  return std::nullopt;
}

std::string param_or(const sim::DeviceSpec& spec, const std::string& name, const std::string& fallback) {
  const auto it = spec.params.find(name);
  return it == spec.params.end() ? fallback : it->second;
}

std::string furniture_of(const sim::DeviceSpec& spec) {
  const std::string fallback = spec.type == "BedOccupancy" ? "bed" : spec.type == "SofaOccupancy" ? "sofa" : "";
  return param_or(spec, "furniture", fallback);
}

}  // namespace

bool simulated_over_mqtt(const std::string& type) { return kind_of(type).has_value(); }

std::vector<const sim::DeviceSpec*> mqtt_devices(const sim::House& house) {
  std::vector<const sim::DeviceSpec*> out;
  for (const auto& d : house.devices) {
    if (d.mqtt.empty()) continue;
    if (!simulated_over_mqtt(d.type)) {
      throw sim::HouseError(house.source, d.line,
                            fmt::format("device \"{}\" of type {} cannot be an MQTT device of the simulated house; "
                                        "Light, BedOccupancy, SofaOccupancy, Occupancy and MotionSensor can",
                                        d.id, d.type));
    }
    out.push_back(&d);
  }
  return out;
}

mqtt::PlacementTable mqtt_placements(const sim::House& house) {
  mqtt::PlacementTable table;
  for (const auto& d : house.devices) {
    if (d.mqtt.empty()) continue;
    table[d.mqtt] = mqtt::Placement{d.id, d.room, kind_of(d.type) == Kind::occupancy ? furniture_of(d) : ""};
  }
  return table;
}

struct SimulatedMqttDevices::Device {
  const sim::DeviceSpec* spec = nullptr;
  Kind kind = Kind::light;
  std::string furniture;         // occupancy
  std::string room;              // motion: the room it watches
  std::set<std::string> present;  // motion: the users in its room
  bool on = false;               // light on, occupied, motion
  int brightness = kBrightnessScale;
  std::string state_topic, command_topic, config_topic;
};

SimulatedMqttDevices::SimulatedMqttDevices(sim::World& world, std::vector<const sim::DeviceSpec*> devices,
                                           EffectObserver effects, SimulatedMqttOptions options)
    : world_(world), effects_(std::move(effects)), options_(std::move(options)) {
  log_ = options_.logger ? options_.logger
                         : std::make_shared<spdlog::logger>("sim-mqtt",
                                                            std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  if (options_.broker.client_id.empty()) options_.broker.client_id = "icars-sim-" + world_.house().name;
  options_.broker.will = bm::Will{availability_topic(), "offline", true};
  for (const auto* spec : devices) {
    const auto kind = kind_of(spec->type);
    if (!kind) throw std::invalid_argument(fmt::format("device {}: type {} cannot be simulated over MQTT", spec->id, spec->type));
    auto d = std::make_unique<Device>();
    d->spec = spec;
    d->kind = *kind;
    d->furniture = furniture_of(*spec);
    d->room = param_or(*spec, "room", spec->room);
    d->state_topic = state_topic(spec->id);
    d->command_topic = command_topic(spec->id);
    const std::string component = *kind == Kind::light ? "light" : "binary_sensor";
    d->config_topic = fmt::format("{}/{}/{}/{}/config", options_.discovery_prefix, component, options_.base_topic, spec->id);
    if (*kind == Kind::occupancy) d->on = world_.occupied(d->furniture);
    if (*kind == Kind::light) by_command_topic_[d->command_topic] = d.get();
    devices_.push_back(std::move(d));
  }
  client_ = std::make_unique<bm::Client>(options_.broker);
  client_->on_message([this](const bm::Message& m) { on_command(m); });
  for (const auto& [topic, device] : by_command_topic_) client_->subscribe(topic);
  client_->on_connection([this](bool connected, const std::string& reason) {
    std::lock_guard lock(mutex_);
    if (!started_) return;  // stopping: the disconnection is ours
    if (!connected) {
      log_->warn("MQTT broker {}:{} lost: {}", options_.broker.host, options_.broker.port, reason);
      return;
    }
    // On every connection: a broker restarted without persistence has lost what was retained.
    publish_all();
  });
}

SimulatedMqttDevices::~SimulatedMqttDevices() { stop(); }

std::string SimulatedMqttDevices::state_topic(const std::string& device_id) const {
  return options_.base_topic + "/" + device_id;
}
std::string SimulatedMqttDevices::command_topic(const std::string& device_id) const {
  return options_.base_topic + "/" + device_id + "/set";
}
std::string SimulatedMqttDevices::availability_topic() const { return options_.base_topic + "/bridge/state"; }

void SimulatedMqttDevices::start(std::chrono::milliseconds timeout) {
  {
    std::lock_guard lock(mutex_);
    if (started_) return;
    started_ = true;
  }
  world_listener_ = world_.on_user([this](const sim::UserState& u) { on_user(u); });
  client_->start();
  if (!client_->wait_connected(timeout)) {
    const auto why = client_->last_error();
    stop();
    throw bm::Error(fmt::format("the simulated house's MQTT devices cannot reach the broker {}:{}: {}",
                                options_.broker.host, options_.broker.port, why.empty() ? "no answer" : why));
  }
}

// Under mutex_.
void SimulatedMqttDevices::publish_all() {
  try {
    for (auto& d : devices_) {
      const auto& spec = *d->spec;
      json config = {
          {"unique_id", spec.mqtt},
          {"object_id", spec.id},
          {"name", nullptr},
          {"state_topic", d->state_topic},
          {"availability", json::array({{{"topic", availability_topic()}}})},
          {"device",
           {{"identifiers", json::array({options_.base_topic + "_" + spec.id})},
            {"name", spec.id},
            {"model", "simulated " + spec.type},
            {"manufacturer", "ICARS"},
            {"suggested_area", spec.room}}},
      };
      if (d->kind == Kind::light) {
        config["schema"] = "json";
        config["command_topic"] = d->command_topic;
        config["brightness"] = true;
        config["brightness_scale"] = kBrightnessScale;
      } else {
        config["device_class"] = d->kind == Kind::occupancy ? "occupancy" : "motion";
        config["value_template"] = "{{ value_json.occupancy }}";
        config["payload_on"] = true;
        config["payload_off"] = false;
      }
      publish_state(*d);
      client_->publish(d->config_topic, config.dump(), true);
    }
    client_->publish(availability_topic(), "online", true);
  } catch (const bm::Error& e) {
    log_->warn("the simulated house's MQTT devices were not all published: {}", e.what());
  }
}

// A user moved, sat, lay down or got up: the sensors that see it publish their new state.
void SimulatedMqttDevices::on_user(const sim::UserState& u) {
  std::lock_guard lock(mutex_);
  for (auto& d : devices_) {
    bool now = d->on;
    if (d->kind == Kind::occupancy) now = world_.occupied(d->furniture);
    if (d->kind == Kind::motion) {
      if (u.room == d->room) {
        d->present.insert(u.user);
      } else {
        d->present.erase(u.user);
      }
      now = !d->present.empty();
    }
    if (d->kind == Kind::light || now == d->on) continue;
    d->on = now;
    publish_state(*d);
  }
}

// Under mutex_ (or before start's listeners exist).
void SimulatedMqttDevices::publish_state(Device& d) {
  json state;
  if (d.kind == Kind::light) {
    state = {{"state", d.on ? "ON" : "OFF"}, {"brightness", d.brightness}};
  } else {
    state = {{"occupancy", d.on}};
  }
  try {
    client_->publish(d.state_topic, state.dump(), true);
  } catch (const bm::Error& e) {
    // The broker is away: the state is published again, retained, when the device next changes;
    // a bridge reads the retained one when it is back.
    log_->warn("{}: state of {} not published: {}", d.state_topic, d.spec->id, e.what());
    return;
  }
  if (options_.activity) holds_[d.state_topic].push_back(options_.activity->hold());
}

void SimulatedMqttDevices::on_command(const bm::Message& m) {
  const auto it = by_command_topic_.find(m.topic);
  if (it == by_command_topic_.end()) return;
  Device& d = *it->second;
  const json command = json::parse(m.payload, nullptr, false);
  const auto state = command.is_object() ? command.find("state") : command.end();
  const bool has_brightness = command.is_object() && command.contains("brightness");
  if (!command.is_object() || (state == command.end() && !has_brightness) ||
      (state != command.end() && (!state->is_string() || (*state != "ON" && *state != "OFF" && *state != "TOGGLE"))) ||
      (has_brightness && !command.at("brightness").is_number())) {
    // As zigbee2mqtt does: the command is refused, the state stays and is said again.
    log_->warn("{}: command '{}' refused: expected {{\"state\":\"ON\"|\"OFF\"|\"TOGGLE\", \"brightness\":0..{}}}",
               m.topic, m.payload, kBrightnessScale);
    std::lock_guard lock(mutex_);
    publish_state(d);
    return;
  }
  std::vector<DeviceEffect> effects;
  const auto now = world_.clock().now();
  {
    std::lock_guard lock(mutex_);
    if (state != command.end()) {
      d.on = *state == "TOGGLE" ? !d.on : *state == "ON";
      effects.push_back(DeviceEffect{now, d.spec->id, "power", d.on ? "on" : "off", 0});
    }
    if (has_brightness) {
      d.brightness =
          std::clamp(static_cast<int>(std::lround(command.at("brightness").get<double>())), 0, kBrightnessScale);
      const int percent = static_cast<int>(std::lround(d.brightness * 100.0 / kBrightnessScale));
      effects.push_back(DeviceEffect{now, d.spec->id, "intensity", std::to_string(percent), 0});
    }
  }
  // What the device did is told before its state confirms it, so that a cause's record
  // precedes the bridge's acknowledgement.
  if (effects_) {
    for (const auto& e : effects) effects_(e);
  }
  std::lock_guard lock(mutex_);
  publish_state(d);
}

void SimulatedMqttDevices::handled(const bm::Message& m) {
  std::lock_guard lock(mutex_);
  const auto it = holds_.find(m.topic);
  if (it == holds_.end()) return;
  if (m.retained) {
    holds_.erase(it);  // delivered on subscribing: the latest state, standing for all before it
  } else {
    it->second.pop_front();
    if (it->second.empty()) holds_.erase(it);
  }
}

std::size_t SimulatedMqttDevices::held() const {
  std::lock_guard lock(mutex_);
  std::size_t n = 0;
  for (const auto& [topic, holds] : holds_) n += holds.size();
  return n;
}

void SimulatedMqttDevices::stop() {
  {
    std::lock_guard lock(mutex_);
    if (!started_) return;
    started_ = false;
  }
  world_.remove_listener(world_listener_);
  // As a zigbee2mqtt that stops: its devices say offline, their configs stay.
  try {
    if (client_->connected()) {
      client_->publish(availability_topic(), "offline", true);
      client_->drain(std::chrono::seconds(5));
    }
  } catch (const bm::Error& e) {
    log_->warn("cannot publish {}: {}", availability_topic(), e.what());
  }
  client_->stop();
  std::lock_guard lock(mutex_);
  holds_.clear();
}

}  // namespace icars::home
