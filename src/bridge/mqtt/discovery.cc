#include "icars/bridge/mqtt/discovery.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <mosquitto.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <map>
#include <stdexcept>

namespace icars::bridge::mqtt {

namespace {

using nlohmann::json;

// Home Assistant's abbreviations of the keys ICARS reads (entity level, device level, and
// availability entries).
const std::map<std::string, std::string, std::less<>>& abbreviations() {
  static const std::map<std::string, std::string, std::less<>> table = {
      {"stat_t", "state_topic"},
      {"cmd_t", "command_topic"},
      {"avty_t", "availability_topic"},
      {"avty", "availability"},
      {"avty_mode", "availability_mode"},
      {"pl_avail", "payload_available"},
      {"pl_not_avail", "payload_not_available"},
      {"uniq_id", "unique_id"},
      {"obj_id", "object_id"},
      {"dev", "device"},
      {"dev_cla", "device_class"},
      {"bri", "brightness"},
      {"bri_cmd_t", "brightness_command_topic"},
      {"bri_stat_t", "brightness_state_topic"},
      {"bri_scl", "brightness_scale"},
      {"pl_on", "payload_on"},
      {"pl_off", "payload_off"},
      {"stat_on", "state_on"},
      {"stat_off", "state_off"},
      {"unit_of_meas", "unit_of_measurement"},
      {"val_tpl", "value_template"},
      {"stat_val_tpl", "state_value_template"},
      {"mode_cmd_t", "mode_command_topic"},
      {"mode_stat_t", "mode_state_topic"},
      {"mode_stat_tpl", "mode_state_template"},
      {"pl_open", "payload_open"},
      {"pl_cls", "payload_close"},
      {"pl_stop", "payload_stop"},
      {"stat_open", "state_open"},
      {"stat_clsd", "state_closed"},
      {"stat_opening", "state_opening"},
      {"stat_closing", "state_closing"},
      {"stat_stopped", "state_stopped"},
      {"sug_area", "suggested_area"},
      {"ids", "identifiers"},
      {"sa", "suggested_area"},
      {"mf", "manufacturer"},
      {"mdl", "model"},
      {"t", "topic"},
  };
  return table;
}

json expand(const json& object) {
  json out = json::object();
  for (const auto& [key, value] : object.items()) {
    const auto it = abbreviations().find(key);
    const std::string& name = it == abbreviations().end() ? key : it->second;
    if (value.is_object()) {
      out[name] = expand(value);
    } else if (value.is_array()) {
      json list = json::array();
      for (const auto& v : value) list.push_back(v.is_object() ? expand(v) : v);
      out[name] = std::move(list);
    } else {
      out[name] = value;
    }
  }
  return out;
}

bool is_id(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
  });
}

std::vector<std::string_view> split(std::string_view s, char sep) {
  std::vector<std::string_view> out;
  for (std::size_t start = 0;;) {
    const auto at = s.find(sep, start);
    out.push_back(s.substr(start, at == std::string_view::npos ? std::string_view::npos : at - start));
    if (at == std::string_view::npos) return out;
    start = at + 1;
  }
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

// A scalar as text: strings as they are, numbers and booleans as JSON writes them.
std::string text(const json& j) { return j.is_string() ? j.get<std::string>() : j.dump(); }

class Bad : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct Reader {
  const json& config;
  std::string base;  // `~`

  std::string string(const char* key, std::string fallback = {}) const {
    const auto it = config.find(key);
    if (it == config.end() || it->is_null()) return fallback;
    if (it->is_object() || it->is_array()) throw Bad(fmt::format("'{}' must be a string, not {}", key, it->type_name()));
    return text(*it);
  }
  // A topic: `~` expanded, no wildcards.
  std::string topic(const char* key) const { return checked_topic(key, string(key)); }
  std::string checked_topic(const char* key, std::string t) const {
    if (t.empty()) return t;
    // `~` at the start or (otherwise) at the end of the value stands for the base topic; a lone
    // `~` is the base itself, and with no base it is an empty topic (refused below).
    if (t.front() == '~') {
      t = base + t.substr(1);
    } else if (t.back() == '~') {
      t = t.substr(0, t.size() - 1) + base;
    }
    if (mosquitto_pub_topic_check(t.c_str()) != MOSQ_ERR_SUCCESS) {
      throw Bad(fmt::format("'{}' is '{}': not a topic one can publish to (wildcards '+' or '#', or empty)", key, t));
    }
    return t;
  }
};

}  // namespace

std::optional<DiscoveryTopic> parse_discovery_topic(std::string_view topic, std::string_view prefix) {
  if (!topic.starts_with(prefix) || topic.size() <= prefix.size() || topic[prefix.size()] != '/') return std::nullopt;
  const auto parts = split(topic.substr(prefix.size() + 1), '/');
  if (parts.size() != 3 && parts.size() != 4) return std::nullopt;
  if (parts.back() != "config") return std::nullopt;
  for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
    if (!is_id(parts[i])) return std::nullopt;
  }
  DiscoveryTopic out;
  out.component = std::string(parts[0]);
  if (parts.size() == 4) out.node_id = std::string(parts[1]);
  out.object_id = std::string(parts[parts.size() - 2]);
  return out;
}

std::optional<std::vector<std::string>> value_template_path(std::string_view t) {
  t = trim(t);
  if (!t.starts_with("{{") || !t.ends_with("}}")) return std::nullopt;
  t = trim(t.substr(2, t.size() - 4));
  // A conversion filter at the end changes nothing for ICARS, which reads numbers and text.
  for (const std::string_view filter : {"| float", "|float", "| int", "|int", "| string", "|string"}) {
    if (t.ends_with(filter)) {
      t = trim(t.substr(0, t.size() - filter.size()));
      break;
    }
  }
  if (t == "value") return std::vector<std::string>{};
  if (!t.starts_with("value_json")) return std::nullopt;
  t.remove_prefix(std::string_view("value_json").size());
  std::vector<std::string> path;
  while (!t.empty()) {
    if (t.front() == '.') {
      t.remove_prefix(1);
      std::size_t n = 0;
      while (n < t.size() && t[n] != '.' && t[n] != '[') ++n;
      if (n == 0 || !is_id(t.substr(0, n))) return std::nullopt;
      path.emplace_back(t.substr(0, n));
      t.remove_prefix(n);
    } else if (t.starts_with("['") || t.starts_with("[\"")) {
      const char quote = t[1];
      const auto end = t.find(quote, 2);
      if (end == std::string_view::npos || end + 1 >= t.size() || t[end + 1] != ']' || end == 2) return std::nullopt;
      path.emplace_back(t.substr(2, end - 2));
      t.remove_prefix(end + 2);
    } else {
      return std::nullopt;
    }
  }
  if (path.empty()) return std::nullopt;
  return path;
}

DiscoveryResult read_discovery(std::string_view topic, std::string_view payload, std::string_view prefix,
                               std::size_t max_payload) {
  DiscoveryResult result;
  const auto fail = [&](const std::string& what) {
    result.error = fmt::format("{}: {}", topic, what);
    return result;
  };
  const auto where = parse_discovery_topic(topic, prefix);
  if (!where) return fail(fmt::format("not a discovery topic ({}/<component>/[<node_id>/]<object_id>/config)", prefix));
  if (payload.empty()) {
    result.removed = true;
    return result;
  }
  if (payload.size() > max_payload) {
    return fail(fmt::format("a config of {} bytes is larger than {} bytes; ignored", payload.size(), max_payload));
  }
  const auto& supported = kSupportedComponents;
  if (std::find(std::begin(supported), std::end(supported), where->component) == std::end(supported)) {
    return fail(fmt::format("component '{}' is not supported (supported: {})", where->component,
                            fmt::join(std::begin(supported), std::end(supported), ", ")));
  }
  json raw;
  try {
    raw = json::parse(payload);
  } catch (const json::exception& e) {  // a syntax error, or a number too large to hold
    return fail(fmt::format("the config is not JSON: {}", e.what()));
  }
  if (!raw.is_object()) return fail(fmt::format("the config must be a JSON object, not {}", raw.type_name()));
  try {
    const json config = expand(raw);
    Reader r{config, ""};
    r.base = r.string("~");
    Entity e;
    e.where = *where;
    e.config_topic = std::string(topic);
    const auto& c = where->component;
    e.unique_id = r.string("unique_id");
    if (e.unique_id.empty()) e.unique_id = where->node_id.empty() ? where->object_id : where->node_id + "_" + where->object_id;
    e.name = r.string("name", where->object_id);
    e.device_class = r.string("device_class");
    e.state_topic = r.topic("state_topic");
    e.command_topic = r.topic("command_topic");
    if (c == "climate") {
      // ICARS switches a climate device by its mode ("off" or another), which its mode state
      // topic confirms; its power topic has no state topic to confirm a command with.
      e.command_topic = r.topic("mode_command_topic");
      e.state_topic = r.topic("mode_state_topic");
      e.modes = {"auto", "off", "cool", "heat", "dry", "fan_only"};  // Home Assistant's default
      if (const auto modes = config.find("modes"); modes != config.end()) {
        if (!modes->is_array()) throw Bad("'modes' must be a list of strings");
        e.modes.clear();
        for (const auto& m : *modes) {
          if (!m.is_string()) throw Bad("'modes' must be a list of strings");
          e.modes.push_back(m.get<std::string>());
        }
      }
    }
    if (c == "cover") {
      e.payload_open = r.string("payload_open", "OPEN");
      e.payload_close = r.string("payload_close", "CLOSE");
      e.payload_stop = r.string("payload_stop", "STOP");
      e.state_open = r.string("state_open", "open");
      e.state_closed = r.string("state_closed", "closed");
      e.state_opening = r.string("state_opening", "opening");
      e.state_closing = r.string("state_closing", "closing");
      e.state_stopped = r.string("state_stopped", "stopped");
    }
    e.schema = r.string("schema", "default");
    if (c == "light" && e.schema != "default" && e.schema != "json") {
      throw Bad(fmt::format("light schema '{}' is not supported (default, json)", e.schema));
    }
    e.brightness_state_topic = r.topic("brightness_state_topic");
    e.brightness_command_topic = r.topic("brightness_command_topic");
    if (const auto b = config.find("brightness"); b != config.end() && b->is_boolean()) e.brightness = b->get<bool>();
    if (!e.brightness_command_topic.empty()) e.brightness = true;
    if (const auto s = config.find("brightness_scale"); s != config.end()) {
      if (!s->is_number_integer() || s->get<int>() < 1) throw Bad("'brightness_scale' must be a positive integer");
      e.brightness_scale = s->get<int>();
    }
    e.payload_on = r.string("payload_on", "ON");
    e.payload_off = r.string("payload_off", "OFF");
    e.state_on = r.string("state_on", e.payload_on);
    e.state_off = r.string("state_off", e.payload_off);
    e.unit = r.string("unit_of_measurement");
    const auto value_template = c == "climate" ? r.string("mode_state_template")
                                               : r.string("value_template", r.string("state_value_template"));
    if (!value_template.empty()) {
      const auto path = value_template_path(value_template);
      if (!path) {
        throw Bad(fmt::format("value_template '{}' is not one ICARS follows ({{{{ value }}}}, "
                              "{{{{ value_json.a.b }}}}, {{{{ value_json['a'] }}}})",
                              value_template));
      }
      e.value_path = *path;
    } else if (c == "light" && e.schema == "json") {
      e.value_path = {"state"};
    }
    // Availability: one topic, or a list of them.
    if (const auto topic_only = r.topic("availability_topic"); !topic_only.empty()) {
      Availability a;
      a.topic = topic_only;
      a.payload_available = r.string("payload_available", "online");
      a.payload_not_available = r.string("payload_not_available", "offline");
      e.availability.push_back(a);
    }
    if (const auto list = config.find("availability"); list != config.end()) {
      if (!list->is_array()) throw Bad("'availability' must be a list");
      for (const auto& item : *list) {
        if (!item.is_object()) throw Bad("each entry of 'availability' must be an object");
        Reader ar{item, r.base};
        Availability a;
        a.topic = ar.topic("topic");
        if (a.topic.empty()) throw Bad("an entry of 'availability' has no 'topic'");
        a.payload_available = ar.string("payload_available", "online");
        a.payload_not_available = ar.string("payload_not_available", "offline");
        a.value_template = ar.string("value_template");
        e.availability.push_back(a);
      }
    }
    e.availability_mode = r.string("availability_mode", "latest");
    if (e.availability_mode != "latest" && e.availability_mode != "all" && e.availability_mode != "any") {
      throw Bad(fmt::format("availability_mode '{}' is not all, any or latest", e.availability_mode));
    }
    // The device the entity belongs to.
    e.area = r.string("suggested_area");
    if (const auto d = config.find("device"); d != config.end()) {
      if (!d->is_object()) throw Bad("'device' must be an object");
      Reader dr{*d, ""};
      e.device_name = dr.string("name");
      if (const auto sa = dr.string("suggested_area"); !sa.empty()) e.area = sa;
      if (const auto ids = d->find("identifiers"); ids != d->end()) {
        if (ids->is_array() && !ids->empty()) {
          e.device_id = text(ids->front());
        } else if (ids->is_string()) {
          e.device_id = ids->get<std::string>();
        }
      }
    }
    if (e.device_id.empty()) e.device_id = e.unique_id;
    if (e.device_name.empty()) e.device_name = e.name;
    // What each component needs to be of use.
    const bool commanded = c == "light" || c == "switch" || c == "cover" || c == "fan" || c == "climate";
    if (commanded && e.command_topic.empty()) {
      throw Bad(fmt::format("a {} needs a command topic ({})", c,
                            c == "climate" ? "'mode_command_topic'" : "'command_topic'"));
    }
    if ((c == "binary_sensor" || c == "sensor") && e.state_topic.empty()) {
      throw Bad(fmt::format("a {} needs 'state_topic'", c));
    }
    result.entity = std::move(e);
  } catch (const Bad& e) {
    return fail(e.what());
  } catch (const json::exception& e) {
    return fail(fmt::format("unexpected JSON: {}", e.what()));
  }
  return result;
}

}  // namespace icars::bridge::mqtt
