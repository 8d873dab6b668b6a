// icars-device-manager: runs the simulated house of a house file and hosts its devices as a
// device manager (ICARS paper 3.2, 5.1): it serves every device's capabilities over PLANET,
// registers them with the mediating server, and registers them again whenever the link to the
// server comes back.
//
//   icars-device-manager --house houses/paper_house.xml --server 127.0.0.1:7000 [--speedup 60]
//
// Prints "REGISTERED <round> <devices>" after each complete registration round (tests wait on
// it). Stops on SIGINT/SIGTERM.
#include <CLI/CLI.hpp>
#include <csignal>
#include <iostream>
#include <set>
#include <thread>

#include "icars/device/simulated_house.h"

namespace {

std::pair<std::string, std::uint16_t> split_endpoint(const std::string& endpoint) {
  const auto colon = endpoint.rfind(':');
  if (colon == std::string::npos || colon == 0) {
    throw CLI::ValidationError("--server", "expected host:port, got '" + endpoint + "'");
  }
  const int port = std::stoi(endpoint.substr(colon + 1));
  if (port <= 0 || port > 65535) throw CLI::ValidationError("--server", "port out of range");
  return {endpoint.substr(0, colon), static_cast<std::uint16_t>(port)};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"ICARS device manager for a simulated house"};
  std::string house_file;
  std::string server = "127.0.0.1:7000";
  double speedup = 1.0;
  std::vector<std::string> only;
  bool engines = true;
  bool simulator = true;
  std::string pun;
  app.add_option("--house", house_file, "house file (docs/house.md)")->required()->check(CLI::ExistingFile);
  app.add_option("--server", server, "the mediating server, host:port");
  app.add_option("--speedup", speedup, "simulated seconds per wall-clock second")->check(CLI::PositiveNumber);
  app.add_option("--devices", only, "host only these device ids (default: all)")->delimiter(',');
  app.add_flag("!--no-engines", engines, "do not host the speech and vision engines");
  app.add_flag("!--no-simulator", simulator, "do not host the Simulation control device");
  app.add_option("--pun", pun, "this endpoint's PLANET name");
  CLI11_PARSE(app, argc, argv);

  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  icars::sim::House house;
  try {
    house = icars::sim::load_house(house_file);
  } catch (const std::exception& e) {
    std::cerr << "icars-device-manager: " << e.what() << "\n";
    return 2;
  }
  const auto [host, port] = split_endpoint(server);

  icars::device::SimulatedHouseOptions options;
  options.speedup = speedup;
  options.devices = std::set<std::string>(only.begin(), only.end());
  options.engines = engines;
  options.simulator = simulator;
  options.pun = pun;
  std::unique_ptr<icars::device::SimulatedHouse> simulation;
  try {
    simulation = std::make_unique<icars::device::SimulatedHouse>(std::move(house), options);
  } catch (const std::exception& e) {
    std::cerr << "icars-device-manager: " << e.what() << "\n";
    return 2;
  }
  auto& manager = simulation->manager();
  simulation->start(host, port);
  std::cout << "STARTED " << manager.devices().size() << " devices, simulated time "
            << icars::sim::format_time(simulation->clock().now()) << std::endl;

  // Report registration rounds until a stop signal arrives.
  std::atomic<bool> stopping{false};
  std::thread reporter([&] {
    std::uint64_t reported = 0;
    while (!stopping) {
      if (manager.wait_registered(reported + 1, std::chrono::milliseconds(200))) {
        reported = manager.registration_rounds();
        std::cout << "REGISTERED " << reported << ' ' << manager.devices().size() << std::endl;
      }
    }
  });
  int sig = 0;
  sigwait(&signals, &sig);
  stopping = true;
  reporter.join();
  return 0;
}
