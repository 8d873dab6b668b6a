// Home Assistant's MQTT discovery, read: the configs that zigbee2mqtt, Tasmota, ESPHome and
// Shelly devices publish (retained) under `homeassistant/<component>/[<node_id>/]<object_id>/config`,
// each a JSON object naming the entity's topics (`state_topic`, `command_topic`,
// `availability`, ...), its device and its kind (`device_class`). Abbreviated keys (`stat_t`,
// `cmd_t`, `avty_t`, `uniq_id`, `dev`, `ids`, ...) and the `~` base topic are expanded.
//
//   const auto r = mqtt::read_discovery(message.topic, message.payload);
//   if (!r.error.empty()) log(r.error);          // "homeassistant/light/x/config: ..."
//   else if (r.removed) forget(r.topic);          // an empty payload removes the entity
//   else add(*r.entity);
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace icars::bridge::mqtt {

// The components ICARS turns into devices (docs: the bridge's mapping table).
inline constexpr std::string_view kSupportedComponents[] = {"light", "switch", "binary_sensor", "sensor",
                                                             "cover", "fan",   "climate"};

struct DiscoveryTopic {
  std::string component;
  std::string node_id;  // "" when the topic has none
  std::string object_id;
};

// "<prefix>/<component>/[<node_id>/]<object_id>/config" → its parts; nullopt for any other
// topic (ids are letters, digits, '_' and '-').
std::optional<DiscoveryTopic> parse_discovery_topic(std::string_view topic, std::string_view prefix = "homeassistant");

struct Availability {
  std::string topic;
  std::string payload_available = "online";
  std::string payload_not_available = "offline";
  std::string value_template;  // as written ("" when none)
};

// One entity as its config describes it, keys expanded and defaults filled in.
struct Entity {
  DiscoveryTopic where;
  std::string config_topic;
  std::string unique_id;    // `unique_id`, or "<node_id>_<object_id>" when it has none
  std::string name;         // `name`, or the object id
  std::string device_id;    // the device's first identifier, or the unique id
  std::string device_name;  // `device.name`, or the entity's name
  std::string area;         // `device.suggested_area` (or the entity's), "" when none
  std::string device_class;
  std::string state_topic;
  std::string command_topic;
  std::string schema = "default";  // light: "default" (payload_on/off) or "json"
  bool brightness = false;         // the light can be dimmed
  int brightness_scale = 255;
  std::string brightness_state_topic;
  std::string brightness_command_topic;
  std::string payload_on = "ON";
  std::string payload_off = "OFF";
  std::string state_on;   // what the state topic says when on (default: payload_on)
  std::string state_off;  // ... and off (default: payload_off)
  std::string unit;       // `unit_of_measurement`
  // cover: what its command topic takes and its state topic says.
  std::string payload_open = "OPEN";
  std::string payload_close = "CLOSE";
  std::string payload_stop = "STOP";
  std::string state_open = "open";
  std::string state_closed = "closed";
  std::string state_opening = "opening";
  std::string state_closing = "closing";
  std::string state_stopped = "stopped";
  // climate: its HVAC modes (`modes`, Home Assistant's default list when absent); its command
  // and state topics are `mode_command_topic` and `mode_state_topic`, read by
  // `mode_state_template`.
  std::vector<std::string> modes;
  // The JSON path `value_template` reads ("temperature" for "{{ value_json.temperature }}");
  // empty: the payload itself is the value.
  std::vector<std::string> value_path;
  std::vector<Availability> availability;
  std::string availability_mode = "latest";  // "all", "any" or "latest"
};

struct DiscoveryResult {
  std::optional<Entity> entity;  // set when the config describes an entity ICARS can use
  bool removed = false;          // an empty payload: the entity is gone
  std::string error;             // "<topic>: <what is wrong>", or ""
};

// Reads one discovery message. Never throws: a payload that is not JSON, not an object, larger
// than `max_payload`, of a component ICARS does not support, without the topics its component
// needs, with topics that contain wildcards, or with a value_template ICARS cannot follow is an
// error naming the topic and what is wrong.
DiscoveryResult read_discovery(std::string_view topic, std::string_view payload,
                               std::string_view prefix = "homeassistant", std::size_t max_payload = 64 * 1024);

// The JSON path of a value_template: "{{ value_json.a.b }}" and "{{ value_json['a'] }}" give
// {"a", "b"} and {"a"}, "{{ value }}" an empty path; nullopt for anything else.
std::optional<std::vector<std::string>> value_template_path(std::string_view value_template);

}  // namespace icars::bridge::mqtt
