// A simulated house as a device manager: the world of a house file running on its clock at a
// chosen speed-up, every device of the house (plus the speech and vision engines and the
// Simulation control device) served on its own PLANET communicator and registered with the
// mediating server. Used by icars-device-manager and by `icars` in its one-process mode.
// With a state file (SimulatedHouseOptions::state_file) the actuators and robots come back
// from it and keep it up to date (sim_state_file.h, docs/house.md "State file").
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <set>
#include <string>

#include "icars/clock/activity.h"
#include "icars/clock/sim_clock.h"
#include "icars/device/device_manager.h"
#include "icars/coros/knowledge.h"
#include "icars/home/sim/robot_agents.h"
#include "icars/home/sim/sim_devices.h"
#include "icars/home/sim/sim_mqtt_devices.h"
#include "icars/home/sim/sim_state_file.h"
#include "icars/sim/house.h"
#include "icars/sim/world.h"

namespace spdlog {
class logger;
}

namespace icars::home {

struct SimulatedHouseOptions {
  double speedup = 1.0;           // simulated seconds per wall-clock second
  std::set<std::string> devices;  // host only these device ids; empty: all
  bool engines = true;            // host the speech and vision engines
  // The speech engine's model (RecognizerOptions::model_dir): by default the one adapted to the
  // simulated voices if it was built; "": the stock one.
  std::string speech_model_dir = sim_speech_model_dir();
  bool simulator = true;          // host the Simulation control device
  std::string pun;                // the device manager's PLANET name
  planet::TlsOptions tls;         // TLS to the server (docs/security.md)
  std::string token;              // authenticates the device manager to the server
  std::shared_ptr<spdlog::logger> logger;  // the device communicator's; default: stderr, info
  EffectObserver effects;  // hears what the simulated actuators do (SimContext::effects)
  std::filesystem::path state_file;  // keep the devices' state here; empty: none
  SimDeviceTypes device_types = sim_device_types();  // the types its devices may have
  // Lock-step (icars/clock/lock_step.h): the devices' messages count as work of this activity,
  // and the house does not drive its clock (a LockStepDriver does, from start()). Null: the
  // clock runs at `speedup` with the wall clock.
  std::shared_ptr<Activity> activity;
  // The house's MQTT devices (those with an `mqtt` unique_id, docs/house.md) are never served
  // over PLANET: with this set they are simulated on this broker as zigbee2mqtt would serve
  // them (SimulatedMqttDevices; `activity` is taken from above), for an MQTT bridge to bring
  // in; without it they are left to a real home's devices.
  std::optional<SimulatedMqttOptions> mqtt;
  // Set: every robot whose Wheels this house hosts is also a COROS agent of this fleet (port,
  // key, timings; id and role are the robot's) bidding for a RobotMarket's errands
  // (robot_agents.h, docs/distribution.md "Robots").
  std::optional<coros::AgentConfiguration> fleet;
};

class SimulatedHouse {
 public:
  // Throws std::invalid_argument for a device the simulation cannot implement.
  SimulatedHouse(sim::House house, SimulatedHouseOptions options);
  ~SimulatedHouse();  // stops the clock first, so no world event runs during teardown

  // Restores the robots from the state file and writes it (throwing std::runtime_error
  // naming the file when it cannot), publishes the MQTT devices (bridge::mqtt::Error when the
  // broker cannot be reached), then starts the clock (unless in lock-step) and connects
  // to the server (registering every device, again after every reconnection). Set the clock first (--epoch):
  // a robot's kept motion goes on from the clock's time here.
  void start(const std::string& host, std::uint16_t port);
  // The same with several servers of one logical mediating server: the devices move to the next
  // when the current one has been unreachable for `failover_after` (DeviceManager::connect).
  void start(std::vector<device::DeviceManager::ServerAddress> servers, std::chrono::milliseconds failover_after);

  sim::World& world() { return *world_; }
  SimClock& clock() { return clock_; }
  device::DeviceManager& manager() { return *manager_; }
  SimStateFile* state_file() { return state_.get(); }  // null without one
  planet::Communicator& communicator() { return *communicator_; }
  SimulatedMqttDevices* mqtt() { return mqtt_.get(); }  // null without SimulatedHouseOptions::mqtt
  RobotAgents* robot_agents() { return agents_.get(); }  // null without SimulatedHouseOptions::fleet

 private:
  SimulatedHouseOptions options_;
  SimClock clock_;
  std::unique_ptr<sim::World> world_;
  std::unique_ptr<SimStateFile> state_;  // outlives the devices, not the world
  std::unique_ptr<planet::Communicator> communicator_;
  std::unique_ptr<device::DeviceManager> manager_;
  std::unique_ptr<SimulatedMqttDevices> mqtt_;
  std::unique_ptr<RobotAgents> agents_;
  std::unique_ptr<RealTimeDriver> driver_;  // null in lock-step
};

}  // namespace icars::home
