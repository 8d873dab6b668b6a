// Fuzz target: Home Assistant MQTT discovery configs as a bridge reads them from a broker, where
// anyone on the broker may publish anything.
//
// The input is "<topic>\n<payload>" (no newline: all topic, an empty payload). read_discovery
// must not throw, and must give exactly one of: an entity, a removal, an error that begins with
// the topic. An entity's topics must be ones a client can publish to or subscribe to exactly
// (no wildcards), and its brightness scale positive.
#include <mosquitto.h>

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "fuzz_util.h"
#include "icars/bridge/mqtt/discovery.h"

namespace {

namespace mqtt = icars::bridge::mqtt;

void check_topic(const std::string& topic, const char* what) {
  if (topic.empty()) return;
  icars_fuzz::check(mosquitto_pub_topic_check(topic.c_str()) == MOSQ_ERR_SUCCESS, "discovery_fuzz", what);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  const auto newline = input.find('\n');
  const std::string_view topic = input.substr(0, newline);
  const std::string_view payload = newline == std::string_view::npos ? std::string_view{} : input.substr(newline + 1);
  const mqtt::DiscoveryResult r = mqtt::read_discovery(topic, payload);
  const int outcomes = (r.entity ? 1 : 0) + (r.removed ? 1 : 0) + (r.error.empty() ? 0 : 1);
  icars_fuzz::check(outcomes == 1, "discovery_fuzz", "not exactly one of entity, removal, error");
  if (!r.error.empty()) {
    icars_fuzz::note_rejected("discovery_fuzz", r.error.c_str());
    icars_fuzz::check(r.error.compare(0, topic.size(), topic) == 0, "discovery_fuzz", "an error not naming its topic");
  }
  if (r.entity) {
    const auto& e = *r.entity;
    check_topic(e.state_topic, "a state topic with wildcards");
    check_topic(e.command_topic, "a command topic with wildcards");
    check_topic(e.brightness_state_topic, "a brightness state topic with wildcards");
    check_topic(e.brightness_command_topic, "a brightness command topic with wildcards");
    for (const auto& a : e.availability) check_topic(a.topic, "an availability topic with wildcards");
    icars_fuzz::check(e.brightness_scale > 0, "discovery_fuzz", "a brightness scale that is not positive");
    icars_fuzz::check(!e.unique_id.empty() && !e.device_id.empty(), "discovery_fuzz", "an entity without ids");
  }
  return 0;
}
