#include "icars/home/clock_follower.h"

#include "icars/home/adaptors.h"

namespace icars::home {

ClockFollower::ClockFollower(SimClock& clock, service::ServiceContainer& services,
                             std::chrono::milliseconds every)
    : clock_(clock), services_(services), every_(every) {
  thread_ = std::thread([this] { run(); });
}

ClockFollower::~ClockFollower() {
  stop_ = true;
  thread_.join();
}

void ClockFollower::run() {
  while (!stop_) {
    const auto query = service::ServiceQuery::of_type("Simulation").available();
    if (auto simulation = services_.find_first<SimulationService>(query)) {
      try {
        const Time remote(simulation->proxy().now_ms());
        if (remote > clock_.now()) clock_.advance_to(remote);
        following_ = true;
      } catch (const std::exception&) {
        // The device manager is restarting: keep the time we have and ask again.
      }
    }
    std::this_thread::sleep_for(every_);
  }
}

}  // namespace icars::home
