// Home Assistant discovery configs as zigbee2mqtt, Tasmota and ESPHome write them — full and
// abbreviated keys, the `~` base topic, JSON and default light schemas, availability lists —
// and every kind of bad config, each an error naming the topic and what is wrong.
#include "icars/bridge/mqtt/discovery.h"

#include <gtest/gtest.h>

#include <string>

namespace icars::bridge::mqtt {
namespace {

TEST(DiscoveryTopic, NamesComponentNodeAndObject) {
  auto t = parse_discovery_topic("homeassistant/light/0x00158d0001/light/config");
  ASSERT_TRUE(t);
  EXPECT_EQ(t->component, "light");
  EXPECT_EQ(t->node_id, "0x00158d0001");
  EXPECT_EQ(t->object_id, "light");
  t = parse_discovery_topic("homeassistant/binary_sensor/sofa_occupancy/config");
  ASSERT_TRUE(t);
  EXPECT_EQ(t->node_id, "");
  EXPECT_EQ(t->object_id, "sofa_occupancy");
  EXPECT_TRUE(parse_discovery_topic("ha/switch/plug/config", "ha"));
  for (const char* other : {"homeassistant/light/x/state", "homeassistant/light/config", "homeassistant/a/b/c/d/config",
                            "zigbee2mqtt/lamp", "homeassistant/light/bad id/config", "homeassistant/light/+/config",
                            "homeassistantx/light/x/config", "homeassistant//x/config"}) {
    EXPECT_FALSE(parse_discovery_topic(other)) << other;
  }
}

TEST(Discovery, AZigbee2mqttJsonLightWithBrightnessAndAvailability) {
  const auto r = read_discovery("homeassistant/light/0x0017880104e45517/light/config", R"({
    "availability": [{"topic": "zigbee2mqtt/bridge/state"}, {"topic": "zigbee2mqtt/lamp/availability"}],
    "availability_mode": "all",
    "brightness": true, "brightness_scale": 254,
    "command_topic": "zigbee2mqtt/lamp/set",
    "device": {"identifiers": ["zigbee2mqtt_0x0017880104e45517"], "manufacturer": "Philips",
               "model": "Hue white A60", "name": "lamp", "suggested_area": "Living room"},
    "name": null, "schema": "json", "state_topic": "zigbee2mqtt/lamp",
    "unique_id": "0x0017880104e45517_light_zigbee2mqtt"})");
  ASSERT_EQ(r.error, "");
  ASSERT_TRUE(r.entity);
  const auto& e = *r.entity;
  EXPECT_EQ(e.where.component, "light");
  EXPECT_EQ(e.unique_id, "0x0017880104e45517_light_zigbee2mqtt");
  EXPECT_EQ(e.name, "light");  // "name": null: the object id
  EXPECT_EQ(e.device_id, "zigbee2mqtt_0x0017880104e45517");
  EXPECT_EQ(e.device_name, "lamp");
  EXPECT_EQ(e.area, "Living room");
  EXPECT_EQ(e.schema, "json");
  EXPECT_TRUE(e.brightness);
  EXPECT_EQ(e.brightness_scale, 254);
  EXPECT_EQ(e.state_topic, "zigbee2mqtt/lamp");
  EXPECT_EQ(e.command_topic, "zigbee2mqtt/lamp/set");
  EXPECT_EQ(e.value_path, std::vector<std::string>{"state"});
  ASSERT_EQ(e.availability.size(), 2u);
  EXPECT_EQ(e.availability[1].topic, "zigbee2mqtt/lamp/availability");
  EXPECT_EQ(e.availability[1].payload_available, "online");
  EXPECT_EQ(e.availability_mode, "all");
}

TEST(Discovery, ATasmotaStyleAbbreviatedSwitchWithABaseTopic) {
  const auto r = read_discovery("homeassistant/switch/A1B2C3_RL_1/config", R"({
    "~": "tasmota/plug", "name": "Plug", "uniq_id": "A1B2C3_RL_1",
    "stat_t": "~/stat/POWER", "cmd_t": "~/cmnd/POWER", "avty_t": "~/tele/LWT",
    "pl_avail": "Online", "pl_not_avail": "Offline", "pl_on": "ON", "pl_off": "OFF",
    "dev": {"ids": ["A1B2C3"], "name": "Kitchen plug", "sa": "kitchen"}})");
  ASSERT_EQ(r.error, "");
  const auto& e = *r.entity;
  EXPECT_EQ(e.state_topic, "tasmota/plug/stat/POWER");
  EXPECT_EQ(e.command_topic, "tasmota/plug/cmnd/POWER");
  ASSERT_EQ(e.availability.size(), 1u);
  EXPECT_EQ(e.availability[0].topic, "tasmota/plug/tele/LWT");
  EXPECT_EQ(e.availability[0].payload_available, "Online");
  EXPECT_EQ(e.availability[0].payload_not_available, "Offline");
  EXPECT_EQ(e.device_id, "A1B2C3");
  EXPECT_EQ(e.area, "kitchen");
  EXPECT_EQ(e.state_on, "ON");
}

TEST(Discovery, SensorsReadTheirValueThroughTheTemplatesPath) {
  auto r = read_discovery("homeassistant/sensor/0xabc/temperature/config", R"({
    "state_topic": "zigbee2mqtt/bedroom_climate", "device_class": "temperature",
    "unit_of_measurement": "°C", "value_template": "{{ value_json.temperature }}"})");
  ASSERT_EQ(r.error, "");
  EXPECT_EQ(r.entity->device_class, "temperature");
  EXPECT_EQ(r.entity->unit, "°C");
  EXPECT_EQ(r.entity->value_path, std::vector<std::string>{"temperature"});
  EXPECT_EQ(r.entity->unique_id, "0xabc_temperature");
  r = read_discovery("homeassistant/switch/7/plug/config", R"({"uniq_id": "", "cmd_t": "p/set", "dev": {"ids": [""]}})");
  ASSERT_EQ(r.error, "");
  EXPECT_EQ(r.entity->unique_id, "7_plug");  // an empty unique_id is none
  EXPECT_EQ(r.entity->device_id, "7_plug");
  r = read_discovery("homeassistant/binary_sensor/sofa/config",
                     R"({"stat_t": "home/sofa", "dev_cla": "occupancy", "pl_on": true, "pl_off": false})");
  ASSERT_EQ(r.error, "");
  EXPECT_EQ(r.entity->device_class, "occupancy");
  EXPECT_EQ(r.entity->payload_on, "true");
  EXPECT_TRUE(r.entity->value_path.empty());

  EXPECT_EQ(value_template_path("{{ value_json['occupancy'] }}"), std::vector<std::string>{"occupancy"});
  EXPECT_EQ(value_template_path("{{value_json.a.b | float}}"), (std::vector<std::string>{"a", "b"}));
  EXPECT_EQ(value_template_path("{{ value }}"), std::vector<std::string>{});
  for (const char* other : {"{{ value_json.a + 1 }}", "{% if value %}on{% endif %}", "value_json.a", "{{ value_json }}",
                            "{{ value_json[0] }}", "{{ states('sensor.x') }}"}) {
    EXPECT_FALSE(value_template_path(other)) << other;
  }
}

TEST(Discovery, AnEmptyPayloadRemovesTheEntity) {
  const auto r = read_discovery("homeassistant/light/lamp/config", "");
  EXPECT_TRUE(r.removed);
  EXPECT_FALSE(r.entity);
  EXPECT_EQ(r.error, "");
}

TEST(Discovery, EveryBadConfigIsAnErrorNamingTheTopicAndTheReason) {
  const std::string t = "homeassistant/light/lamp/config";
  const std::pair<std::string, std::string> cases[] = {
      {"{not json", "the config is not JSON"},
      {"[1, 2]", "the config must be a JSON object, not array"},
      {R"({"command_topic": "a/set", "brightness_scale": 80104e45517})", "the config is not JSON: [json.exception.out_of_range.406] number overflow"},
      {R"({"state_topic": "a/b"})", "a light needs a command topic ('command_topic')"},
      {R"({"command_topic": "zigbee2mqtt/+/set"})", "'command_topic' is 'zigbee2mqtt/+/set': not a topic one can publish to"},
      {R"({"command_topic": "a/set", "state_topic": "a/#"})", "'state_topic' is 'a/#'"},
      {R"({"command_topic": "a/set", "schema": "template"})", "light schema 'template' is not supported"},
      {R"({"command_topic": "a/set", "value_template": "{{ value_json.a * 2 }}"})", "value_template '{{ value_json.a * 2 }}' is not one ICARS follows"},
      {R"({"command_topic": "a/set", "availability": "a/avail"})", "'availability' must be a list"},
      {R"({"command_topic": "a/set", "availability": [{"payload_available": "up"}]})", "an entry of 'availability' has no 'topic'"},
      {R"({"command_topic": "a/set", "availability_mode": "some"})", "availability_mode 'some' is not all, any or latest"},
      {R"({"command_topic": {"a": 1}})", "'command_topic' must be a string, not object"},
      {R"({"command_topic": "a/set", "brightness_scale": -3})", "'brightness_scale' must be a positive integer"},
      {R"({"command_topic": "a/set", "device": "lamp"})", "'device' must be an object"},
      // `~` standing for a base topic that is not there: no command topic.
      {R"({"command_topic": "~"})", "a light needs a command topic ('command_topic')"},
      {R"({"~": "", "cmd_t": "~"})", "a light needs a command topic ('command_topic')"},
  };
  for (const auto& [payload, reason] : cases) {
    const auto r = read_discovery(t, payload);
    EXPECT_FALSE(r.entity) << payload;
    EXPECT_EQ(r.error.rfind(t + ": ", 0), 0u) << r.error;
    EXPECT_NE(r.error.find(reason), std::string::npos) << "for " << payload << "\n got " << r.error;
  }
  auto r = read_discovery("homeassistant/vacuum/robo/config", R"({"command_topic": "robo/set"})");
  EXPECT_NE(r.error.find("component 'vacuum' is not supported (supported: light, switch, binary_sensor, sensor"),
            std::string::npos)
      << r.error;
  r = read_discovery("homeassistant/sensor/t/config", R"({"device_class": "temperature"})");
  EXPECT_NE(r.error.find("a sensor needs 'state_topic'"), std::string::npos) << r.error;
  r = read_discovery(t, std::string(70 * 1024, ' '));
  EXPECT_NE(r.error.find("a config of 71680 bytes is larger than 65536 bytes"), std::string::npos) << r.error;
  r = read_discovery("zigbee2mqtt/lamp", "{}");
  EXPECT_NE(r.error.find("not a discovery topic"), std::string::npos) << r.error;
}

TEST(Discovery, ClimateFanAndCoverNeedOnlyWhatTurnsThemOnOrOff) {
  auto r = read_discovery("homeassistant/climate/thermostat/config",
                          R"({"mode_cmd_t": "heat/mode/set", "mode_stat_t": "heat/mode", "modes": ["off", "heat"]})");
  ASSERT_EQ(r.error, "");
  EXPECT_EQ(r.entity->command_topic, "heat/mode/set");
  EXPECT_EQ(r.entity->state_topic, "heat/mode");
  r = read_discovery("homeassistant/fan/ceiling/config", R"({"cmd_t": "fan/set", "stat_t": "fan/state"})");
  EXPECT_EQ(r.error, "");
  r = read_discovery("homeassistant/cover/blind/config", R"({"cmd_t": "blind/set"})");
  EXPECT_EQ(r.error, "");
  r = read_discovery("homeassistant/climate/thermostat/config", R"({"temperature_command_topic": "t/set"})");
  EXPECT_NE(r.error.find("a climate needs a command topic ('mode_command_topic')"), std::string::npos) << r.error;
  // A power topic alone is not enough: nothing would confirm a command sent to it.
  r = read_discovery("homeassistant/climate/thermostat/config", R"({"power_command_topic": "t/power"})");
  EXPECT_NE(r.error.find("'mode_command_topic'"), std::string::npos) << r.error;
}

TEST(Discovery, ACoverReadsItsPayloadsAndStatesWithHomeAssistantsDefaults) {
  auto r = read_discovery("homeassistant/cover/blind/config", R"({"cmd_t": "blind/set", "stat_t": "blind/state"})");
  ASSERT_EQ(r.error, "");
  EXPECT_EQ(r.entity->payload_open, "OPEN");
  EXPECT_EQ(r.entity->payload_close, "CLOSE");
  EXPECT_EQ(r.entity->payload_stop, "STOP");
  EXPECT_EQ(r.entity->state_open, "open");
  EXPECT_EQ(r.entity->state_closed, "closed");
  EXPECT_EQ(r.entity->state_opening, "opening");
  EXPECT_EQ(r.entity->state_closing, "closing");
  EXPECT_EQ(r.entity->state_stopped, "stopped");
  // zigbee2mqtt's covers: abbreviated keys, upper-case states, the state in a JSON field.
  r = read_discovery("homeassistant/cover/0x01/cover/config", R"({
    "cmd_t": "zigbee2mqtt/blind/set", "stat_t": "zigbee2mqtt/blind", "val_tpl": "{{ value_json.state }}",
    "pl_open": "OPEN", "pl_cls": "CLOSE", "pl_stop": "STOP",
    "stat_open": "OPEN", "stat_clsd": "CLOSE", "stat_opening": "OPENING", "stat_closing": "CLOSING",
    "stat_stopped": "STOP"})");
  ASSERT_EQ(r.error, "");
  EXPECT_EQ(r.entity->value_path, std::vector<std::string>{"state"});
  EXPECT_EQ(r.entity->state_closed, "CLOSE");
  EXPECT_EQ(r.entity->state_opening, "OPENING");
  EXPECT_EQ(r.entity->state_stopped, "STOP");
}

TEST(Discovery, AClimateIsSwitchedByItsModeTopicsAndReadsItsModes) {
  auto r = read_discovery("homeassistant/climate/0x02/climate/config", R"({
    "mode_cmd_t": "zigbee2mqtt/trv/set/system_mode", "mode_stat_t": "zigbee2mqtt/trv",
    "mode_stat_tpl": "{{ value_json.system_mode }}", "modes": ["off", "heat", "auto"],
    "power_command_topic": "zigbee2mqtt/trv/set/power"})");
  ASSERT_EQ(r.error, "");
  EXPECT_EQ(r.entity->command_topic, "zigbee2mqtt/trv/set/system_mode");
  EXPECT_EQ(r.entity->state_topic, "zigbee2mqtt/trv");
  EXPECT_EQ(r.entity->value_path, std::vector<std::string>{"system_mode"});
  EXPECT_EQ(r.entity->modes, (std::vector<std::string>{"off", "heat", "auto"}));
  r = read_discovery("homeassistant/climate/ac/config", R"({"mode_command_topic": "ac/mode/set"})");
  ASSERT_EQ(r.error, "");
  EXPECT_EQ(r.entity->modes, (std::vector<std::string>{"auto", "off", "cool", "heat", "dry", "fan_only"}));
  for (const char* bad : {R"({"mode_command_topic": "ac/set", "modes": "heat"})",
                          R"({"mode_command_topic": "ac/set", "modes": ["off", 3]})"}) {
    r = read_discovery("homeassistant/climate/ac/config", bad);
    EXPECT_NE(r.error.find("'modes' must be a list of strings"), std::string::npos) << bad << ": " << r.error;
  }
}

}  // namespace
}  // namespace icars::bridge::mqtt
