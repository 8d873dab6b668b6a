// A collaboration policy driving a real home's MQTT devices through a mediating server: a real
// Mosquitto broker, the zigbee2mqtt/Tasmota-like fleet, MqttDevices registering them, and a
// MediatingServer on the wall clock running a policy. Motion in the hall (an MQTT binary sensor)
// moves the statechart, whose task switches the living-room lamp (an MQTT light) on — done only
// once the lamp's state topic confirmed it. With the lamp offline, the same task fails and the
// policy's `failed` transition takes over. A temperature from an MQTT sensor reaches a policy's
// rules through a Sense behavior like any other sensor's events.
#include <gtest/gtest.h>

#include <algorithm>
#include <mutex>
#include <string>
#include <vector>

#include "broker.h"
#include "child_process.h"
#include "fleet.h"
#include "icars/home/mqtt/entity_devices.h"
#include "policy_server.h"

namespace icars::home::mqtt {
namespace {

using namespace std::chrono_literals;
namespace bm = icars::bridge::mqtt;

constexpr const char* kPolicy = R"xml(<?xml version="1.0" encoding="UTF-8"?>
<policy name="hall_light">
  <task name="Watch" events="Motion">
    <interpret name="Hall">
      <rule when="event == 'MotionEvent' and motion" emit="Motion"/>
      <behavior type="Sense" service="MotionSensor" room="hallway"/>
    </interpret>
  </task>
  <task name="Light">
    <behavior type="SetLights" on="true" rooms="living_room"/>
  </task>
  <task name="Trouble">
    <behavior type="Wait" duration="1h"/>
  </task>
  <statechart initial="Watching">
    <transition event="failed" target="InTrouble"/>
    <state name="Watching" task="Watch"><transition event="Motion" target="Lighting"/></state>
    <state name="Lighting" task="Light"><transition event="done" target="Watching"/></state>
    <state name="InTrouble" task="Trouble"/>
  </statechart>
</policy>
)xml";

// A policy that watches the bedroom's temperature.
constexpr const char* kWarmPolicy = R"xml(<?xml version="1.0" encoding="UTF-8"?>
<policy name="too_warm">
  <task name="Watch" events="TooWarm">
    <interpret name="Bedroom">
      <rule when="event == 'MeasurementEvent' and quantity == 'temperature' and value > 25" emit="TooWarm"/>
      <behavior type="Sense" service="MeasurementSensor" room="bedroom"/>
    </interpret>
  </task>
  <task name="Cool">
    <behavior type="Wait" duration="1h"/>
  </task>
  <statechart initial="Watching">
    <state name="Watching" task="Watch"><transition event="TooWarm" target="Cooling"/></state>
    <state name="Cooling" task="Cool"/>
  </statechart>
</policy>
)xml";

// A lamp that does not answer at first: the retry's next attempt switches it.
constexpr const char* kRetryPolicy = R"xml(<?xml version="1.0" encoding="UTF-8"?>
<policy name="retry_light">
  <task name="Light">
    <retry name="On" times="6" delay="500ms"><behavior type="SetLights" on="true" rooms="living_room"/></retry>
  </task>
  <task name="Rest">
    <behavior type="Wait" duration="1h"/>
  </task>
  <statechart initial="Lighting">
    <transition event="failed" target="InTrouble"/>
    <state name="Lighting" task="Light"><transition event="done" target="Resting"/></state>
    <state name="Resting" task="Rest"/>
    <state name="InTrouble" task="Rest"/>
  </statechart>
</policy>
)xml";

// The fleet on a broker of its own and the bridge registering its devices with a server.
struct MqttHome {
  MqttHome(std::uint16_t server_port, MqttDevicesOptions options)
      : fleet(broker.port()), client(client_options(broker.port())), manager(manager_side),
        devices(client, manager, std::move(options)) {
    client.start();
    manager.connect("127.0.0.1", server_port);
    fleet.start();
  }
  static bm::ClientOptions client_options(int port) {
    bm::ClientOptions o;
    o.port = port;
    o.client_id = "icars-bridge";
    return o;
  }
  bridge_test::Broker broker;
  mqtt_test::Fleet fleet;
  bm::Client client;
  planet::Communicator manager_side;
  device::DeviceManager manager;
  MqttDevices devices;
};

class MqttPolicy : public ::testing::Test {
 protected:
  // The transitions the policy took, as the trace says them.
  std::vector<std::string> transitions() {
    std::lock_guard lock(mutex_);
    return transitions_;
  }
  bool took(const std::string& transition) {
    const auto all = transitions();
    return std::find(all.begin(), all.end(), transition) != all.end();
  }

  home_test::PolicyServer policy_{{{"hall_light", kPolicy}, {"too_warm", kWarmPolicy}, {"retry_light", kRetryPolicy}}};
  std::mutex mutex_;
  std::vector<std::string> transitions_;
};

TEST_F(MqttPolicy, MotionOnAnMqttSensorSwitchesAnMqttLampAndAnOfflineLampFailsTheTask) {
  MqttDevicesOptions options;
  options.placements[mqtt_test::Fleet::unique_id("living_lamp")] = Placement{"living_light", "living_room", ""};
  MqttHome home(policy_.port(), options);
  auto& fleet = home.fleet;
  auto& c = policy_->container();
  ASSERT_TRUE(planet_test::wait_until([&] {
    return c.find(service::ServiceQuery::of_type("LightControl").in_room("living_room").available()).size() == 1 &&
           c.find(service::ServiceQuery::of_type("MotionSensor").in_room("hallway").available()).size() == 1;
  }, 30s));

  policy_->trace().add_sink([this](const behavior::TraceRecord& r) {
    if (r.kind != "transition") return;
    std::lock_guard lock(mutex_);
    transitions_.push_back(r.text);
  });
  policy_->run_policy("hall_light");
  // Someone walks through the hall, every 40th look (200 ms): the sensor goes off and on.
  int looks = 0;
  const auto walk_through = [&] {
    if (looks++ % 40 != 0) return;
    fleet.set_sensor("hall_motion", false);
    fleet.set_sensor("hall_motion", true);
  };

  // Motion in the hall: the lamp goes on, and the task is done only once the lamp said so.
  // (The sensor is toggled until the Sense behavior, which subscribes as the policy starts, hears it.)
  ASSERT_TRUE(planet_test::wait_until([&] {
    walk_through();
    return took("Lighting -> Watching on done");
  }, 60s)) << ::testing::PrintToString(transitions());
  EXPECT_EQ(fleet.on("living_lamp"), true);
  EXPECT_TRUE(took("Watching -> Lighting on Motion"));

  // The lamp goes offline: its service leaves the server, and the next motion fails the task.
  fleet.set_online("living_lamp", false);
  ASSERT_TRUE(planet_test::wait_until([&] {
    return c.find(service::ServiceQuery::of_type("LightControl").in_room("living_room").available()).empty();
  }, 30s));
  looks = 0;
  ASSERT_TRUE(planet_test::wait_until([&] {
    walk_through();
    return policy_.state() == "InTrouble";
  }, 60s)) << ::testing::PrintToString(transitions());
  const auto all = transitions();
  ASSERT_FALSE(all.empty());
  EXPECT_NE(all.back().find("Lighting -> InTrouble on failed"), std::string::npos) << all.back();
  EXPECT_NE(all.back().find("no available light"), std::string::npos) << all.back();
  policy_->stop();
}

TEST_F(MqttPolicy, ATemperatureFromAnMqttSensorReachesThePolicysRules) {
  MqttHome home(policy_.port(), {});
  auto& c = policy_->container();
  ASSERT_TRUE(planet_test::wait_until([&] {
    return c.find(service::ServiceQuery::of_type("MeasurementSensor").in_room("bedroom").available()).size() == 1;
  }, 30s));
  policy_->trace().add_sink([this](const behavior::TraceRecord& r) {
    if (r.kind != "transition") return;
    std::lock_guard lock(mutex_);
    transitions_.push_back(r.text);
  });
  policy_->run_policy("too_warm");
  // The room warms up, a quarter degree every 200 ms (the Sense behavior subscribes as the
  // policy starts, so a change before that is not heard).
  int looks = 0;
  double temperature = 24.0;
  ASSERT_TRUE(planet_test::wait_until([&] {
    if (looks++ % 40 == 0) home.fleet.set_measurement("bedroom_temp", temperature += 0.25);
    return took("Watching -> Cooling on TooWarm");
  }, 60s)) << ::testing::PrintToString(transitions());
  EXPECT_GT(temperature, 25.0) << "moved before the temperature was above 25";
  policy_->stop();
}

// A retry starts the same SetLights again: an attempt whose lamp did not confirm fails, and the
// next attempt, with the lamp answering again, succeeds (the failure is not carried over).
TEST_F(MqttPolicy, ALampThatDidNotAnswerTheFirstAttemptIsSwitchedByTheRetry) {
  MqttDevicesOptions options;
  options.placements[mqtt_test::Fleet::unique_id("living_lamp")] = Placement{"living_light", "living_room", ""};
  options.command_timeout = 500ms;
  MqttHome home(policy_.port(), options);
  auto& c = policy_->container();
  ASSERT_TRUE(planet_test::wait_until([&] {
    return c.find(service::ServiceQuery::of_type("LightControl").in_room("living_room").available()).size() == 1;
  }, 30s));
  std::vector<std::string> notes;
  policy_->trace().add_sink([this, &notes](const behavior::TraceRecord& r) {
    std::lock_guard lock(mutex_);
    if (r.kind == "transition") transitions_.push_back(r.text);
    if (r.kind == "note") notes.push_back(r.text);
  });
  const auto noted = [&](const std::string& text) {
    std::lock_guard lock(mutex_);
    return std::any_of(notes.begin(), notes.end(), [&](const std::string& n) { return n.find(text) != std::string::npos; });
  };
  home.fleet.ignore_commands(true);
  policy_->run_policy("retry_light");
  ASSERT_TRUE(planet_test::wait_until([&] { return noted("attempt 2 of 6"); }, 60s));
  home.fleet.ignore_commands(false);
  ASSERT_TRUE(planet_test::wait_until([&] { return policy_.state() != "Lighting"; }, 60s))
      << ::testing::PrintToString(transitions());
  EXPECT_EQ(policy_.state(), "Resting") << ::testing::PrintToString(transitions());
  EXPECT_EQ(home.fleet.on("living_lamp"), true);
  EXPECT_FALSE(noted("attempt 4 of 6")) << "an attempt with the lamp answering failed";
  policy_->stop();
}

}  // namespace
}  // namespace icars::home::mqtt
