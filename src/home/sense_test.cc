// The Sense behavior in a running policy, against real PLANET devices: a sensor whose device
// registers again under its id (a new service object on the server) is still sensed, and its
// state is reported once it can be read; sensors registering while the policy starts are all
// sensed, whichever side of the behavior's start they fall on.
#include <gtest/gtest.h>

#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "child_process.h"
#include "icars/clock/wall_clock.h"
#include "icars/device/device_manager.h"
#include "icars/home/adaptors.h"
#include "icars/home/behaviors.h"
#include "icars/home/services.h"
#include "icars/planet/publisher.h"
#include "icars/server/mediating_server.h"

namespace icars::home {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
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

class FakeSofa final : public OccupancySensorServant {
 public:
  explicit FakeSofa(std::string device) : device_(std::move(device)) {}
  bool occupied(const p::Current&) override { return occupied_.load(); }
  std::string furniture(const p::Current&) override { return "sofa"; }
  void subscribe(OccupancyListenerPrx l, const p::Current&) override { events_.subscribe(l); }
  void unsubscribe(OccupancyListenerPrx l, const p::Current&) override { events_.unsubscribe(l); }
  void set(bool occupied) {
    occupied_ = occupied;
    events_.publish(OccupancyEvent{device_, "sofa", occupied, 0});
  }
  std::size_t subscribers() const { return events_.size(); }

 private:
  std::string device_;
  std::atomic<bool> occupied_{false};
  p::Publisher<OccupancyEvent> events_{OccupancyListener::on_occupancy};
};

class SenseTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("icars_sense_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    std::ofstream(dir_ / "sofas.xml") << kPolicy;
    server::ServerOptions o;
    o.adaptors = adaptors();
    o.composers = {composer()};
    o.behaviors = behavior_registry();
    o.policy_dir = dir_.string();
    server_ = std::make_unique<server::MediatingServer>(std::move(o));
    port_ = server_->listen();
    server_->use_clock(clock_);
  }
  void TearDown() override {
    server_.reset();
    fs::remove_all(dir_);
  }
  bool resting() { return server_->coordinator() && server_->coordinator()->current() == "Resting"; }
  std::size_t available_sofas() {
    return server_->container().find(service::ServiceQuery::of_type("OccupancySensor").available()).size();
  }

  fs::path dir_;
  std::unique_ptr<server::MediatingServer> server_;
  std::uint16_t port_ = 0;
  WallClock clock_;
};

TEST_F(SenseTest, ASensorWhoseDeviceRegistersAgainIsStillSensed) {
  p::Communicator side;
  device::DeviceManager manager(side);
  auto sofa = std::make_shared<FakeSofa>("sofa_sensor");
  auto device = std::make_shared<device::Device>("sofa_sensor", "SofaOccupancy", "living_room");
  device->add("occupancy", sofa);
  manager.add(device);
  manager.connect("127.0.0.1", port_);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_sofas() == 1 && sofa->subscribers() == 1; }, 30s));
  const auto first = server_->container().find(service::ServiceQuery::of_type("OccupancySensor")).at(0);
  server_->run_policy("sofas");
  ASSERT_TRUE(planet_test::wait_until([&] { return server_->coordinator() && server_->coordinator()->current() == "Watching"; }, 30s));

  // The device leaves the server (its service is removed) and registers again: a new service
  // object under the same id, which the running Sense must take up.
  manager.set_online("sofa_sensor", false);
  ASSERT_TRUE(planet_test::wait_until([&] { return server_->container().find(service::ServiceQuery::of_type("OccupancySensor")).empty(); }, 30s));
  manager.set_online("sofa_sensor", true);
  ASSERT_TRUE(planet_test::wait_until([&] { return available_sofas() == 1 && sofa->subscribers() >= 1; }, 30s));
  EXPECT_NE(server_->container().find(service::ServiceQuery::of_type("OccupancySensor")).at(0), first);

  // Someone sits down, and gets up and sits again until the policy hears it (the Sense takes up
  // the new service on the runtime, a moment after it is added).
  ASSERT_TRUE(planet_test::wait_until([&] {
    sofa->set(false);
    sofa->set(true);
    return resting();
  }, 30s)) << "the policy did not hear the sofa after its device registered again";
  server_->stop();
}

TEST_F(SenseTest, ASofaOccupiedWhenItsDeviceRegistersLateIsReported) {
  server_->run_policy("sofas");
  ASSERT_TRUE(planet_test::wait_until([&] { return server_->coordinator() && server_->coordinator()->current() == "Watching"; }, 30s));
  // The sofa is occupied before its device manager comes, and no event says so afterwards.
  p::Communicator side;
  device::DeviceManager manager(side);
  auto sofa = std::make_shared<FakeSofa>("sofa_sensor");
  sofa->set(true);
  auto device = std::make_shared<device::Device>("sofa_sensor", "SofaOccupancy", "living_room");
  device->add("occupancy", sofa);
  manager.add(device);
  manager.connect("127.0.0.1", port_);
  EXPECT_TRUE(planet_test::wait_until([&] { return resting(); }, 30s))
      << "report_current did not report a sensor that registered while the Sense ran";
  server_->stop();
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
  server_->trace().add_sink([&](const behavior::TraceRecord& r) {
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
    manager.connect("127.0.0.1", port_);
    std::thread registering([&] {
      std::this_thread::sleep_for(std::chrono::microseconds(round * 300));  // spreads the rounds only
      for (int i = 0; i < kSofas; ++i) manager.set_online("sofa_" + std::to_string(i), true);
    });
    server_->run_policy("sofas");
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
    server_->stop_policy(5s);
    for (int i = 0; i < kSofas; ++i) manager.set_online("sofa_" + std::to_string(i), false);
    ASSERT_TRUE(planet_test::wait_until([&] { return server_->container().find(service::ServiceQuery::of_type("OccupancySensor")).empty(); }, 30s));
  }
  server_->stop();
}

}  // namespace
}  // namespace icars::home
