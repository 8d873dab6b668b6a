// The paper's house end to end at the service level: a device manager process runs the
// simulated house and registers its devices with this process (the mediating server) over TCP;
// the server discovers services by type and room, hears a simulated utterance as recognized
// speech through the SpeechSensor composite, drives the robot along a planned path with
// position events on the way, and gets everything back after the device manager is killed
// with SIGKILL and restarted.
#include <gtest/gtest.h>

#include <signal.h>

#include <atomic>
#include <future>
#include <iostream>
#include <map>
#include <mutex>

#include "child_process.h"
#include "scoped_subscription.h"
#include "icars/home/adaptors.h"
#include "icars/home/services.h"
#include "icars/service/service_framework.h"

namespace icars::home {
namespace {

using namespace icars::service;
using namespace std::chrono_literals;
namespace p = icars::planet;

class HouseServices : public ::testing::Test {
 protected:
  void SetUp() override {
    port_ = server_.listen("127.0.0.1", 0);
    start_device_manager();
  }

  void start_device_manager() {
    manager_ = std::make_unique<planet_test::ChildProcess>(std::vector<std::string>{
        ICARS_DEVICE_MANAGER, "--house", ICARS_PAPER_HOUSE, "--server",
        "127.0.0.1:" + std::to_string(port_), "--speedup", "20"});
    for (;;) {
      const auto line = manager_->read_line(60s);
      ASSERT_TRUE(line) << "the device manager did not register its devices";
      if (line->rfind("REGISTERED ", 0) == 0) break;
    }
  }

  std::shared_ptr<SimulationService> simulation() {
    return sf_.container().find_first<SimulationService>(ServiceQuery::of_type("Simulation"));
  }

  p::Communicator server_;
  ServiceFramework sf_{server_, adaptors(), {}, {composer()}};
  std::uint16_t port_ = 0;
  std::unique_ptr<planet_test::ChildProcess> manager_;
};

TEST_F(HouseServices, TheServerDiscoversTheHousesServicesByTypeAndRoom) {
  auto& c = sf_.container();
  const auto lights_bedroom = c.find(ServiceQuery::of_type("LightControl").in_room("bedroom"));
  ASSERT_EQ(lights_bedroom.size(), 1u);
  EXPECT_EQ(lights_bedroom[0]->attributes().device, "bedroom_light");
  const auto lights_living = c.find(ServiceQuery::of_type("LightControl").in_room("living_room"));
  ASSERT_EQ(lights_living.size(), 1u);
  EXPECT_EQ(lights_living[0]->attributes().device, "living_light");
  EXPECT_EQ(c.find(ServiceQuery::of_type("TVControl").in_room("living_room")).size(), 1u);
  EXPECT_EQ(c.find(ServiceQuery::of_type("OccupancySensor").in_room("bedroom")).size(), 1u);
  // The robot's wheels, microphone, speaker and camera, plus the adaptive services on them:
  // SpeechSensor and SoundLocalizer (microphone), CameraFactory and UserLocator (camera).
  EXPECT_EQ(c.find(ServiceQuery().carried_by("robot1")).size(), 8u);

  std::map<std::string, int> by_type;
  for (const auto& s : c.all()) ++by_type[s->type()];
  std::cout << "services of the paper's house (" << c.all().size() << "):";
  for (const auto& s : c.all()) std::cout << ' ' << s->id() << '[' << s->type() << ']';
  std::cout << '\n';

  auto tv = c.find_first<TVControlService>(ServiceQuery::of_type("TVControl").available());
  ASSERT_TRUE(tv);
  tv->proxy().set_power(true);
  tv->proxy().set_channel(5);
  EXPECT_EQ(tv->proxy().state().channel, 5);
  EXPECT_THROW(tv->proxy().set_channel(0), home::OutOfRange);
}

TEST_F(HouseServices, ASimulatedUtteranceBecomesRecognizedSpeech) {
  auto speech = sf_.container().find_first<SpeechSensor>(ServiceQuery::of_type("SpeechSensor"));
  ASSERT_TRUE(speech);
  ASSERT_TRUE(planet_test::wait_until([&] { return speech->available(); }));
  // What a voice-control behavior would listen for.
  speech->want_phrases(this, {"turn on the tv", "turn off the tv", "channel 5", "play music"});
  std::promise<SpeechEvent> heard;
  std::atomic<bool> done{false};
  const auto subscription = planet_test::subscribe_scoped(*speech, [&](const SpeechEvent& e) {
    if (e.text == "turn on the tv" && !done.exchange(true)) heard.set_value(e);
  });
  auto sound = sf_.container().find_first<SoundSensor>(ServiceQuery::of_type("SoundSensor"));
  // Once the sensor listens to the microphone's capture, what the user says is heard.
  ASSERT_TRUE(planet_test::wait_until([&] { return sound->stats().captures > 0; }, 60s));
  simulation()->proxy().say("user1", "turn on the TV");
  auto future = heard.get_future();
  ASSERT_EQ(future.wait_for(20s), std::future_status::ready);
  const SpeechEvent e = future.get();
  EXPECT_EQ(e.device, "robot1_mic");
  EXPECT_GT(e.confidence, 0.5);
  EXPECT_GT(speech->recognized(), 0u);
}

TEST_F(HouseServices, AServiceCallDrivesTheRobotAlongAPlannedPathInSimulatedTime) {
  auto nav = sf_.container().find_first<NavigationService>(ServiceQuery::of_type("Navigation"));
  ASSERT_TRUE(nav);
  std::mutex mutex;
  std::vector<home::PositionEvent> seen;
  const auto subscription = planet_test::subscribe_scoped(*nav, [&](const home::PositionEvent& e) {
    std::lock_guard lock(mutex);
    seen.push_back(e);
  });
  // The adaptor subscribed while the device registered (its CALL preceded the registration's
  // REPLY on the same connection), so every event of the trip arrives.
  const double length = nav->proxy().go_to_waypoint("bedroom");
  EXPECT_GT(length, 2.0);
  ASSERT_TRUE(planet_test::wait_until(
      [&] {
        std::lock_guard lock(mutex);
        return !seen.empty() && seen.back().arrived;
      },
      60s));
  std::lock_guard lock(mutex);
  const auto moving = std::count_if(seen.begin(), seen.end(), [](const auto& e) { return e.moving; });
  EXPECT_GE(moving, 3) << "position events on the way";
  EXPECT_EQ(seen.back().room, "bedroom");
  EXPECT_EQ(nav->proxy().room(), "bedroom");
  // The trip took simulated time: about length / 0.5 m/s.
  const auto sim_ms = seen.back().time_ms - seen.front().time_ms;
  EXPECT_GE(static_cast<double>(sim_ms), length / 0.5 * 1000 * 0.8) << sim_ms;
  std::cout << "robot drove " << length << " m in " << static_cast<double>(sim_ms) / 1000
            << " simulated s with " << seen.size() << " position events\n";
}

TEST_F(HouseServices, TheCameraIsSharedAndTheUserLocatorFindsTheUser) {
  auto& c = sf_.container();
  auto camera = c.find_first<CameraFactory>(ServiceQuery::of_type("CameraFactory"));
  auto locator = c.find_first<UserLocator>(ServiceQuery::of_type("UserLocator"));
  auto nav = c.find_first<NavigationService>(ServiceQuery::of_type("Navigation"));
  ASSERT_TRUE(camera && locator && nav);
  EXPECT_TRUE(locator->available());

  // Three users of the camera at once cost one remote capture.
  std::atomic<int> images{0};
  const auto before = camera->remote_captures();
  for (int i = 0; i < 3; ++i) {
    camera->capture([&](std::exception_ptr e, const home::Image& image) {
      if (!e && image.encoding == "sim/scene") ++images;
    });
  }
  ASSERT_TRUE(planet_test::wait_until([&] { return images.load() == 3; }));
  EXPECT_EQ(camera->remote_captures() - before, 1u);

  // The user starts in the living room; bring the robot there and look.
  nav->proxy().go_to_waypoint("living_room");
  ASSERT_TRUE(planet_test::wait_until([&] { return nav->proxy().room() == "living_room"; }, 60s));
  std::promise<std::vector<UserLocation>> found;
  std::atomic<bool> done{false};
  ASSERT_TRUE(planet_test::wait_until([&] {
    std::promise<std::vector<UserLocation>> attempt;
    locator->locate([&](std::exception_ptr e, const std::vector<UserLocation>& users) {
      attempt.set_value(e ? std::vector<UserLocation>{} : users);
    });
    auto users = attempt.get_future().get();
    if (users.empty() || done.exchange(true)) return false;
    found.set_value(users);
    return true;
  }, 60s));
  const auto users = found.get_future().get();
  ASSERT_EQ(users.size(), 1u);
  EXPECT_EQ(users[0].person, "user1");
  EXPECT_EQ(users[0].camera, "robot1_camera");
}

TEST_F(HouseServices, KilledAndRestartedDeviceManagerBringsItsServicesBack) {
  auto speech = sf_.container().find_first<SpeechSensor>(ServiceQuery::of_type("SpeechSensor"));
  auto tv = sf_.container().find_first<TVControlService>(ServiceQuery::of_type("TVControl"));
  ASSERT_TRUE(speech && tv);
  speech->want_phrases(this, {"channel 5", "volume up", "stop"});
  std::atomic<int> heard{0};
  const auto subscription = planet_test::subscribe_scoped(*speech, [&](const SpeechEvent& e) {
    if (e.text == "channel 5") ++heard;
  });
  const auto services = sf_.container().all().size();
  const auto captures = sf_.container().find_first<SoundSensor>(ServiceQuery::of_type("SoundSensor"))->stats().captures;

  manager_->signal(SIGKILL);
  manager_->wait();
  ASSERT_TRUE(planet_test::wait_until([&] { return !tv->available() && !speech->available(); }, 60s));
  EXPECT_THROW(tv->proxy().state(), p::Error);

  start_device_manager();
  ASSERT_TRUE(planet_test::wait_until([&] { return tv->available() && speech->available(); }, 60s));
  EXPECT_EQ(sf_.container().all().size(), services) << "the same services came back";
  EXPECT_EQ(tv->proxy().state().channel, 1) << "a fresh TV";
  // The sound sensor opened the new microphone's capture: what the user says is heard again.
  auto sound = sf_.container().find_first<SoundSensor>(ServiceQuery::of_type("SoundSensor"));
  ASSERT_TRUE(planet_test::wait_until([&] { return sound->stats().captures >= captures + 1; }, 60s));
  simulation()->proxy().say("user1", "channel 5");
  ASSERT_TRUE(planet_test::wait_until([&] { return heard.load() > 0; }, 60s));
}

}  // namespace
}  // namespace icars::home
