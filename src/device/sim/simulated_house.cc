#include "icars/device/simulated_house.h"

namespace icars::device {

SimulatedHouse::SimulatedHouse(sim::House house, SimulatedHouseOptions options)
    : options_(std::move(options)), clock_(house.start_time) {
  world_ = std::make_unique<sim::World>(std::move(house), clock_);
  planet::CommunicatorOptions comm;
  comm.name = "devices";
  comm.pun = options_.pun;
  comm.tls = options_.tls;
  comm.token = options_.token;
  comm.logger = options_.logger;
  communicator_ = std::make_unique<planet::Communicator>(comm);
  manager_ = std::make_unique<DeviceManager>(*communicator_);
  const SimContext context{*world_, *communicator_, options_.effects};
  for (const auto& spec : world_->house().devices) {
    if (options_.devices.empty() || options_.devices.contains(spec.id)) {
      manager_->add(make_sim_device(spec, context));
    }
  }
  if (options_.engines) {
    for (auto& d : make_sim_engines(context)) manager_->add(d);
  }
  if (options_.simulator) manager_->add(make_simulator_device(context));
  driver_ = std::make_unique<sim::RealTimeDriver>(clock_, options_.speedup);
}

SimulatedHouse::~SimulatedHouse() {
  driver_->stop();
  manager_.reset();
  communicator_.reset();  // no servant runs after this
  world_.reset();
}

void SimulatedHouse::start(const std::string& host, std::uint16_t port) {
  driver_->start();
  manager_->connect(host, port);
}

}  // namespace icars::device
