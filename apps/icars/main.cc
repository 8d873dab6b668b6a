// icars: the mediating server of a smart home (ICARS paper 3, Fig. 16b).
//
// It serves the Service Framework — the device registry that device managers register with,
// the service container, the adaptive services — over PLANET. By default it also runs the
// simulated house of a house file in the same process (a device manager on its own
// communicator, over loopback), so one command shows the whole system:
//
//   icars                                   # houses/paper_house.xml, 18:00 to 19:35, 600x
//   icars --house my_home.xml --until 23:00 --speedup 120
//   icars --listen 0.0.0.0:7000 --no-simulation   # wait for icars-device-manager processes
//
// At the service level (the behaviors and tasks that act on what it hears come on top of
// this), it finds the user with the robot's camera, then reports what the house's services
// observe: recognized speech, occupancy of the bed and sofa, the robot's trips.
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include <csignal>
#include <cstdio>
#include <future>
#include <iostream>

#include "icars/device/simulated_house.h"
#include "icars/service/service_framework.h"
#include "icars/sim/time.h"

namespace p = icars::planet;
namespace s = icars::service;
using namespace std::chrono_literals;

namespace {

std::string at(std::int64_t time_ms) { return icars::sim::format_time(icars::sim::SimTime(time_ms)); }

std::pair<std::string, std::uint16_t> split_endpoint(const std::string& endpoint) {
  const auto colon = endpoint.rfind(':');
  if (colon == std::string::npos) throw CLI::ValidationError("--listen", "expected host:port");
  return {endpoint.substr(0, colon), static_cast<std::uint16_t>(std::stoi(endpoint.substr(colon + 1)))};
}

// Drives the robot to `room` and waits (simulated time passes) until it arrived.
bool drive_to(s::NavigationService& nav, const std::string& room) {
  auto arrived = std::make_shared<std::promise<bool>>();
  auto future = arrived->get_future();
  auto done = std::make_shared<std::atomic<bool>>(false);
  const auto id = nav.subscribe([arrived, done, room](const home::PositionEvent& e) {
    if (e.arrived && !done->exchange(true)) arrived->set_value(e.room == room);
  });
  bool ok = false;
  try {
    const double length = nav.proxy().go_to_waypoint(room);
    std::printf("[icars] robot1 drives %.1f m to the %s\n", length, room.c_str());
    ok = future.wait_for(120s) == std::future_status::ready && future.get();
  } catch (const std::exception& e) {
    std::printf("[icars] robot1 cannot go to %s: %s\n", room.c_str(), e.what());
  }
  nav.unsubscribe(id);
  return ok;
}

std::vector<s::UserLocation> look(s::UserLocator& locator) {
  std::promise<std::vector<s::UserLocation>> found;
  locator.locate([&](std::exception_ptr e, const std::vector<s::UserLocation>& users) {
    found.set_value(e ? std::vector<s::UserLocation>{} : users);
  });
  return found.get_future().get();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"ICARS mediating server for a smart home"};
  std::string house_file = "houses/paper_house.xml";
  std::string listen = "127.0.0.1:0";
  double speedup = 600;
  std::string until = "19:35";
  bool simulation = true;
  app.add_option("--house", house_file, "house file (docs/house.md)");
  app.add_option("--listen", listen, "where device managers connect, host:port");
  app.add_option("--speedup", speedup, "simulated seconds per second")->check(CLI::PositiveNumber);
  app.add_option("--until", until, "stop at this simulated time of day (HH:MM)");
  app.add_flag("!--no-simulation", simulation, "serve only; device managers run elsewhere");
  CLI11_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::warn);

  const auto [host, port] = split_endpoint(listen);
  p::CommunicatorOptions options;
  options.name = "icars";
  options.logger = spdlog::default_logger();
  p::Communicator server(options);
  s::ServiceFramework sf(server);
  const auto bound = server.listen(host, port);
  std::printf("[icars] mediating server listening on %s:%u\n", host.c_str(), bound);

  if (!simulation) {
    sigset_t signals;
    sigemptyset(&signals);
    sigaddset(&signals, SIGINT);
    sigaddset(&signals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &signals, nullptr);
    sf.container().watch([](const std::shared_ptr<s::Service>& service, const s::ServiceChange& c) {
      static const char* names[] = {"added", "removed", "available", "unavailable"};
      std::printf("[icars] service %s (%s): %s\n", service->id().c_str(), service->type().c_str(),
                  names[static_cast<int>(c)]);
      std::fflush(stdout);
    });
    int sig = 0;
    sigwait(&signals, &sig);
    return 0;
  }

  icars::sim::House house;
  std::optional<icars::sim::SimTime> end_of_day = icars::sim::parse_time_of_day(until);
  if (!end_of_day) {
    std::fprintf(stderr, "icars: --until %s is not a time of day (HH:MM)\n", until.c_str());
    return 2;
  }
  try {
    house = icars::sim::load_house(house_file);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "icars: %s\n", e.what());
    return 2;
  }
  icars::device::SimulatedHouseOptions house_options;
  house_options.speedup = speedup;
  house_options.pun = "house-devices";
  house_options.logger = spdlog::default_logger();
  icars::device::SimulatedHouse home(std::move(house), house_options);
  home.start("127.0.0.1", bound);
  if (!home.manager().wait_registered(1, 30s)) {
    std::fprintf(stderr, "icars: the house's devices did not register: %s\n",
                 home.manager().last_error().c_str());
    return 1;
  }
  auto& c = sf.container();
  std::printf("[icars] %s: %zu devices registered, %zu services:\n", home.world().house().name.c_str(),
              home.manager().devices().size(), c.all().size());
  for (const auto& service : c.all()) {
    const auto& a = service->attributes();
    std::printf("  %-32s %-18s %s\n", service->id().c_str(), service->type().c_str(),
                !a.room.empty() ? ("in the " + a.room).c_str()
                : !a.carrier.empty() ? ("on " + a.carrier).c_str() : "");
  }

  std::atomic<int> heard{0};
  for (auto& speech : c.find(s::ServiceQuery::of_type("SpeechSensor"))) {
    std::static_pointer_cast<s::SpeechSensor>(speech)->subscribe([&](const s::SpeechEvent& e) {
      ++heard;
      std::printf("[%s] heard \"%s\" (%s, %.0f%% sure)\n", at(e.time_ms).c_str(), e.text.c_str(),
                  e.device.c_str(), e.confidence * 100);
      std::fflush(stdout);
    });
  }
  for (auto& sensor : c.find(s::ServiceQuery::of_type("OccupancySensor"))) {
    std::static_pointer_cast<s::OccupancyService>(sensor)->subscribe([](const home::OccupancyEvent& e) {
      std::printf("[%s] the %s is %s\n", at(e.time_ms).c_str(), e.furniture.c_str(),
                  e.occupied ? "occupied" : "free");
      std::fflush(stdout);
    });
  }

  // Find the user: visit the rooms with the robot and look with its camera.
  auto nav = c.find_first<s::NavigationService>(s::ServiceQuery::of_type("Navigation"));
  auto locator = c.find_first<s::UserLocator>(s::ServiceQuery::of_type("UserLocator"));
  if (nav && locator) {
    for (const auto& room : home.world().house().rooms) {
      if (!drive_to(*nav, room.name)) continue;
      auto users = look(*locator);
      if (!users.empty()) {
        std::printf("[%s] found %s in the %s at (%.1f, %.1f)\n",
                    icars::sim::format_time(home.clock().now()).c_str(), users[0].person.c_str(),
                    room.name.c_str(), users[0].x, users[0].y);
        break;
      }
      std::printf("[%s] nobody in the %s\n", icars::sim::format_time(home.clock().now()).c_str(),
                  room.name.c_str());
    }
  }

  // Let the evening run until `until`.
  const auto stop_at = home.world().house().start_time < *end_of_day
                           ? *end_of_day
                           : *end_of_day + icars::sim::kDay;
  while (home.clock().now() < stop_at) std::this_thread::sleep_for(20ms);
  std::printf("[icars] %s: heard %d voice commands; %zu services, %zu available\n",
              icars::sim::format_time(home.clock().now()).c_str(), heard.load(), c.all().size(),
              c.find(s::ServiceQuery().available()).size());
  return 0;
}
