// The Service Framework over real PLANET connections: a device manager registers devices, SF
// creates an adaptor service per capability, discovery finds them by type and attributes,
// SpeechSensor composes a microphone with a speech recognizer (what it hears while the recognizer
// is out of reach is recognized when it is back, in order), and services follow their device's
// connection: unavailable when it drops, back (same objects) when it returns.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <future>
#include <mutex>
#include <string>
#include <vector>

#include "child_process.h"
#include "fake_voice.h"
#include "scoped_subscription.h"
#include "icars/device/device_manager.h"
#include "icars/audio/pcm.h"
#include "icars/home/adaptors.h"
#include "icars/home/microphone.h"
#include "icars/home/services.h"
#include "icars/planet/publisher.h"
#include "icars/service/device_registry.h"
#include "icars/service/service_framework.h"

namespace icars::home {
namespace {

using namespace icars::service;
using namespace std::chrono_literals;
namespace p = icars::planet;

class FakeTV final : public home::TVControlServant {
 public:
  void set_power(bool on, const p::Current&) override { state_.on = on; }
  void set_channel(std::int32_t channel, const p::Current&) override {
    if (channel < 1 || channel > 99) throw home::OutOfRange("channel", channel, 1, 99);
    state_.channel = channel;
  }
  void set_volume(std::int32_t volume, const p::Current&) override { state_.volume = volume; }
  home::TVState state(const p::Current&) override { return state_; }

 private:
  home::TVState state_;
};

class FakeLight final : public home::LightServant {
 public:
  void set_power(bool on, const p::Current&) override { state_.on = on; }
  void set_intensity(std::int32_t percent, const p::Current&) override { state_.intensity = percent; }
  home::LightState state(const p::Current&) override { return state_; }

 private:
  home::LightState state_;
};

using home_test::FakeMicrophone;
using home_test::FakeRecognizer;
using home_test::kSentences;

// The devices of one device manager process, on their own communicator.
struct DeviceSide {
  p::Communicator communicator;
  device::DeviceManager manager{communicator};
  std::shared_ptr<FakeMicrophone> mic = std::make_shared<FakeMicrophone>(communicator);

  explicit DeviceSide(std::uint16_t server_port) {
    auto tv = std::make_shared<device::Device>("tv", "TV", "living_room");
    tv->add("tv_control", std::make_shared<FakeTV>());
    auto light = std::make_shared<device::Device>("bedroom_light", "Light", "bedroom");
    light->add("light", std::make_shared<FakeLight>());
    auto robot_mic = std::make_shared<device::Device>("robot1_mic", "Microphone", "", "robot1");
    robot_mic->add("sound_sensor", mic);
    auto speech = std::make_shared<device::Device>("speech_engine", "SpeechEngine");
    speech->add("speech_recognizer", std::make_shared<FakeRecognizer>());
    for (auto& d : {tv, light, robot_mic, speech}) manager.add(d);
    manager.connect("127.0.0.1", server_port);
  }
};

class SF : public ::testing::Test {
 protected:
  void SetUp() override { port_ = server_.listen("127.0.0.1", 0); }

  p::Communicator server_;
  service::ServiceFramework sf_{server_, adaptors(), {}, {composer()}};
  ServiceContainer& container_ = sf_.container();
  DeviceRegistry* registry_ = &sf_.registry();
  std::uint16_t port_ = 0;
};

TEST_F(SF, RegisteredDevicesBecomeServicesDiscoverableByTypeAndAttributes) {
  DeviceSide devices(port_);
  ASSERT_TRUE(devices.manager.wait_registered(1, 20s)) << devices.manager.last_error();

  EXPECT_EQ(container_.find(ServiceQuery::of_type("TVControl")).size(), 1u);
  EXPECT_EQ(container_.find(ServiceQuery::of_type("LightControl").in_room("bedroom")).size(), 1u);
  EXPECT_TRUE(container_.find(ServiceQuery::of_type("LightControl").in_room("living_room")).empty());
  EXPECT_EQ(container_.find(ServiceQuery().in_room("living_room")).size(), 1u);
  auto carried = container_.find(ServiceQuery().carried_by("robot1"));
  ASSERT_EQ(carried.size(), 3u);  // the microphone's SoundSensor, and the SpeechSensor and SoundLocalizer on it
  // 4 adaptors (one per capability) + the SpeechSensor and SoundLocalizer composites.
  EXPECT_EQ(container_.all().size(), 6u);

  auto tv = container_.find_first<TVControlService>(ServiceQuery::of_type("TVControl").available());
  ASSERT_TRUE(tv);
  tv->proxy().set_power(true);
  tv->proxy().set_channel(5);
  EXPECT_EQ(tv->proxy().state().channel, 5);
  EXPECT_THROW(tv->proxy().set_channel(500), home::OutOfRange);
}

TEST_F(SF, SpeechSensorTurnsSoundIntoRecognizedSpeech) {
  DeviceSide devices(port_);
  ASSERT_TRUE(devices.manager.wait_registered(1, 20s)) << devices.manager.last_error();
  auto speech = container_.find_first<SpeechSensor>(ServiceQuery::of_type("SpeechSensor"));
  ASSERT_TRUE(speech);
  EXPECT_TRUE(speech->available());
  std::promise<SpeechEvent> heard;
  const auto subscription = planet_test::subscribe_scoped(*speech, [&](const SpeechEvent& e) {
    if (e.text == "turn on the TV") heard.set_value(e);
  });
  ASSERT_TRUE(planet_test::wait_until([&] { return devices.mic->subscribers() == 1; }));
  devices.mic->hear("turn on the TV");
  auto future = heard.get_future();
  ASSERT_EQ(future.wait_for(20s), std::future_status::ready);
  const SpeechEvent e = future.get();
  EXPECT_EQ(e.device, "robot1_mic");
  EXPECT_DOUBLE_EQ(e.confidence, 0.9);
}

// The speech engine's device manager goes away while the user speaks: the three sentences wait
// for it and are recognized, in the order they were said, when it registers again; what is
// said afterwards follows them.
TEST_F(SF, SpeechHeardWhileTheRecognizerIsAwayIsRecognizedInOrderWhenItIsBack) {
  struct EngineSide {
    p::Communicator communicator;
    device::DeviceManager manager{communicator};
    explicit EngineSide(std::uint16_t port) {
      auto speech = std::make_shared<device::Device>("speech_engine", "SpeechEngine");
      speech->add("speech_recognizer", std::make_shared<FakeRecognizer>());
      manager.add(speech);
      manager.connect("127.0.0.1", port);
    }
  };
  struct MicSide {
    p::Communicator communicator;
    device::DeviceManager manager{communicator};
    std::shared_ptr<FakeMicrophone> mic = std::make_shared<FakeMicrophone>(communicator);
    explicit MicSide(std::uint16_t port) {
      auto robot_mic = std::make_shared<device::Device>("robot1_mic", "Microphone", "", "robot1");
      robot_mic->add("sound_sensor", mic);
      manager.add(robot_mic);
      manager.connect("127.0.0.1", port);
    }
  };
  MicSide microphone(port_);
  auto engine = std::make_unique<EngineSide>(port_);
  ASSERT_TRUE(microphone.manager.wait_registered(1, 20s));
  ASSERT_TRUE(engine->manager.wait_registered(1, 20s));
  std::shared_ptr<SpeechSensor> speech;
  ASSERT_TRUE(planet_test::wait_until([&] {
    speech = container_.find_first<SpeechSensor>(ServiceQuery::of_type("SpeechSensor").available());
    return speech != nullptr;
  }));
  std::mutex mutex;
  std::vector<std::string> heard;
  const auto subscription = planet_test::subscribe_scoped(*speech, [&](const SpeechEvent& e) {
    std::lock_guard lock(mutex);
    heard.push_back(e.text);
  });
  auto so_far = [&] {
    std::lock_guard lock(mutex);
    return heard;
  };
  ASSERT_TRUE(planet_test::wait_until([&] { return microphone.mic->subscribers() == 1; }));
  microphone.mic->hear("turn on the TV");
  ASSERT_TRUE(planet_test::wait_until([&] { return so_far().size() == 1; }));

  engine.reset();  // the recognizer goes away
  ASSERT_TRUE(planet_test::wait_until([&] { return !speech->available(); }));
  for (const char* text : {"channel 5", "volume up", "play music"}) microphone.mic->hear(text);
  auto sound = container_.find_first<SoundSensor>(ServiceQuery::of_type("SoundSensor"));
  ASSERT_TRUE(planet_test::wait_until([&] { return speech->waiting() == 3; }))
      << speech->waiting() << " waiting, " << sound->stats().sounds << " sounds, " << speech->rejected() << " rejected, "
      << sound->stats().frames << " frames";
  EXPECT_EQ(so_far().size(), 1u);

  engine = std::make_unique<EngineSide>(port_);  // and comes back
  ASSERT_TRUE(engine->manager.wait_registered(1, 20s));
  ASSERT_TRUE(planet_test::wait_until([&] { return so_far().size() == 4; }));
  microphone.mic->hear("stop");
  ASSERT_TRUE(planet_test::wait_until([&] { return so_far().size() == 5; }));
  EXPECT_EQ(so_far(), (std::vector<std::string>{"turn on the TV", "channel 5", "volume up", "play music", "stop"}));
  EXPECT_EQ(speech->rejected(), 0u);
  EXPECT_GE(speech->retried(), 3u);
}

// The speech engine stays connected but refuses the first calls (overloaded, as an engine busy
// with other decodes): the sentence is recognized by a later retry although nothing else
// happens (no other sound, no reconnection) that would trigger one.
TEST_F(SF, ASentenceTheConnectedRecognizerRefusesAtFirstIsRecognizedByALaterRetry) {
  class BusyRecognizer final : public home::SpeechRecognizerServant {
   public:
    home::Recognition recognize(const p::Binary& audio, std::int32_t rate, std::int32_t channels,
                                const std::vector<std::string>& phrases, const p::Current& c) override {
      if (calls_++ < 3) throw p::Error(p::ErrorKind::overloaded, "busy with other decodes");
      return inner_.recognize(audio, rate, channels, phrases, c);
    }
    int calls() const { return calls_.load(); }

   private:
    std::atomic<int> calls_{0};
    FakeRecognizer inner_;
  };
  p::Communicator side;
  device::DeviceManager manager(side);
  auto mic = std::make_shared<FakeMicrophone>(side);
  auto robot_mic = std::make_shared<device::Device>("robot1_mic", "Microphone", "", "robot1");
  robot_mic->add("sound_sensor", mic);
  auto busy = std::make_shared<BusyRecognizer>();
  auto engine = std::make_shared<device::Device>("speech_engine", "SpeechEngine");
  engine->add("speech_recognizer", busy);
  manager.add(robot_mic);
  manager.add(engine);
  manager.connect("127.0.0.1", port_);
  ASSERT_TRUE(manager.wait_registered(1, 20s));
  std::shared_ptr<SpeechSensor> speech;
  ASSERT_TRUE(planet_test::wait_until([&] {
    speech = container_.find_first<SpeechSensor>(ServiceQuery::of_type("SpeechSensor").available());
    return speech != nullptr;
  }));
  std::promise<std::string> heard;
  const auto subscription = planet_test::subscribe_scoped(*speech, [&](const SpeechEvent& e) { heard.set_value(e.text); });
  ASSERT_TRUE(planet_test::wait_until([&] { return mic->subscribers() == 1; }));
  mic->hear("channel 5");
  auto future = heard.get_future();
  ASSERT_EQ(future.wait_for(60s), std::future_status::ready)
      << busy->calls() << " calls, " << speech->waiting() << " waiting, " << speech->rejected() << " rejected";
  EXPECT_EQ(future.get(), "channel 5");
  EXPECT_EQ(busy->calls(), 4);
  EXPECT_EQ(speech->rejected(), 0u);
}

TEST_F(SF, ServicesFollowTheirDevicesConnection) {
  auto devices = std::make_unique<DeviceSide>(port_);
  ASSERT_TRUE(devices->manager.wait_registered(1, 20s));
  auto tv = container_.find_first<TVControlService>(ServiceQuery::of_type("TVControl"));
  auto speech = container_.find_first<SpeechSensor>(ServiceQuery::of_type("SpeechSensor"));
  ASSERT_TRUE(tv && speech);
  std::atomic<int> went_down{0};
  std::atomic<int> came_back{0};
  const auto watch = planet_test::watch_scoped(*tv, [&](const bool& up) { ++(up ? came_back : went_down); });
  std::atomic<int> heard{0};
  const auto subscription = planet_test::subscribe_scoped(*speech, [&](const SpeechEvent&) { ++heard; });

  devices.reset();  // the device manager goes away
  ASSERT_TRUE(planet_test::wait_until([&] { return !tv->available() && !speech->available(); }));
  // A service's watchers are told after its availability flips: waited for, not looked for.
  EXPECT_TRUE(planet_test::wait_until([&] { return went_down == 1; }));
  EXPECT_THROW(tv->proxy().set_power(true), p::Error);
  EXPECT_EQ(registry_->connected_devices(), 0u);

  devices = std::make_unique<DeviceSide>(port_);  // and comes back
  ASSERT_TRUE(devices->manager.wait_registered(1, 20s));
  ASSERT_TRUE(planet_test::wait_until([&] { return tv->available() && speech->available(); }));
  EXPECT_TRUE(planet_test::wait_until([&] { return came_back == 1; }));
  EXPECT_EQ(container_.all().size(), 6u) << "the same services were rebound, none added";
  tv->proxy().set_channel(7);
  ASSERT_TRUE(planet_test::wait_until([&] { return devices->mic->subscribers() == 1; }));
  devices->mic->hear("volume up");
  EXPECT_TRUE(planet_test::wait_until([&] { return heard.load() == 1; }));
}

TEST(DeviceManagerTest, RegistersAgainWhenTheServerRestarts) {
  auto server = std::make_unique<p::Communicator>();
  auto sf = std::make_unique<service::ServiceFramework>(*server, adaptors(), service::RegistryOptions{}, std::vector{composer()});
  const auto port = server->listen("127.0.0.1", 0);
  DeviceSide devices(port);
  ASSERT_TRUE(devices.manager.wait_registered(1, 20s)) << devices.manager.last_error();
  EXPECT_EQ(sf->container().all().size(), 6u);

  sf.reset();  // the server goes down...
  server.reset();
  server = std::make_unique<p::Communicator>();  // ...and comes back on the same port, empty
  sf = std::make_unique<service::ServiceFramework>(*server, adaptors(), service::RegistryOptions{}, std::vector{composer()});
  ASSERT_EQ(server->listen("127.0.0.1", port), port);
  ASSERT_TRUE(devices.manager.wait_registered(2, 30s)) << devices.manager.last_error();
  EXPECT_EQ(sf->container().all().size(), 6u);
  auto tv = sf->container().find_first<TVControlService>(ServiceQuery::of_type("TVControl"));
  ASSERT_TRUE(tv);
  tv->proxy().set_channel(9);
  EXPECT_EQ(tv->proxy().state().channel, 9);
  sf.reset();
}

// A device added after the manager connected is registered at once; one set offline leaves the
// registry (its services go), stays out of the registration round after the server restarts,
// and is registered again when set online.
TEST(DeviceManagerTest, RegistersDevicesAddedLaterAndKeepsOfflineOnesOut) {
  auto server = std::make_unique<p::Communicator>();
  auto sf = std::make_unique<service::ServiceFramework>(*server, adaptors(), service::RegistryOptions{}, std::vector{composer()});
  const auto port = server->listen("127.0.0.1", 0);
  DeviceSide devices(port);
  ASSERT_TRUE(devices.manager.wait_registered(1, 20s)) << devices.manager.last_error();
  const auto lights = [&] { return sf->container().find(ServiceQuery::of_type("LightControl").available()).size(); };
  const auto tvs = [&] { return sf->container().find(ServiceQuery::of_type("TVControl").available()).size(); };

  auto desk = std::make_shared<device::Device>("desk_light", "Light", "office");
  desk->add("light", std::make_shared<FakeLight>());
  devices.manager.add(desk);
  ASSERT_TRUE(planet_test::wait_until([&] { return lights() == 2; }));
  auto porch = std::make_shared<device::Device>("porch_light", "Light", "porch");
  porch->add("light", std::make_shared<FakeLight>());
  devices.manager.add(porch, /*online=*/false);
  EXPECT_FALSE(devices.manager.online("porch_light"));

  devices.manager.set_online("tv", false);
  ASSERT_TRUE(planet_test::wait_until([&] { return tvs() == 0; }));
  // An unregistered device's services are unbound (unavailable) first, then removed.
  EXPECT_TRUE(planet_test::wait_until([&] { return sf->container().find(ServiceQuery::of_type("TVControl")).empty(); }))
      << "unregistered, not only unavailable";
  EXPECT_THROW(devices.manager.set_online("no_such_device", true), std::invalid_argument);

  sf.reset();  // the server restarts: the round registers the online devices only
  server.reset();
  server = std::make_unique<p::Communicator>();
  sf = std::make_unique<service::ServiceFramework>(*server, adaptors(), service::RegistryOptions{}, std::vector{composer()});
  ASSERT_EQ(server->listen("127.0.0.1", port), port);
  ASSERT_TRUE(devices.manager.wait_registered(2, 30s)) << devices.manager.last_error();
  EXPECT_EQ(lights(), 2u) << "bedroom_light and desk_light, not porch_light";
  EXPECT_EQ(tvs(), 0u);

  devices.manager.set_online("tv", true);
  devices.manager.set_online("porch_light", true);
  ASSERT_TRUE(planet_test::wait_until([&] { return tvs() == 1 && lights() == 3; }));
  sf.reset();
}

TEST_F(SF, BadRegistrationsAreRefusedWithAReason) {
  p::Communicator client;
  auto peer = client.connect("127.0.0.1", port_);
  ASSERT_TRUE(peer->wait_connected(20s));
  df::DeviceRegistryPrx registry(client, peer, std::string(device::kRegistryPath));
  try {
    registry.register_device(df::DeviceInfo{"lamp", "Light", "hall", "", {}});
    FAIL() << "a device without capabilities was accepted";
  } catch (const df::RegistrationRefused& e) {
    EXPECT_EQ(e.device(), "lamp");
    EXPECT_EQ(e.reason(), "the device declares no capabilities");
  }
  // An unknown interface still becomes a (generic) service, discoverable by its interface id.
  registry.register_device(
      df::DeviceInfo{"fridge", "Fridge", "kitchen", "", {df::CapabilityInfo{"cool", "acme::Fridge", "/f"}}});
  EXPECT_EQ(container_.find(ServiceQuery::of_type("acme::Fridge").in_room("kitchen")).size(), 1u);
  EXPECT_EQ(registry.devices(), std::vector<std::string>{"fridge"});
}

}  // namespace
}  // namespace icars::home
