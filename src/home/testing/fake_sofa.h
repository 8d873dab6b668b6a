// Test support: a sofa's occupancy sensor served over PLANET, set by the test, publishing an
// OccupancyEvent to its subscribers on every change.
#pragma once

#include <atomic>
#include <string>
#include <vector>

#include "home.planet.h"
#include "icars/planet/publisher.h"

namespace home_test {

class FakeSofa final : public icars::home::OccupancySensorServant {
 public:
  explicit FakeSofa(std::string device = "sofa_sensor") : device_(std::move(device)) {}
  bool occupied(const icars::planet::Current&) override { return occupied_.load(); }
  std::string furniture(const icars::planet::Current&) override { return "sofa"; }
  void subscribe(icars::home::OccupancyListenerPrx l, const icars::planet::Current&) override { events_.subscribe(l); }
  void unsubscribe(icars::home::OccupancyListenerPrx l, const icars::planet::Current&) override {
    events_.unsubscribe(l);
  }
  void set(bool occupied) {
    occupied_ = occupied;
    events_.publish(icars::home::OccupancyEvent{device_, "sofa", occupied, 0});
  }
  std::size_t subscribers() const { return events_.size(); }
  // Where its subscribers' listeners are (servant paths on their servers).
  std::vector<std::string> subscriber_paths() const {
    std::vector<std::string> out;
    for (const auto& s : events_.subscribers()) out.push_back(s.path);
    return out;
  }

 private:
  std::string device_;
  std::atomic<bool> occupied_{false};
  icars::planet::Publisher<icars::home::OccupancyEvent> events_{icars::home::OccupancyListener::on_occupancy};
};

}  // namespace home_test
