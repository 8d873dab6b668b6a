// Test support: a mediating server with the home's adaptors, composite services and behaviors,
// listening on loopback and running policies the test wrote into a directory of its own, on
// the wall clock.
#pragma once

#include <fstream>
#include <map>
#include <memory>
#include <string>

#include "icars/clock/wall_clock.h"
#include "icars/home/adaptors.h"
#include "icars/home/behaviors.h"
#include "icars/home/services.h"
#include "icars/server/mediating_server.h"
#include "test_directory.h"

namespace home_test {

class PolicyServer {
 public:
  // `policies`: file name without ".xml" -> the policy's XML.
  explicit PolicyServer(const std::map<std::string, std::string>& policies) {
    for (const auto& [name, xml] : policies) std::ofstream(directory_ / (name + ".xml")) << xml;
    icars::server::ServerOptions o;
    o.adaptors = icars::home::adaptors();
    o.composers = {icars::home::composer()};
    o.behaviors = icars::home::behavior_registry();
    o.policy_dir = directory_.path().string();
    server_ = std::make_unique<icars::server::MediatingServer>(std::move(o));
    port_ = server_->listen();
    server_->use_clock(clock_);
  }

  icars::server::MediatingServer& server() { return *server_; }
  icars::server::MediatingServer* operator->() { return server_.get(); }
  std::uint16_t port() const { return port_; }
  // The state the running policy's statechart is in ("" when none runs).
  std::string state() { return server_->coordinator() ? server_->coordinator()->current() : std::string(); }

 private:
  planet_test::TestDirectory directory_{"icars_policy_server"};
  icars::WallClock clock_;
  std::unique_ptr<icars::server::MediatingServer> server_;  // before the clock goes
  std::uint16_t port_ = 0;
};

}  // namespace home_test
