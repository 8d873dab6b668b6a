// One service directory over two mediating servers (docs/distribution.md): devices register on
// server A, which shares them; server B mirrors A's directory and its behaviors call the
// devices' services and hear their events as if the devices had registered on B. Real PLANET
// over loopback: A, B and a device manager each with their own communicator.
#include <gtest/gtest.h>

#include <atomic>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "icars/clock/wall_clock.h"
#include "icars/device/device_manager.h"
#include "icars/home/adaptors.h"
#include "icars/home/behaviors.h"
#include "icars/home/services.h"
#include "fake_sofa.h"
#include "fake_voice.h"
#include "icars/planet/publisher.h"
#include "icars/server/mediating_server.h"
#include "icars/service/shared_directory.h"
#include "child_process.h"
#include "scoped_subscription.h"

namespace icars::home {
namespace {

using namespace std::chrono_literals;
namespace p = icars::planet;
namespace s = icars::service;

class FakeLight final : public LightServant {
 public:
  void set_power(bool on, const p::Current&) override { on_ = on; }
  void set_intensity(std::int32_t percent, const p::Current&) override {
    if (percent < 0 || percent > 100) throw OutOfRange("intensity", percent, 0, 100);
    intensity_ = percent;
  }
  LightState state(const p::Current&) override { return {on_.load(), intensity_.load()}; }
  bool on() const { return on_; }

 private:
  std::atomic<bool> on_{false};
  std::atomic<std::int32_t> intensity_{100};
};

using home_test::FakeSofa;

server::ServerOptions home_server() {
  server::ServerOptions o;
  o.adaptors = adaptors();
  o.composers = {composer()};
  o.behaviors = behavior_registry();
  return o;
}

// A device manager with a light and a sofa sensor in the living room.
struct Devices {
  Devices() {
    auto lamp = std::make_shared<device::Device>("lamp", "Lamp", "living_room");
    lamp->add("light", light);
    manager->add(lamp);
    auto sensor = std::make_shared<device::Device>("sofa_sensor", "SofaOccupancy", "living_room");
    sensor->add("occupancy", sofa);
    manager->add(sensor);
  }
  std::shared_ptr<FakeLight> light = std::make_shared<FakeLight>();
  std::shared_ptr<FakeSofa> sofa = std::make_shared<FakeSofa>();
  std::unique_ptr<p::Communicator> side = std::make_unique<p::Communicator>();
  std::unique_ptr<device::DeviceManager> manager = std::make_unique<device::DeviceManager>(*side);
};

class SharedDirectoryTest : public ::testing::Test {
 protected:
  SharedDirectoryTest() {
    auto a_options = home_server();
    a_options.share_devices = true;
    a_ = std::make_unique<server::MediatingServer>(std::move(a_options));
    a_port_ = a_->listen();
    auto b_options = home_server();
    b_options.device_peers = {{"A", "127.0.0.1", a_port_}};
    b_ = std::make_unique<server::MediatingServer>(std::move(b_options));
    b_->listen();
  }

  template <class T>
  std::shared_ptr<T> on_b(const std::string& type) {
    return b_->container().find_first<T>(s::ServiceQuery::of_type(type).available());
  }
  std::size_t available_on_b(const std::string& type) {
    return b_->container().find(s::ServiceQuery::of_type(type).available()).size();
  }

  std::unique_ptr<server::MediatingServer> a_;
  std::uint16_t a_port_ = 0;
  std::unique_ptr<server::MediatingServer> b_;
};

TEST_F(SharedDirectoryTest, ADeviceRegisteredOnOneServerIsCalledAndHeardFromAnother) {
  Devices devices;
  devices.manager->connect("127.0.0.1", a_port_);
  ASSERT_TRUE(b_->wait_device_peers(30s));
  ASSERT_TRUE(planet_test::wait_until(
      [&] { return available_on_b("LightControl") == 1 && available_on_b("OccupancySensor") == 1; }, 30s));
  // B's services are its own adaptors, with the device's attributes.
  auto light = on_b<LightService>("LightControl");
  ASSERT_NE(light, nullptr);
  EXPECT_EQ(light->id(), "lamp.light");
  EXPECT_EQ(light->attributes().room, "living_room");
  EXPECT_EQ(light->attributes().device, "lamp");

  // A command from B reaches the device through A, and counts there as acknowledged: the state
  // an outage of the device would restore.
  light->proxy().set_power(true);
  EXPECT_TRUE(devices.light->on());
  auto light_on_a = a_->container().find_first<LightService>(s::ServiceQuery::of_type("LightControl"));
  ASSERT_TRUE(planet_test::wait_until([&] {
    const auto state = light_on_a->acknowledged_state();
    return state.has("on") && state.get<bool>("on");
  }, 30s));
  // The device's typed exception reaches B as the device threw it.
  try {
    light->proxy().set_intensity(150);
    FAIL() << "OutOfRange expected";
  } catch (const OutOfRange& e) {
    EXPECT_EQ(e.requested(), 150);
  }

  // The sofa's events reach B's subscribers, and A's still reach A's.
  auto sofa = on_b<OccupancyService>("OccupancySensor");
  ASSERT_NE(sofa, nullptr);
  std::atomic<int> heard_on_b{0}, heard_on_a{0};
  // Scoped, like every subscription below: the servers outlive the test body and an event
  // arriving while it ends must not reach its locals.
  const auto on_b_sub =
      planet_test::subscribe_scoped(*sofa, [&](const OccupancyEvent& e) { heard_on_b += e.occupied ? 1 : 0; });
  auto sofa_on_a = a_->container().find_first<OccupancyService>(s::ServiceQuery::of_type("OccupancySensor"));
  ASSERT_NE(sofa_on_a, nullptr);
  const auto on_a_sub =
      planet_test::subscribe_scoped(*sofa_on_a, [&](const OccupancyEvent& e) { heard_on_a += e.occupied ? 1 : 0; });
  ASSERT_TRUE(planet_test::wait_until([&] { return devices.sofa->subscribers() == 2; }, 30s));
  devices.sofa->set(true);
  EXPECT_TRUE(planet_test::wait_until([&] { return heard_on_b == 1 && heard_on_a == 1; }, 30s))
      << "B heard " << heard_on_b << ", A heard " << heard_on_a;
}

TEST_F(SharedDirectoryTest, AMirroredServiceFollowsItsDeviceOutagesAndRegistrations) {
  std::mutex mutex;
  std::vector<std::string> device_events;
  // Scoped: B hears `again` going away while the test body ends, before the fixture stops B.
  const auto watch = planet_test::watch_devices_scoped(b_->container(), [&](const p::Event& e) {
    std::lock_guard lock(mutex);
    device_events.push_back(e.type() + " " + e.get<std::string>("device"));
  });
  // B unbinds a lost device's services before it tells its watchers, and binds a returning
  // one's before: an event is waited for, never looked for at the instant the state flips.
  const auto heard_event = [&](const std::string& event) {
    return planet_test::wait_until([&] {
      std::lock_guard lock(mutex);
      return std::find(device_events.begin(), device_events.end(), event) != device_events.end();
    }, 30s);
  };
  auto devices = std::make_unique<Devices>();
  devices->manager->connect("127.0.0.1", a_port_);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("OccupancySensor") == 1; }, 30s));
  auto sofa = on_b<OccupancyService>("OccupancySensor");

  // The device leaves A: it leaves B too.
  devices->manager->set_online("sofa_sensor", false);
  ASSERT_TRUE(planet_test::wait_until(
      [&] { return b_->container().find(s::ServiceQuery::of_type("OccupancySensor")).empty(); }, 30s));
  devices->manager->set_online("sofa_sensor", true);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("OccupancySensor") == 1; }, 30s));

  // Its device manager dies: B's services stay, unavailable, and B is told; a new manager
  // registers the same devices and B's same service objects work again.
  auto light = on_b<LightService>("LightControl");
  devices.reset();
  ASSERT_TRUE(planet_test::wait_until([&] { return !light->available(); }, 30s));
  EXPECT_TRUE(heard_event("DeviceLost lamp"));
  EXPECT_THROW(light->proxy().set_power(true), p::Error);
  Devices again;
  again.manager->connect("127.0.0.1", a_port_);
  ASSERT_TRUE(planet_test::wait_until([&] { return light->available(); }, 30s));
  light->proxy().set_power(true);
  EXPECT_TRUE(again.light->on());
  // B binds each device as A tells of it: the sofa may come back just after the lamp.
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("OccupancySensor") == 1; }, 30s));
  auto sofa_now = on_b<OccupancyService>("OccupancySensor");
  ASSERT_NE(sofa_now, nullptr);
  std::atomic<int> heard{0};
  const auto subscription = planet_test::subscribe_scoped(*sofa_now, [&](const OccupancyEvent&) { ++heard; });
  ASSERT_TRUE(planet_test::wait_until([&] { return again.sofa->subscribers() == 2; }, 30s));
  again.sofa->set(true);
  EXPECT_TRUE(planet_test::wait_until([&] { return heard == 1; }, 30s));
  EXPECT_TRUE(heard_event("DeviceBack lamp"));
}

// Another client of A (a device manager of its own, or anyone who may call /sf/listeners/*)
// cannot speak for a shared device: events sent to a relay listener count only from the
// device's own link. Malformed or unknown calls to a relay get a clear error and the link
// stays up.
TEST_F(SharedDirectoryTest, RelaysRefuseImpostorsAndMalformedCallsClearly) {
  Devices devices;
  devices.manager->connect("127.0.0.1", a_port_);
  ASSERT_TRUE(planet_test::wait_until([&] { return devices.sofa->subscribers() == 2; }, 30s));
  std::string relay_listener;
  for (const auto& path : devices.sofa->subscriber_paths()) {
    if (path.starts_with(std::string(s::kRelayListenerPrefix))) relay_listener = path;
  }
  ASSERT_FALSE(relay_listener.empty());
  // B's sensor subscribes as it binds, before it counts as available.
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("OccupancySensor") == 1; }, 30s));
  auto sofa = on_b<OccupancyService>("OccupancySensor");
  ASSERT_NE(sofa, nullptr);
  std::atomic<int> heard{0};
  const auto subscription = planet_test::subscribe_scoped(*sofa, [&](const OccupancyEvent&) { ++heard; });

  p::Communicator impostor;
  auto link = impostor.connect("127.0.0.1", a_port_);
  ASSERT_TRUE(link->wait_connected(20s)) << link->last_error();
  // A forged event on the relay listener: refused (a two-way call says why), never forwarded.
  const p::Operation<void(OccupancyEvent)> as_call{"on_occupancy"};
  try {
    p::Proxy(impostor, link, relay_listener).call(as_call, OccupancyEvent{"sofa_sensor", "sofa", true, 0});
    FAIL() << "a forged event was accepted";
  } catch (const p::Error& e) {
    EXPECT_EQ(e.kind(), p::ErrorKind::denied) << e.what();
  }
  p::Proxy(impostor, link, relay_listener).notify(OccupancyListener::on_occupancy,
                                                  OccupancyEvent{"sofa_sensor", "sofa", true, 0});
  // The device's own event arrives; the forged one never did (the link delivers in order).
  devices.sofa->set(true);
  ASSERT_TRUE(planet_test::wait_until([&] { return heard >= 1; }, 30s));
  EXPECT_EQ(heard.load(), 1);

  // A call to a relay with arguments of the wrong type, and an unknown operation.
  const auto relay = std::string(s::kRelayPrefix) + "lamp.light";
  const p::Operation<void(std::string)> wrong{"set_power"};
  try {
    p::Proxy(impostor, link, relay).call(wrong, "yes");
    FAIL();
  } catch (const p::Error& e) {
    EXPECT_EQ(e.kind(), p::ErrorKind::bad_data) << e.what();
    EXPECT_NE(std::string(e.what()).find("argument 1 of 'set_power'"), std::string::npos) << e.what();
  }
  const p::Operation<void()> unknown{"explode"};
  try {
    p::Proxy(impostor, link, relay).call(unknown);
    FAIL();
  } catch (const p::Error& e) {
    EXPECT_EQ(e.kind(), p::ErrorKind::unimplemented) << e.what();
  }
  // A relay whose device's manager is gone says so.
  devices.manager.reset();
  devices.side.reset();
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("LightControl") == 0; }, 30s));
  try {
    p::Proxy(impostor, link, relay).call(Light::set_power, true);
    FAIL();
  } catch (const p::Error& e) {
    EXPECT_EQ(e.kind(), p::ErrorKind::disconnected) << e.what();
    EXPECT_NE(std::string(e.what()).find("device lamp is not connected"), std::string::npos) << e.what();
  }
  EXPECT_EQ(link->connect_count(), 1u);
}

// A device manager given two servers moves to the second when the first dies; there its
// devices take the place of the mirrored ones, and a third server that mirrors both follows
// them to the server they are on now.
TEST_F(SharedDirectoryTest, ADeviceManagerMovesToAnotherServerAndEveryServerFollows) {
  b_->services().share();  // B shares what registers on it, as every icars serve does
  auto c_options = home_server();
  c_options.device_peers = {{"A", "127.0.0.1", a_port_}, {"B", "127.0.0.1", b_->endpoint().port}};
  server::MediatingServer c(std::move(c_options));
  c.listen();
  auto b_options_port = b_->endpoint().port;
  Devices devices;
  devices.manager->connect({{"127.0.0.1", a_port_}, {"127.0.0.1", b_options_port}}, 500ms);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("LightControl") == 1; }, 30s));
  const auto available_on_c = [&] {
    return c.container().find(s::ServiceQuery::of_type("LightControl").available()).size();
  };
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_c() == 1; }, 30s));
  EXPECT_EQ(devices.manager->current_server(), "127.0.0.1:" + std::to_string(a_port_));

  a_.reset();  // A dies with its links
  ASSERT_TRUE(planet_test::wait_until([&] {
    return devices.manager->failovers() == 1 && b_->services().registry().view("lamp").has_value() &&
           available_on_b("LightControl") == 1;
  }, 30s)) << devices.manager->last_error();
  EXPECT_EQ(devices.manager->current_server(), "127.0.0.1:" + std::to_string(b_options_port));
  on_b<LightService>("LightControl")->proxy().set_power(true);
  EXPECT_TRUE(devices.light->on());
  // C held the lamp through A (gone); now through B.
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_c() == 1; }, 30s));
  c.container().find_first<LightService>(s::ServiceQuery::of_type("LightControl").available())->proxy().set_power(false);
  EXPECT_FALSE(devices.light->on());
  // The sofa's events reach C through B.
  auto sofa = c.container().find_first<OccupancyService>(s::ServiceQuery::of_type("OccupancySensor").available());
  ASSERT_NE(sofa, nullptr);
  std::atomic<int> heard{0};
  const auto subscription = planet_test::subscribe_scoped(*sofa, [&](const OccupancyEvent&) { ++heard; });
  ASSERT_TRUE(planet_test::wait_until([&] { return devices.sofa->subscribers() == 2; }, 30s))
      << devices.sofa->subscribers();
  devices.sofa->set(true);
  EXPECT_TRUE(planet_test::wait_until([&] { return heard == 1; }, 30s));
}

// The voice path over two servers: the microphone and the speech recognizer register on A;
// B's SpeechSensor (B's own composite of the mirrored services) captures the microphone through
// A's relay, a stream of A fed from the device's, and has B's recognizer call, relayed, decode it.
TEST_F(SharedDirectoryTest, SpeechOnAMicrophoneOfAnotherServerIsRecognizedThroughItsRelay) {
  p::Communicator side;
  device::DeviceManager manager(side);
  auto mic = std::make_shared<home_test::FakeMicrophone>(side);
  auto robot_mic = std::make_shared<device::Device>("robot1_mic", "Microphone", "", "robot1");
  robot_mic->add("sound_sensor", mic);
  auto engine = std::make_shared<device::Device>("speech_engine", "SpeechEngine");
  engine->add("speech_recognizer", std::make_shared<home_test::FakeRecognizer>());
  manager.add(robot_mic);
  manager.add(engine);
  manager.connect("127.0.0.1", a_port_);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("SpeechSensor") == 1; }, 30s));
  auto speech = on_b<SpeechSensor>("SpeechSensor");
  std::mutex mutex;
  std::vector<std::string> heard;
  const auto subscription = planet_test::subscribe_scoped(*speech, [&](const SpeechEvent& e) {
    std::lock_guard lock(mutex);
    heard.push_back(e.text);
  });
  // Two captures: A's own SoundSensor's and the relay's for B.
  ASSERT_TRUE(planet_test::wait_until([&] { return mic->subscribers() == 2; }, 30s)) << mic->subscribers();
  mic->hear("turn on the TV");
  mic->hear("volume up");
  ASSERT_TRUE(planet_test::wait_until([&] {
    std::lock_guard lock(mutex);
    return heard.size() == 2;
  }, 30s));
  std::lock_guard lock(mutex);
  EXPECT_EQ(heard, (std::vector<std::string>{"turn on the TV", "volume up"}));
}

// The link between the servers drops and comes back: B's services are unavailable meanwhile,
// then B reads A's directory again and what changed meanwhile (a device that left) applies.
TEST_F(SharedDirectoryTest, AfterTheLinkToTheSharingServerComesBackTheDirectoryIsReadAgain) {
  Devices devices;
  devices.manager->connect("127.0.0.1", a_port_);
  ASSERT_TRUE(planet_test::wait_until(
      [&] { return available_on_b("LightControl") == 1 && available_on_b("OccupancySensor") == 1; }, 30s));
  auto light = on_b<LightService>("LightControl");
  // The sofa's device leaves A while B's link to A is cut.
  const auto close_b_to_a = [&] {
    for (const auto& c : b_->communicator().connections().connections()) {
      if (c->role() == p::ConnectionRole::client) c->close("cut by the test");
    }
  };
  close_b_to_a();
  devices.manager->set_online("sofa_sensor", false);
  ASSERT_TRUE(planet_test::wait_until([&] { return light->available(); }, 30s))
      << "B did not read A's directory again after its link came back";
  ASSERT_TRUE(planet_test::wait_until(
      [&] { return b_->container().find(s::ServiceQuery::of_type("OccupancySensor")).empty(); }, 30s));
  light->proxy().set_power(true);
  EXPECT_TRUE(devices.light->on());
}

TEST_F(SharedDirectoryTest, WhenTheMirroringServerGoesItsSubscriptionsGoFromTheDevices) {
  Devices devices;
  devices.manager->connect("127.0.0.1", a_port_);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("OccupancySensor") == 1; }, 30s));
  ASSERT_TRUE(planet_test::wait_until([&] { return devices.sofa->subscribers() == 2; }, 30s));
  b_.reset();
  // A's own subscription stays; the relay's is withdrawn from the device.
  EXPECT_TRUE(planet_test::wait_until([&] { return devices.sofa->subscribers() == 1; }, 30s))
      << devices.sofa->subscribers() << " subscribers";
  auto light_on_a = a_->container().find_first<LightService>(s::ServiceQuery::of_type("LightControl").available());
  ASSERT_NE(light_on_a, nullptr);
  light_on_a->proxy().set_power(true);
  EXPECT_TRUE(devices.light->on());
}

TEST_F(SharedDirectoryTest, AServerWithALocalDeviceOfTheSameIdKeepsItsOwn) {
  Devices local;
  local.manager->connect("127.0.0.1", b_->endpoint().port);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("LightControl") == 1; }, 30s));
  ASSERT_TRUE(b_->wait_device_peers(30s));
  Devices on_a;
  on_a.manager->connect("127.0.0.1", a_port_);
  ASSERT_TRUE(planet_test::wait_until([&] { return on_a.sofa->subscribers() == 1; }, 30s));
  // A's lamp is not mirrored over B's own: a call on B reaches B's lamp.
  on_b<LightService>("LightControl")->proxy().set_power(true);
  EXPECT_TRUE(local.light->on());
  EXPECT_FALSE(on_a.light->on());
  EXPECT_EQ(b_->container().find(s::ServiceQuery::of_type("LightControl")).size(), 1u);
}

TEST_F(SharedDirectoryTest, ADeviceRegisteringHereTakesThePlaceOfAMirroredOneOfTheSameId) {
  Devices on_a;
  on_a.manager->connect("127.0.0.1", a_port_);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_on_b("LightControl") == 1; }, 30s));
  Devices local;
  local.manager->connect("127.0.0.1", b_->endpoint().port);
  ASSERT_TRUE(local.manager->wait_registered(1, 30s)) << local.manager->last_error();
  ASSERT_TRUE(b_->services().registry().view("lamp").has_value());
  on_b<LightService>("LightControl")->proxy().set_power(true);
  EXPECT_TRUE(local.light->on());
  EXPECT_FALSE(on_a.light->on());
  EXPECT_EQ(b_->container().find(s::ServiceQuery::of_type("LightControl")).size(), 1u);
}

}  // namespace
}  // namespace icars::home
