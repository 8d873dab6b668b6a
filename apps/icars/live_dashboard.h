// `icars run ... --http HOST:PORT` and `icars replay TRACE --http HOST:PORT`: the dashboard of a
// run (icars/dashboard/), with the views of its house, its running policy and its services, and
// the controls through the paths a run already has — the Simulation service for a user's
// sentence, the mediating server for a policy, the lock-step driver for pausing and the speed.
#pragma once

#include <memory>
#include <mutex>
#include <string>

#include "icars/clock/lock_step.h"
#include "icars/dashboard/dashboard.h"
#include "icars/server/mediating_server.h"
#include "icars/sim/house.h"

namespace icars::app {

struct DashboardSettings {
  std::string listen;      // host:port; empty: no dashboard
  std::string token_file;  // the controls' token (its first line); empty: a new one per run
  std::string tls_cert, tls_key;
};

// The lock-step driver as the dashboard's controls see it: set once it runs.
class DriverControl {
 public:
  void attach(LockStepDriver* driver);
  nlohmann::json pause();
  nlohmann::json resume();
  nlohmann::json speed(double speedup);

 private:
  std::mutex mutex_;
  LockStepDriver* driver_ = nullptr;
  bool paused_ = false;
};

// A dashboard on `server`'s trace, started: prints its URL. Throws std::invalid_argument and
// std::runtime_error (bad address, TLS files, token file) with the reason.
std::shared_ptr<dashboard::Dashboard> start_run_dashboard(const DashboardSettings& settings, const sim::House& house,
                                                          server::MediatingServer& server, DriverControl& driver);

// `icars replay TRACE --world HOUSE [--policy FILE] --http HOST:PORT`: serves until SIGINT or
// SIGTERM; returns the exit code (2 for bad input).
int replay(const std::string& trace, const std::string& world, const std::string& policy,
           const DashboardSettings& settings);

}  // namespace icars::app
