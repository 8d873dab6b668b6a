#include "robot_market_host.h"

namespace icars::app {

RobotMarketHost::RobotMarketHost(server::MediatingServer& server, home::RobotMarketOptions options)
    : server_(server), market_(std::make_shared<home::RobotMarket>(server.container(), std::move(options))) {
  server_.container().add(market_);
}

RobotMarketHost::~RobotMarketHost() {
  server_.container().remove(market_->id());
  market_->stop();  // behaviors may hold it a little longer
}

}  // namespace icars::app
