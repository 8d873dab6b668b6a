// The Sense behavior in a running policy, against real PLANET devices: a sensor whose device
// registers again under its id (a new service object on the server) is still sensed, and its
// state is reported once it can be read; sensors registering while the policy starts are all
// sensed, whichever side of the behavior's start they fall on.
#include <gtest/gtest.h>

#include <atomic>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "child_process.h"
#include "icars/device/device_manager.h"
#include "fake_sofa.h"
#include "icars/planet/publisher.h"
#include "policy_server.h"

namespace icars::home {
namespace {

using namespace std::chrono_literals;
namespace p = icars::planet;

// Sitting down on any sofa moves the statechart; a sofa already occupied when it is sensed
// counts (report_current).
constexpr const char* kPolicy = R"xml(<?xml version="1.0" encoding="UTF-8"?>
<policy name="sofas">
  <task name="Watch" events="Sat">
    <interpret name="Situation">
      <rule when="event == 'OccupancyEvent' and occupied" emit="Sat"/>
      <behavior type="Sense" service="OccupancySensor" report_current="true"/>
    </interpret>
  </task>
  <task name="Rest">
    <behavior type="Wait" duration="1h"/>
  </task>
  <statechart initial="Watching">
    <state name="Watching" task="Watch"><transition event="Sat" target="Resting"/></state>
    <state name="Resting" task="Rest"/>
  </statechart>
</policy>
)xml";

using home_test::FakeSofa;

class SenseTest : public ::testing::Test {
 protected:
  bool resting() { return policy_.state() == "Resting"; }
  std::size_t available_sofas() {
    return policy_->container().find(service::ServiceQuery::of_type("OccupancySensor").available()).size();
  }

  home_test::PolicyServer policy_{{{"sofas", kPolicy}}};
};

TEST_F(SenseTest, ASensorWhoseDeviceRegistersAgainIsStillSensed) {
  p::Communicator side;
  device::DeviceManager manager(side);
  auto sofa = std::make_shared<FakeSofa>("sofa_sensor");
  auto device = std::make_shared<device::Device>("sofa_sensor", "SofaOccupancy", "living_room");
  device->add("occupancy", sofa);
  manager.add(device);
  manager.connect("127.0.0.1", policy_.port());
  ASSERT_TRUE(planet_test::wait_until([&] { return available_sofas() == 1 && sofa->subscribers() == 1; }, 30s));
  const auto first = policy_->container().find(service::ServiceQuery::of_type("OccupancySensor")).at(0);
  policy_->run_policy("sofas");
  ASSERT_TRUE(planet_test::wait_until([&] { return policy_.state() == "Watching"; }, 30s));

  // The device leaves the server (its service is removed) and registers again: a new service
  // object under the same id, which the running Sense must take up.
  manager.set_online("sofa_sensor", false);
  ASSERT_TRUE(planet_test::wait_until([&] { return policy_->container().find(service::ServiceQuery::of_type("OccupancySensor")).empty(); }, 30s));
  manager.set_online("sofa_sensor", true);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_sofas() == 1 && sofa->subscribers() >= 1; }, 30s));
  EXPECT_NE(policy_->container().find(service::ServiceQuery::of_type("OccupancySensor")).at(0), first);

  // Someone sits down, and gets up and sits again until the policy hears it (the Sense takes up
  // the new service on the runtime, a moment after it is added).
  ASSERT_TRUE(planet_test::wait_until([&] {
    sofa->set(false);
    sofa->set(true);
    return resting();
  }, 30s)) << "the policy did not hear the sofa after its device registered again";
  policy_->stop();
}

TEST_F(SenseTest, ASofaOccupiedWhenItsDeviceRegistersLateIsReported) {
  policy_->run_policy("sofas");
  ASSERT_TRUE(planet_test::wait_until([&] { return policy_.state() == "Watching"; }, 30s));
  // The sofa is occupied before its device manager comes, and no event says so afterwards.
  p::Communicator side;
  device::DeviceManager manager(side);
  auto sofa = std::make_shared<FakeSofa>("sofa_sensor");
  sofa->set(true);
  auto device = std::make_shared<device::Device>("sofa_sensor", "SofaOccupancy", "living_room");
  device->add("occupancy", sofa);
  manager.add(device);
  manager.connect("127.0.0.1", policy_.port());
  EXPECT_TRUE(planet_test::wait_until([&] { return resting(); }, 30s))
      << "report_current did not report a sensor that registered while the Sense ran";
  policy_->stop();
}

// Sensors register from another process's side while the policy starts, in rounds with the
// registrations at different moments relative to the Sense's start: every sensor is sensed
// (report_current reads each once, whichever side of the start its registration fell on) and
// the one sat on moves the statechart.
TEST_F(SenseTest, EverySensorRegisteringAsThePolicyStartsIsSensed) {
  constexpr int kRounds = 8;
  constexpr int kSofas = 32;
  std::mutex mutex;
  std::set<std::string> read;  // the sofas whose state the Sense read this round
  policy_->trace().add_sink([&](const behavior::TraceRecord& r) {
    if (r.kind != "call" || !r.text.ends_with(".occupancy.occupied")) return;
    std::lock_guard lock(mutex);
    read.insert(r.text.substr(r.text.rfind(' ') + 1));
  });
  for (int round = 0; round < kRounds; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    {
      std::lock_guard lock(mutex);
      read.clear();
    }
    p::Communicator side;
    device::DeviceManager manager(side);
    std::vector<std::shared_ptr<FakeSofa>> sofas;
    for (int i = 0; i < kSofas; ++i) {
      const auto id = "sofa_" + std::to_string(i);
      sofas.push_back(std::make_shared<FakeSofa>(id));
      auto device = std::make_shared<device::Device>(id, "SofaOccupancy", "living_room");
      device->add("occupancy", sofas.back());
      manager.add(device, false);
    }
    manager.connect("127.0.0.1", policy_.port());
    std::thread registering([&] {
      std::this_thread::sleep_for(std::chrono::microseconds(round * 300));  // spreads the rounds only
      for (int i = 0; i < kSofas; ++i) manager.set_online("sofa_" + std::to_string(i), true);
    });
    policy_->run_policy("sofas");
    registering.join();
    ASSERT_TRUE(planet_test::wait_until([&] {
      if (available_sofas() != kSofas) return false;
      for (const auto& s : sofas) {
        if (s->subscribers() == 0) return false;
      }
      return true;
    }, 30s));
    EXPECT_TRUE(planet_test::wait_until([&] {
      std::lock_guard lock(mutex);
      return read.size() == kSofas;
    }, 30s)) << "the Sense read " << read.size() << " of " << kSofas << " sofas";
    // One sofa is sat on, another each round: its events reach the policy.
    auto& sat_on = *sofas[static_cast<std::size_t>((round * 7) % kSofas)];
    ASSERT_TRUE(planet_test::wait_until([&] {
      sat_on.set(false);
      sat_on.set(true);
      return resting();
    }, 30s)) << "the policy did not hear a sofa that registered as it started";
    policy_->stop_policy(5s);
    for (int i = 0; i < kSofas; ++i) manager.set_online("sofa_" + std::to_string(i), false);
    ASSERT_TRUE(planet_test::wait_until([&] { return policy_->container().find(service::ServiceQuery::of_type("OccupancySensor")).empty(); }, 30s));
  }
  policy_->stop();
}

}  // namespace
}  // namespace icars::home
