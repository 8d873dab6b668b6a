// A mediating server's robot market (home/robot_market.h): a service of its container for as
// long as this object lives (docs/distribution.md, "Robots").
#pragma once

#include <memory>

#include "icars/home/robot_market.h"
#include "icars/server/mediating_server.h"

namespace icars::app {

class RobotMarketHost {
 public:
  // Starts the market's agent and adds the market to the server's container; throws
  // coros::CorosError when its sockets cannot be bound or it has no key.
  RobotMarketHost(server::MediatingServer& server, home::RobotMarketOptions options);
  ~RobotMarketHost();  // removes it from the container, then stops it
  RobotMarketHost(const RobotMarketHost&) = delete;
  RobotMarketHost& operator=(const RobotMarketHost&) = delete;
  home::RobotMarket& market() { return *market_; }

 private:
  server::MediatingServer& server_;
  std::shared_ptr<home::RobotMarket> market_;
};

}  // namespace icars::app
