// A real home's MQTT devices as ICARS devices, end to end: a real Mosquitto broker, a
// zigbee2mqtt/Tasmota-like fleet publishing Home Assistant discovery, the bridge with its
// device manager, and a real mediating server (PLANET + Service Framework) in this process.
// The server finds the devices' services by type and room; commands are acknowledged only once
// the device's state topic confirms them and fail with a clear error when it never does, when
// the device is offline or when the broker is gone; sensor changes reach subscribers on the
// server; availability takes services away and brings them back; configs the bridge cannot use
// are reported and the bridge goes on. Besides lights, switches and occupancy and motion sensors:
// a temperature sensor's readings, a cover's open/close/stop, a fan's and a thermostat's power.
#include "icars/home/mqtt/entity_devices.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <future>
#include <iterator>
#include <map>
#include <mutex>
#include <thread>
#include <vector>

#include "broker.h"
#include "child_process.h"
#include "fleet.h"
#include "icars/home/adaptors.h"
#include "icars/home/services.h"
#include "icars/service/service_framework.h"
#include "scoped_subscription.h"

namespace icars::home::mqtt {
namespace {

using namespace icars::service;
using namespace std::chrono_literals;
namespace bm = icars::bridge::mqtt;
namespace p = icars::planet;

bm::ClientOptions bridge_client(const bridge_test::Broker& broker) {
  bm::ClientOptions o;
  o.port = broker.port();
  o.client_id = "icars-bridge";
  return o;
}

class MqttDevicesTest : public ::testing::Test {
 protected:
  void SetUp() override { server_port_ = server_.listen("127.0.0.1", 0); }

  void start(std::chrono::milliseconds command_timeout = 5s) {
    MqttDevicesOptions o;
    o.command_timeout = command_timeout;
    o.placements[mqtt_test::Fleet::unique_id("bed_sensor")] =
        Placement{"bed_occupancy", "bedroom", "bed"};
    bridge_ = std::make_unique<MqttDevices>(client_, manager_, o);
    client_.start();
    manager_.connect("127.0.0.1", server_port_);
    fleet_.start();
    ASSERT_TRUE(planet_test::wait_until([&] { return services_ready(); }, 30s))
        << describe_services();
  }

  bool services_ready() {
    auto& c = sf_.container();
    return c.find(ServiceQuery::of_type("LightControl").available()).size() == 3 &&
           c.find(ServiceQuery::of_type("OccupancySensor").available()).size() == 1 &&
           c.find(ServiceQuery::of_type("MotionSensor").available()).size() == 1 &&
           c.find(ServiceQuery::of_type("MeasurementSensor").available()).size() == 1 &&
           c.find(ServiceQuery::of_type("CoverControl").available()).size() == 1 &&
           c.find(ServiceQuery::of_type("FanControl").available()).size() == 1 &&
           c.find(ServiceQuery::of_type("ClimateControl").available()).size() == 1;
  }

  std::string describe_services() {
    std::string out = "services:";
    for (const auto& s : sf_.container().all()) {
      out += " " + s->id() + "[" + s->type() + (s->available() ? "" : ", unavailable") + "]";
    }
    return out;
  }

  std::shared_ptr<LightService> light(const std::string& device) {
    return sf_.container().find_first<LightService>(
        ServiceQuery::of_type("LightControl").on_device(device).available());
  }

  // The light capability served by the device manager, called directly (not through the
  // server's registry), as a caller that kept its reference would.
  home::LightPrx direct_light(const std::string& device) {
    if (manager_port_ == 0) manager_port_ = manager_side_.listen("127.0.0.1", 0);
    return home::LightPrx(caller_, caller_.connect("127.0.0.1", manager_port_),
                          "/devices/" + device + "/light");
  }

  template <class S>
  std::shared_ptr<S> service(const std::string& type, const std::string& device) {
    return sf_.container().find_first<S>(ServiceQuery::of_type(type).on_device(device).available());
  }

  std::size_t problems_with(const std::string& part) const {
    const auto all = bridge_->problems();
    return static_cast<std::size_t>(std::count_if(
        all.begin(), all.end(), [&](const auto& p) { return p.find(part) != std::string::npos; }));
  }

  bool online(const std::string& device_id) const {
    for (const auto& d : bridge_->devices()) {
      if (d.device_id == device_id) return d.online;
    }
    return false;
  }

  bool has_problem(const std::string& part) const {
    for (const auto& p : bridge_->problems()) {
      if (p.find(part) != std::string::npos) return true;
    }
    return false;
  }

  bridge_test::Broker broker_;
  p::Communicator server_;
  ServiceFramework sf_{server_, adaptors(), {}, {composer()}};
  std::uint16_t server_port_ = 0;
  mqtt_test::Fleet fleet_{broker_.port()};
  bm::Client client_{bridge_client(broker_)};
  p::Communicator manager_side_;
  device::DeviceManager manager_{manager_side_};
  std::unique_ptr<MqttDevices> bridge_;
  std::uint16_t manager_port_ = 0;
  p::Communicator caller_;
};

std::string error_of(const std::function<void()>& call, p::ErrorKind* kind = nullptr) {
  try {
    call();
  } catch (const p::Error& e) {
    if (kind) *kind = e.kind();
    return e.what();
  }
  return "";
}

TEST_F(MqttDevicesTest, DiscoveredEntitiesBecomeServicesFoundByTypeAndRoom) {
  start();
  auto& c = sf_.container();
  const auto bedroom_lights = c.find(ServiceQuery::of_type("LightControl").in_room("bedroom"));
  ASSERT_EQ(bedroom_lights.size(), 1u);
  EXPECT_EQ(bedroom_lights[0]->attributes().device, "bedroom_lamp_z2m");
  EXPECT_EQ(c.find(ServiceQuery::of_type("LightControl").in_room("living_room")).size(), 1u);
  EXPECT_EQ(c.find(ServiceQuery::of_type("LightControl").in_room("kitchen")).size(), 1u)
      << "the switch";
  const auto bed = c.find(ServiceQuery::of_type("OccupancySensor").in_room("bedroom"));
  ASSERT_EQ(bed.size(), 1u);
  EXPECT_EQ(bed[0]->attributes().device, "bed_occupancy") << "from the placement table";
  EXPECT_EQ(c.find(ServiceQuery::of_type("MotionSensor").in_room("hallway")).size(), 1u);
  EXPECT_EQ(c.find(ServiceQuery::of_type("MeasurementSensor").in_room("bedroom")).size(), 1u);
  EXPECT_EQ(c.find(ServiceQuery::of_type("CoverControl").in_room("living_room")).size(), 1u);
  EXPECT_EQ(c.find(ServiceQuery::of_type("FanControl").in_room("bedroom")).size(), 1u);
  EXPECT_EQ(c.find(ServiceQuery::of_type("ClimateControl").in_room("living_room")).size(), 1u);
  EXPECT_TRUE(c.find(ServiceQuery::of_type("LightControl").in_room("bedroom")).size() == 1)
      << "a fan is not a light";

  const auto devices = bridge_->devices();
  ASSERT_EQ(devices.size(), std::size(mqtt_test::kFleetDevices));
  std::map<std::string, std::string> types;
  for (const auto& d : devices) {
    EXPECT_TRUE(d.online) << d.device_id;
    types[d.device_id] = d.type;
  }
  EXPECT_EQ(types["bedroom_temp_z2m"], "MeasurementSensor");
  EXPECT_EQ(types["living_blind_z2m"], "Cover");
  EXPECT_EQ(types["bedroom_fan_z2m"], "Fan");
  EXPECT_EQ(types["living_thermostat_z2m"], "Climate");
  auto occupancy = c.find_first<OccupancyService>(ServiceQuery::of_type("OccupancySensor"));
  ASSERT_TRUE(occupancy);
  EXPECT_EQ(occupancy->proxy().furniture(), "bed");
  EXPECT_FALSE(occupancy->proxy().occupied());
  auto temperature = service<MeasurementService>("MeasurementSensor", "bedroom_temp_z2m");
  ASSERT_TRUE(temperature);
  EXPECT_EQ(temperature->proxy().quantity(), "temperature");
  EXPECT_EQ(temperature->proxy().unit(), "°C");
  EXPECT_EQ(temperature->proxy().value(), 21.5) << "the retained state";
  auto blind = service<CoverService>("CoverControl", "living_blind_z2m");
  ASSERT_TRUE(blind);
  EXPECT_EQ(blind->proxy().state().position, "closed");
  auto thermostat = service<PowerSwitchService>("ClimateControl", "living_thermostat_z2m");
  ASSERT_TRUE(thermostat);
  EXPECT_FALSE(thermostat->proxy().on()) << "mode off";
  EXPECT_TRUE(bridge_->problems().empty());
}

TEST_F(MqttDevicesTest, ALightCommandIsAcknowledgedOnlyOnceTheDeviceConfirmsIt) {
  start();
  fleet_.set_delay(400ms);  // the device reports its new state this late
  auto lamp = light("bedroom_lamp_z2m");
  ASSERT_TRUE(lamp);
  const auto before = std::chrono::steady_clock::now();
  lamp->proxy().set_power(true);
  EXPECT_GE(std::chrono::steady_clock::now() - before, 350ms)
      << "acknowledged before the device confirmed";
  EXPECT_EQ(fleet_.on("bedroom_lamp"), true);
  EXPECT_TRUE(lamp->proxy().state().on);

  lamp->proxy().set_intensity(50);
  EXPECT_EQ(fleet_.brightness("bedroom_lamp"), 128) << "50 % of brightness_scale 255";
  EXPECT_EQ(lamp->proxy().state().intensity, 50);
  lamp->proxy().set_power(false);
  EXPECT_EQ(fleet_.on("bedroom_lamp"), false);
  EXPECT_FALSE(lamp->proxy().state().on);
  EXPECT_THROW(lamp->proxy().set_intensity(101), home::OutOfRange);

  // The default schema (Tasmota): brightness on its own topics, scale 100.
  fleet_.set_delay(0ms);
  auto living = light("living_lamp_z2m");
  ASSERT_TRUE(living);
  living->proxy().set_intensity(30);
  EXPECT_EQ(fleet_.on("living_lamp"), true);
  EXPECT_EQ(fleet_.brightness("living_lamp"), 30);
  EXPECT_EQ(living->proxy().state().intensity, 30);
  living->proxy().set_power(false);
  EXPECT_EQ(fleet_.on("living_lamp"), false);

  // A switch is a light that is on or off only.
  auto kettle = light("kettle_z2m");
  ASSERT_TRUE(kettle);
  kettle->proxy().set_intensity(100);
  EXPECT_EQ(fleet_.on("kettle"), true);
  EXPECT_EQ(kettle->proxy().state().intensity, 100);
  EXPECT_THROW(kettle->proxy().set_intensity(50), home::OutOfRange);
  kettle->proxy().set_intensity(0);
  EXPECT_EQ(fleet_.on("kettle"), false);
}

TEST_F(MqttDevicesTest, ACommandTheDeviceIgnoresFailsAfterTheTimeoutNamingEntityTopicAndTimeout) {
  start(1s);
  auto lamp = light("bedroom_lamp_z2m");
  ASSERT_TRUE(lamp);
  fleet_.ignore_commands(true);
  p::ErrorKind kind{};
  const auto before = std::chrono::steady_clock::now();
  const auto error = error_of([&] { lamp->proxy().set_power(true); }, &kind);
  const auto took = std::chrono::steady_clock::now() - before;
  EXPECT_EQ(kind, p::ErrorKind::timeout) << error;
  EXPECT_NE(error.find("Bedroom lamp"), std::string::npos) << error;
  EXPECT_NE(error.find("zigbee2mqtt/bedroom_lamp/set"), std::string::npos) << error;
  EXPECT_NE(error.find("1000 ms"), std::string::npos) << error;
  EXPECT_GE(took, 900ms);
  EXPECT_EQ(fleet_.commands("bedroom_lamp"), 1) << "the command was sent";
  EXPECT_EQ(fleet_.on("bedroom_lamp"), false);

  // Obeyed again: the next command is acknowledged.
  fleet_.ignore_commands(false);
  lamp->proxy().set_power(true);
  EXPECT_EQ(fleet_.on("bedroom_lamp"), true);
}

TEST_F(MqttDevicesTest, OccupancyAndMotionChangesReachSubscribersOnTheServer) {
  start();
  auto bed = sf_.container().find_first<OccupancyService>(ServiceQuery::of_type("OccupancySensor"));
  auto hall =
      sf_.container().find_first<MotionSensorService>(ServiceQuery::of_type("MotionSensor"));
  ASSERT_TRUE(bed && hall);
  std::mutex mutex;
  std::vector<home::OccupancyEvent> occupancy;
  std::vector<home::MotionEvent> motion;
  const auto s1 = planet_test::subscribe_scoped(*bed, [&](const home::OccupancyEvent& e) {
    std::lock_guard lock(mutex);
    occupancy.push_back(e);
  });
  const auto s2 = planet_test::subscribe_scoped(*hall, [&](const home::MotionEvent& e) {
    std::lock_guard lock(mutex);
    motion.push_back(e);
  });
  // The adaptors subscribe to their sensors asynchronously after registration: change the
  // sensors until a change reaches the server.
  bool state = false;
  ASSERT_TRUE(planet_test::wait_until(
      [&] {
        {
          std::lock_guard lock(mutex);
          const bool heard_bed = std::any_of(occupancy.begin(), occupancy.end(),
                                             [](const auto& e) { return e.occupied; });
          const bool heard_hall =
              std::any_of(motion.begin(), motion.end(), [](const auto& e) { return e.motion; });
          if (heard_bed && heard_hall) return true;
        }
        state = !state;
        fleet_.set_sensor("bed_sensor", state);
        fleet_.set_sensor("hall_motion", state);
        std::this_thread::sleep_for(100ms);  // lets the change travel before the next flip
        return false;
      },
      30s));
  std::lock_guard lock(mutex);
  const auto e =
      *std::find_if(occupancy.begin(), occupancy.end(), [](const auto& o) { return o.occupied; });
  EXPECT_EQ(e.device, "bed_occupancy");
  EXPECT_EQ(e.furniture, "bed");
  EXPECT_GT(e.time_ms, 0);
  const auto m =
      *std::find_if(motion.begin(), motion.end(), [](const auto& o) { return o.motion; });
  EXPECT_EQ(m.device, "hall_motion_z2m");
  EXPECT_EQ(m.room, "hallway");
}

TEST_F(MqttDevicesTest, TemperatureChangesReachSubscribersAndANonNumericReadingIsReportedOnce) {
  start();
  auto sensor = service<MeasurementService>("MeasurementSensor", "bedroom_temp_z2m");
  ASSERT_TRUE(sensor);
  std::mutex mutex;
  std::vector<home::MeasurementEvent> heard;
  const auto subscription =
      planet_test::subscribe_scoped(*sensor, [&](const home::MeasurementEvent& e) {
        std::lock_guard lock(mutex);
        heard.push_back(e);
      });
  const auto heard_value = [&](double value) {
    std::lock_guard lock(mutex);
    return std::any_of(heard.begin(), heard.end(), [&](const auto& e) { return e.value == value; });
  };
  // The adaptor subscribes to its sensor asynchronously after registration: change the reading
  // until a change reaches the server.
  double reading = 22.0;
  ASSERT_TRUE(planet_test::wait_until(
      [&] {
        if (heard_value(reading)) return true;
        reading += 0.5;
        fleet_.set_measurement("bedroom_temp", reading);
        std::this_thread::sleep_for(100ms);  // lets the change travel before the next one
        return false;
      },
      30s));
  {
    std::lock_guard lock(mutex);
    const auto e = *std::find_if(heard.begin(), heard.end(),
                                 [&](const auto& m) { return m.value == reading; });
    EXPECT_EQ(e.device, "bedroom_temp_z2m");
    EXPECT_EQ(e.quantity, "temperature");
    EXPECT_EQ(e.unit, "°C");
    EXPECT_EQ(e.room, "bedroom");
    EXPECT_GT(e.time_ms, 0);
  }
  EXPECT_EQ(sensor->proxy().value(), reading);

  // A reading that is not a number is reported once and ignored; the next number is an event.
  const auto topic = mqtt_test::Fleet::state_topic("bedroom_temp");
  fleet_.publish(topic, R"({"temperature":"warm","humidity":45})");
  fleet_.publish(topic, R"({"temperature":"warm","humidity":45})");
  fleet_.set_measurement("bedroom_temp", 30.25);
  ASSERT_TRUE(planet_test::wait_until([&] { return heard_value(30.25); }));
  EXPECT_EQ(problems_with("zigbee2mqtt/bedroom_temp: state of sensor 'Bedroom temperature' "
                          "(bedroom_temp_z2m) ignored: 'warm' is not a number"),
            1u)
      << fmt::format("{}", fmt::join(bridge_->problems(), "\n"));
  EXPECT_EQ(sensor->proxy().value(), 30.25);
  std::lock_guard lock(mutex);
  const auto events_of_30 =
      std::count_if(heard.begin(), heard.end(), [](const auto& e) { return e.value == 30.25; });
  EXPECT_EQ(events_of_30, 1) << "an event for every change, one per change";
}

TEST_F(MqttDevicesTest, ACoverMovesAndAFanAndAThermostatSwitchOnlyOnceTheDeviceConfirms) {
  start();
  fleet_.set_delay(400ms);  // the devices report their new state this late
  auto blind = service<CoverService>("CoverControl", "living_blind_z2m");
  ASSERT_TRUE(blind);
  auto before = std::chrono::steady_clock::now();
  blind->proxy().open();
  EXPECT_GE(std::chrono::steady_clock::now() - before, 350ms)
      << "acknowledged before the cover confirmed";
  EXPECT_EQ(fleet_.position("living_blind"), "open");
  EXPECT_EQ(fleet_.commands("living_blind"), 1);
  ASSERT_TRUE(planet_test::wait_until([&] { return blind->proxy().state().position == "open"; }))
      << "'opening' confirmed it; 'open' follows";
  blind->proxy().close();
  EXPECT_EQ(fleet_.position("living_blind"), "closed");
  // A stop is confirmed by any state at rest: the fleet's "closed" after its "closing" may be
  // the one, so the test waits for the fleet to have the stop rather than assume it has.
  blind->proxy().stop();
  EXPECT_TRUE(planet_test::wait_until([&] { return fleet_.commands("living_blind") == 3; }));
  EXPECT_EQ(blind->proxy().state().position, "closed");

  auto fan = service<PowerSwitchService>("FanControl", "bedroom_fan_z2m");
  ASSERT_TRUE(fan);
  before = std::chrono::steady_clock::now();
  fan->proxy().set_power(true);
  EXPECT_GE(std::chrono::steady_clock::now() - before, 350ms)
      << "acknowledged before the fan confirmed";
  EXPECT_EQ(fleet_.on("bedroom_fan"), true);
  EXPECT_TRUE(fan->proxy().on());
  fan->proxy().set_power(false);
  EXPECT_EQ(fleet_.on("bedroom_fan"), false);
  EXPECT_FALSE(fan->proxy().on());

  // A thermostat is switched by its mode: on is its first mode other than "off" ...
  fleet_.set_delay(0ms);
  auto thermostat = service<PowerSwitchService>("ClimateControl", "living_thermostat_z2m");
  ASSERT_TRUE(thermostat);
  thermostat->proxy().set_power(true);
  EXPECT_EQ(fleet_.mode("living_thermostat"), "heat");
  EXPECT_TRUE(thermostat->proxy().on());
  // ... or the mode it last ran in.
  fleet_.publish(mqtt_test::Fleet::state_topic("living_thermostat"), R"({"system_mode":"auto"})",
                 true);
  thermostat->proxy().set_power(false);
  EXPECT_EQ(fleet_.mode("living_thermostat"), "off");
  EXPECT_FALSE(thermostat->proxy().on());
  thermostat->proxy().set_power(true);
  EXPECT_EQ(fleet_.mode("living_thermostat"), "auto");
  EXPECT_TRUE(bridge_->problems().empty())
      << fmt::format("{}", fmt::join(bridge_->problems(), "\n"));
}

TEST_F(MqttDevicesTest, ACoverOrFanCommandTheDeviceIgnoresFailsAfterTheTimeout) {
  start(1s);
  fleet_.ignore_commands(true);
  auto fan = service<PowerSwitchService>("FanControl", "bedroom_fan_z2m");
  auto blind = service<CoverService>("CoverControl", "living_blind_z2m");
  ASSERT_TRUE(fan && blind);
  p::ErrorKind kind{};
  auto error = error_of([&] { fan->proxy().set_power(true); }, &kind);
  EXPECT_EQ(kind, p::ErrorKind::timeout) << error;
  EXPECT_NE(error.find("fan 'Bedroom fan'"), std::string::npos) << error;
  EXPECT_NE(error.find("esphome/bedroom_fan/command"), std::string::npos) << error;
  EXPECT_NE(error.find("1000 ms"), std::string::npos) << error;
  EXPECT_EQ(fleet_.commands("bedroom_fan"), 1) << "the command was sent";
  EXPECT_FALSE(fan->proxy().on());

  kind = {};
  error = error_of([&] { blind->proxy().open(); }, &kind);
  EXPECT_EQ(kind, p::ErrorKind::timeout) << error;
  EXPECT_NE(error.find("cover 'Living blind'"), std::string::npos) << error;
  EXPECT_NE(error.find("open it"), std::string::npos) << error;
  EXPECT_EQ(blind->proxy().state().position, "closed");

  fleet_.ignore_commands(false);
  blind->proxy().open();
  EXPECT_EQ(fleet_.position("living_blind"), "open");
}

TEST_F(MqttDevicesTest, AnOfflineDeviceLeavesTheServerAndComesBackWhenOnline) {
  start();
  ASSERT_TRUE(light("kettle_z2m"));
  fleet_.set_online("kettle", false);
  ASSERT_TRUE(planet_test::wait_until([&] { return !light("kettle_z2m"); })) << describe_services();
  // Its services are unbound (unavailable) first, then removed.
  EXPECT_TRUE(planet_test::wait_until(
      [&] { return sf_.container().find(ServiceQuery::of_type("LightControl").in_room("kitchen")).empty(); }))
      << describe_services();
  EXPECT_FALSE(online("kettle_z2m"));
  EXPECT_TRUE(light("bedroom_lamp_z2m")) << "the others stay";

  fleet_.set_online("kettle", true);
  ASSERT_TRUE(planet_test::wait_until([&] { return light("kettle_z2m") != nullptr; }))
      << describe_services();
  light("kettle_z2m")->proxy().set_power(true);
  EXPECT_EQ(fleet_.on("kettle"), true);

  // An empty config removes the entity: its device leaves the server until a config comes again.
  fleet_.publish(mqtt_test::Fleet::config_topic("kettle"), "", true);
  ASSERT_TRUE(planet_test::wait_until([&] { return !light("kettle_z2m"); })) << describe_services();
  fleet_.publish(mqtt_test::Fleet::config_topic("kettle"), mqtt_test::Fleet::config("kettle"),
                 true);
  ASSERT_TRUE(planet_test::wait_until([&] { return light("kettle_z2m") != nullptr; }))
      << describe_services();

  // availability_mode "all": the bedroom lamp needs the zigbee2mqtt bridge online too.
  fleet_.set_bridge_online(false);
  ASSERT_TRUE(planet_test::wait_until([&] { return !light("bedroom_lamp_z2m"); }))
      << describe_services();
  fleet_.set_bridge_online(true);
  ASSERT_TRUE(planet_test::wait_until([&] { return light("bedroom_lamp_z2m") != nullptr; }))
      << describe_services();
}

TEST_F(MqttDevicesTest, ACommandWhileOfflineOrWithoutTheBrokerFailsAtOnceWithTheReason) {
  start();
  auto lamp = direct_light("bedroom_lamp_z2m");
  lamp.set_power(true);
  EXPECT_EQ(fleet_.on("bedroom_lamp"), true);

  fleet_.set_online("bedroom_lamp", false);
  ASSERT_TRUE(planet_test::wait_until([&] { return !online("bedroom_lamp_z2m"); }));
  auto before = std::chrono::steady_clock::now();
  auto error = error_of([&] { lamp.set_power(false); });
  EXPECT_LT(std::chrono::steady_clock::now() - before, 2s);
  EXPECT_NE(error.find("offline"), std::string::npos) << error;
  EXPECT_NE(error.find("zigbee2mqtt/bedroom_lamp/availability"), std::string::npos) << error;
  EXPECT_EQ(fleet_.commands("bedroom_lamp"), 1) << "nothing sent while offline";

  // Offline while a command waits for its confirmation: it fails then, with the reason.
  fleet_.set_online("bedroom_lamp", true);
  ASSERT_TRUE(planet_test::wait_until([&] { return online("bedroom_lamp_z2m"); }));
  fleet_.ignore_commands(true);
  std::promise<std::string> waited;
  lamp.set_power_async(false, [&](std::exception_ptr e) {
    try {
      if (e) std::rethrow_exception(e);
      waited.set_value("");
    } catch (const std::exception& x) {
      waited.set_value(x.what());
    }
  });
  ASSERT_TRUE(planet_test::wait_until([&] { return fleet_.commands("bedroom_lamp") == 2; }));
  fleet_.set_online("bedroom_lamp", false);
  auto result = waited.get_future();
  ASSERT_EQ(result.wait_for(3s), std::future_status::ready) << "not failed at once";
  error = result.get();
  EXPECT_NE(error.find("went offline"), std::string::npos) << error;

  // Without the broker, nothing can be sent: that fails at once too.
  fleet_.ignore_commands(false);
  fleet_.set_online("bedroom_lamp", true);
  ASSERT_TRUE(planet_test::wait_until([&] { return online("bedroom_lamp_z2m"); }));
  broker_.kill();
  ASSERT_TRUE(planet_test::wait_until([&] { return !client_.connected(); }));
  before = std::chrono::steady_clock::now();
  error = error_of([&] { lamp.set_power(false); });
  EXPECT_LT(std::chrono::steady_clock::now() - before, 2s);
  EXPECT_NE(error.find("not connected"), std::string::npos) << error;
  EXPECT_NE(error.find("Bedroom lamp"), std::string::npos) << error;
}

TEST_F(MqttDevicesTest, ConfigsAndStatesTheBridgeCannotUseAreReportedAndItGoesOn) {
  start();
  fleet_.publish("homeassistant/light/broken/config", "{\"name\": \"broken", true);
  fleet_.publish("homeassistant/vacuum/robo/config",
                 R"({"name":"Robo","command_topic":"robo/set"})", true);
  fleet_.publish("homeassistant/sensor/temp/config",
                 R"({"name":"Temp","state_topic":"temp/state"})", true);
  fleet_.publish("homeassistant/binary_sensor/door/config",
                 R"({"name":"Door","device_class":"door","state_topic":"door/state"})", true);
  fleet_.publish("homeassistant/sensor/mode/config",
                 R"({"name":"Mode","device_class":"enum","state_topic":"mode/state"})", true);
  fleet_.publish("homeassistant/climate/ac/config",
                 R"({"name":"AC","mode_command_topic":"ac/set","modes":["heat","cool"]})", true);
  fleet_.publish(mqtt_test::Fleet::state_topic("kettle"), R"({"state":"MAYBE"})");
  fleet_.publish(mqtt_test::Fleet::state_topic("bed_sensor"), R"({"battery":80})");
  fleet_.publish(mqtt_test::Fleet::state_topic("living_blind"), "ajar");
  fleet_.publish(mqtt_test::Fleet::state_topic("living_thermostat"), R"({"system_mode":"cool"})");
  ASSERT_TRUE(planet_test::wait_until([&] {
    return has_problem("homeassistant/light/broken/config: the config is not JSON") &&
           has_problem("homeassistant/vacuum/robo/config: component 'vacuum' is not supported") &&
           has_problem(
               "homeassistant/sensor/temp/config: a sensor of device_class '' has no "
               "ICARS interface") &&
           has_problem("homeassistant/sensor/mode/config: a sensor of device_class 'enum'") &&
           has_problem(
               "homeassistant/climate/ac/config: a climate whose modes (heat, cool) "
               "lack 'off'") &&
           has_problem(
               "esphome/living_blind/state: state of cover 'Living blind' "
               "(living_blind_z2m) ignored: 'ajar' is none of 'open'") &&
           has_problem(
               "zigbee2mqtt/living_thermostat: state of climate 'Living thermostat' "
               "(living_thermostat_z2m) ignored: mode 'cool' is none of its modes (off, "
               "heat, auto)") &&
           has_problem(
               "homeassistant/binary_sensor/door/config: a binary_sensor of device_class 'door'") &&
           has_problem(
               "zigbee2mqtt/kettle: state of switch 'Kettle' (kettle_z2m) ignored: 'MAYBE' is "
               "neither") &&
           has_problem(
               "zigbee2mqtt/bed_sensor: state of binary_sensor 'Bed occupancy' (bed_sensor_z2m) "
               "ignored: "
               "the state has no 'occupancy'");
  })) << fmt::format("{}", fmt::join(bridge_->problems(), "\n"));
  // A device discovered later, without availability topics, is registered at once.
  fleet_.publish(
      "homeassistant/switch/fan_plug/config",
      R"({"name":"Fan","unique_id":"fan_plug","command_topic":"plugs/fan/set","state_topic":"plugs/fan",)"
      R"("device":{"identifiers":["fan"],"suggested_area":"Living Room"}})",
      true);
  ASSERT_TRUE(planet_test::wait_until([&] { return light("fan_plug") != nullptr; }))
      << describe_services();
  EXPECT_EQ(light("fan_plug")->attributes().room, "living_room");
  const auto count = bridge_->problems().size();
  fleet_.publish(mqtt_test::Fleet::state_topic("kettle"),
                 R"({"state":"MAYBE"})");  // logged once only
  EXPECT_EQ(bridge_->devices().size(), std::size(mqtt_test::kFleetDevices) + 1);

  auto kettle = light("kettle_z2m");
  ASSERT_TRUE(kettle);
  kettle->proxy().set_power(true);
  EXPECT_EQ(fleet_.on("kettle"), true);
  EXPECT_EQ(bridge_->problems().size(), count);
}

}  // namespace
}  // namespace icars::home::mqtt
