#include "icars/home/sim/simulated_house.h"

#include <stdexcept>

namespace icars::home {

SimulatedHouse::SimulatedHouse(sim::House house, SimulatedHouseOptions options)
    : options_(std::move(options)), clock_(house.start_time) {
  world_ = std::make_unique<sim::World>(std::move(house), clock_);
  planet::CommunicatorOptions comm;
  comm.name = "devices";
  comm.pun = options_.pun;
  comm.tls = options_.tls;
  comm.token = options_.token;
  comm.logger = options_.logger;
  comm.connection.activity = options_.activity;
  communicator_ = std::make_unique<planet::Communicator>(comm);
  manager_ = std::make_unique<device::DeviceManager>(*communicator_);
  std::vector<const sim::DeviceSpec*> hosted;
  std::vector<const sim::DeviceSpec*> over_mqtt;
  for (const auto& spec : world_->house().devices) {
    if (!options_.devices.empty() && !options_.devices.contains(spec.id)) continue;
    (spec.mqtt.empty() ? hosted : over_mqtt).push_back(&spec);
  }
  if (!options_.state_file.empty()) {
    std::vector<std::string> ids;
    for (const auto* spec : hosted) ids.push_back(spec->id);
    state_ = std::make_unique<SimStateFile>(options_.state_file, *world_, std::move(ids), options_.logger);
  }
  const SimContext context{*world_, *communicator_, options_.effects, state_.get()};
  for (const auto* spec : hosted) {
    try {
      manager_->add(options_.device_types.make(*spec, context));
    } catch (const std::invalid_argument& e) {  // an unknown type, parameters it cannot use
      throw sim::HouseError(world_->house().source, spec->line, e.what());
    }
  }
  if (options_.engines) {
    for (auto& d : make_sim_engines(context, options_.speech_model_dir)) manager_->add(d);
  }
  if (options_.simulator) manager_->add(make_simulator_device(context));
  if (options_.mqtt && !over_mqtt.empty()) {
    for (const auto* spec : over_mqtt) {
      if (!simulated_over_mqtt(spec->type)) {
        throw sim::HouseError(world_->house().source, spec->line,
                              "device \"" + spec->id + "\" of type " + spec->type +
                                  " cannot be an MQTT device of the simulated house; Light, BedOccupancy, "
                                  "SofaOccupancy, Occupancy and MotionSensor can");
      }
    }
    auto mqtt = *options_.mqtt;
    mqtt.activity = options_.activity;
    if (!mqtt.logger) mqtt.logger = options_.logger;
    mqtt_ = std::make_unique<SimulatedMqttDevices>(*world_, std::move(over_mqtt), options_.effects, std::move(mqtt));
  }
  if (options_.fleet) {
    std::vector<std::string> robots;
    for (const auto* spec : hosted) {
      if (spec->type == "Wheels" && !spec->carrier.empty()) robots.push_back(spec->carrier);
    }
    agents_ = std::make_unique<RobotAgents>(*world_, robots, *options_.fleet);
  }
  if (!options_.activity) driver_ = std::make_unique<RealTimeDriver>(clock_, options_.speedup);
}

SimulatedHouse::~SimulatedHouse() {
  agents_.reset();  // they read the world
  if (driver_) driver_->stop();
  mqtt_.reset();
  manager_.reset();
  communicator_.reset();  // no servant runs after this
  state_.reset();         // its last write reads the world
  world_.reset();
}

void SimulatedHouse::start(const std::string& host, std::uint16_t port) {
  if (state_) state_->start();
  if (mqtt_) mqtt_->start();
  if (driver_) driver_->start();
  if (agents_) agents_->start();
  manager_->connect(host, port);
}

void SimulatedHouse::start(std::vector<device::DeviceManager::ServerAddress> servers,
                           std::chrono::milliseconds failover_after) {
  if (state_) state_->start();
  if (mqtt_) mqtt_->start();
  if (driver_) driver_->start();
  if (agents_) agents_->start();
  manager_->connect(std::move(servers), failover_after);
}

}  // namespace icars::home
