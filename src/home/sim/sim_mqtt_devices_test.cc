// The simulated house's MQTT devices on a real mosquitto, with the simulated clock advanced by
// hand: their discovery configs are ones the bridge reads, a light obeys its command topic and
// confirms on its state topic, refuses a malformed command, the bed's sensor follows the user,
// the availability says online and, after stop(), offline; in lock-step a published state holds
// the activity until a bridge handled it.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "broker.h"
#include "icars/bridge/mqtt/discovery.h"
#include "icars/clock/time.h"
#include "icars/home/sim/sim_mqtt_devices.h"
#include "icars/sim/house.h"

namespace icars::home {
namespace {

using namespace std::chrono_literals;
namespace bm = icars::bridge::mqtt;
using nlohmann::json;

// Every topic's messages, as a subscriber hears them.
class Listener {
 public:
  explicit Listener(int port) : client_(options(port)) {
    client_.on_message([this](const bm::Message& m) {
      std::lock_guard lock(mutex_);
      heard_[m.topic].push_back(m.payload);
      changed_.notify_all();
    });
    client_.subscribe("#");
    client_.start();
    if (!client_.wait_connected(20s)) throw std::runtime_error("no broker");
  }
  // The last message on `topic` once `pred` holds for it (within 30 s), or nullopt.
  std::optional<std::string> wait(const std::string& topic, const std::function<bool(const std::string&)>& pred) {
    std::unique_lock lock(mutex_);
    std::optional<std::string> found;
    changed_.wait_for(lock, 30s, [&] {
      const auto it = heard_.find(topic);
      if (it == heard_.end() || it->second.empty() || !pred(it->second.back())) return false;
      found = it->second.back();
      return true;
    });
    return found;
  }
  void publish(const std::string& topic, const std::string& payload) { client_.publish(topic, payload); }

 private:
  static bm::ClientOptions options(int port) {
    bm::ClientOptions o;
    o.port = port;
    o.client_id = "sim-mqtt-test-listener";
    return o;
  }
  bm::Client client_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::string, std::vector<std::string>> heard_;
};

class SimMqttDevices : public ::testing::Test {
 protected:
  SimMqttDevices() : world_(sim::load_house(ICARS_PAPER_HOUSE_MQTT), clock_) {}

  std::unique_ptr<SimulatedMqttDevices> make(std::shared_ptr<Activity> activity = nullptr) {
    SimulatedMqttOptions options;
    options.broker.port = broker_.port();
    options.activity = std::move(activity);
    return std::make_unique<SimulatedMqttDevices>(world_, mqtt_devices(world_.house()),
                                                  [this](const DeviceEffect& e) {
                                                    std::lock_guard lock(mutex_);
                                                    effects_.push_back(e);
                                                  },
                                                  options);
  }

  bridge_test::Broker broker_;
  SimClock clock_{parse_time_of_day("18:00").value()};
  sim::World world_;
  std::mutex mutex_;
  std::vector<DeviceEffect> effects_;
};

TEST_F(SimMqttDevices, PublishesConfigsTheBridgeReadsWithTheHousesNamesAndPlaces) {
  Listener listener(broker_.port());
  auto devices = make();
  devices->start();
  const std::map<std::string, std::string> expected = {
      {"homeassistant/light/icars-sim/living_light/config", "0x0017880100a1b201_light"},
      {"homeassistant/light/icars-sim/bedroom_light/config", "0x0017880100a1b202_light"},
      {"homeassistant/binary_sensor/icars-sim/sofa_sensor/config", "0x00158d0001c3d401_occupancy"},
      {"homeassistant/binary_sensor/icars-sim/bed_sensor/config", "0x00158d0001c3d402_occupancy"},
  };
  for (const auto& [topic, unique_id] : expected) {
    SCOPED_TRACE(topic);
    const auto config = listener.wait(topic, [](const std::string& p) { return !p.empty(); });
    ASSERT_TRUE(config);
    const auto read = bm::read_discovery(topic, *config);
    ASSERT_TRUE(read.entity) << read.error;
    EXPECT_EQ(read.entity->unique_id, unique_id);
    EXPECT_FALSE(read.entity->state_topic.empty());
    ASSERT_EQ(read.entity->availability.size(), 1u);
    EXPECT_EQ(read.entity->availability[0].topic, devices->availability_topic());
  }
  EXPECT_TRUE(listener.wait(devices->availability_topic(), [](const std::string& p) { return p == "online"; }));
  // The bridge's placements give the entities the house's names, rooms and furniture.
  const auto placements = mqtt_placements(world_.house());
  ASSERT_EQ(placements.size(), 4u);
  EXPECT_EQ(placements.at("0x00158d0001c3d402_occupancy").device_id, "bed_sensor");
  EXPECT_EQ(placements.at("0x00158d0001c3d402_occupancy").room, "bedroom");
  EXPECT_EQ(placements.at("0x00158d0001c3d402_occupancy").furniture, "bed");
  EXPECT_EQ(placements.at("0x0017880100a1b201_light").furniture, "");

  devices->stop();
  EXPECT_TRUE(listener.wait(devices->availability_topic(), [](const std::string& p) { return p == "offline"; }));
}

TEST_F(SimMqttDevices, ALightObeysItsCommandTopicAndRefusesMalformedCommands) {
  Listener listener(broker_.port());
  auto devices = make();
  devices->start();
  const auto state = devices->state_topic("living_light");
  ASSERT_TRUE(listener.wait(state, [](const std::string& p) { return json::parse(p)["state"] == "OFF"; }));
  listener.publish(devices->command_topic("living_light"), R"({"state":"ON","brightness":127})");
  const auto on = listener.wait(state, [](const std::string& p) { return json::parse(p)["state"] == "ON"; });
  ASSERT_TRUE(on);
  EXPECT_EQ(json::parse(*on)["brightness"], 127);
  {
    std::lock_guard lock(mutex_);
    ASSERT_EQ(effects_.size(), 2u);
    EXPECT_EQ(effects_[0].device, "living_light");
    EXPECT_EQ(effects_[0].what, "power");
    EXPECT_EQ(effects_[0].value, "on");
    EXPECT_EQ(effects_[1].what, "intensity");
    EXPECT_EQ(effects_[1].value, "50");
  }
  // Not JSON, an unknown state, a brightness that is no number: refused, the state said again.
  for (const auto* bad : {"ON", R"({"state":"BRIGHT"})", R"({"brightness":"high"})", "[]"}) {
    listener.publish(devices->command_topic("living_light"), bad);
  }
  listener.publish(devices->command_topic("living_light"), R"({"state":"TOGGLE"})");
  ASSERT_TRUE(listener.wait(state, [](const std::string& p) { return json::parse(p)["state"] == "OFF"; }));
  std::lock_guard lock(mutex_);
  ASSERT_EQ(effects_.size(), 3u) << "a malformed command changed the light";
  EXPECT_EQ(effects_[2].value, "off");
}

TEST_F(SimMqttDevices, TheBedSensorFollowsTheUserAndHoldsTheClockUntilABridgeHandledIt) {
  Listener listener(broker_.port());
  const auto activity = Activity::create();
  auto devices = make(activity);
  devices->start();
  const auto bed = devices->state_topic("bed_sensor");
  ASSERT_TRUE(listener.wait(bed, [](const std::string& p) { return json::parse(p)["occupancy"] == false; }));
  // The first states were published retained: a bridge subscribing later gets the last one,
  // which stands for all of them.
  EXPECT_GT(devices->held(), 0u);
  for (const auto* id : {"living_light", "bedroom_light", "sofa_sensor", "bed_sensor"}) {
    devices->handled(bm::Message{devices->state_topic(id), "{}", true});
  }
  EXPECT_EQ(devices->held(), 0u);
  EXPECT_EQ(activity->busy(), 0u);

  clock_.advance_to(parse_time_of_day("22:45").value());  // the user lies in bed at 22:30
  ASSERT_TRUE(world_.occupied("bed"));
  ASSERT_TRUE(listener.wait(bed, [](const std::string& p) { return json::parse(p)["occupancy"] == true; }));
  EXPECT_GT(devices->held(), 0u);
  EXPECT_GT(activity->busy(), 0u) << "the clock may move before the bridge heard the user lie down";
  devices->handled(bm::Message{bed, R"({"occupancy":true})", false});
  for (const auto* id : {"living_light", "bedroom_light", "sofa_sensor", "bed_sensor"}) {
    devices->handled(bm::Message{devices->state_topic(id), "{}", true});
  }
  EXPECT_EQ(devices->held(), 0u);
  EXPECT_EQ(activity->busy(), 0u);
}

}  // namespace
}  // namespace icars::home
