#include "fleet.h"

#include "icars/coros/discovery.h"
#include "icars/coros/transport.h"

namespace coros_test {

using namespace std::chrono_literals;
namespace c = icars::coros;

c::Agent::EventSink EventLog::sink() {
  return [this](const nlohmann::json& e) {
    std::lock_guard lock(mutex_);
    events_.push_back(e);
  };
}

std::vector<nlohmann::json> EventLog::find(const std::string& kind) const {
  std::lock_guard lock(mutex_);
  std::vector<nlohmann::json> out;
  for (const auto& e : events_) {
    if (e.value("event", "") == kind) out.push_back(e);
  }
  return out;
}

std::string EventLog::dump() const {
  std::lock_guard lock(mutex_);
  std::string out;
  for (const auto& e : events_) out += e.dump() + "\n";
  return out;
}

KeyHolder::KeyHolder(const c::FleetKey& key, asio::ip::udp::endpoint to)
    : socket_(io_, asio::ip::udp::endpoint(asio::ip::make_address("127.0.0.1"), 0)),
      to_(std::move(to)),
      signer_(key) {
  socket_.non_blocking(true);
}

void KeyHolder::send_signed(std::vector<std::byte> datagram) {
  signer_.sign(datagram);
  socket_.send_to(asio::buffer(datagram), to_);
}

bool KeyHolder::receive() {
  std::vector<std::byte> buffer(c::kMaxDatagram);
  const auto before = replies_.size();
  for (;;) {
    asio::ip::udp::endpoint from;
    std::error_code ec;
    const auto n = socket_.receive_from(asio::buffer(buffer), from, 0, ec);
    if (ec) break;
    replies_.push_back(c::decode_datagram(std::span(buffer.data(), n)));
  }
  return replies_.size() > before;
}

FleetBase::FleetBase(const std::string& map_file)
    : port_(c::free_udp_port()), map_file_(map_file), map_(c::MapPlanner::load(map_file, 0.25)) {}

FleetBase::~FleetBase() { stop_all(); }

c::AgentConfiguration FleetBase::config(const std::string& id, const std::string& role) {
  c::AgentConfiguration config;
  config.id = id;
  config.role = role;
  config.transport.broadcast_port = port_;
  config.transport.faults = faults_;
  config.transport.faults.seed = seed_++;
  if (insecure_) {
    config.transport.insecure = true;
  } else {
    config.transport.key = key_;
  }
  if (logger_) config.transport.logger = logger_;
  config.hello_period = 50ms;
  // Generous bounds for sanitizer builds on a loaded machine: auctions close as soon as every
  // known robot has bid, so a long window costs nothing unless a bid is lost.
  config.neighbor_expiry = 1500ms;
  config.bid_window = bid_window_;
  config.retry_period = 40ms;
  config.max_retries = 50;
  config.map = map_file_;
  return config;
}

c::Agent& FleetBase::add_agent(const c::AgentConfiguration& config) {
  agents_.push_back(std::make_unique<c::Agent>(config));
  agents_.back()->set_event_sink(log_.sink());
  agents_.back()->add_operator(std::make_shared<c::DiscoveryOperator>());
  return *agents_.back();
}

c::Agent& FleetBase::add_robot(const std::string& id, double x, double y, double speedup) {
  c::Agent& agent = add_agent(config(id, "robot"));
  c::SimRobotOptions options;
  options.id = id;
  options.start = {x, y, 0};
  options.speedup = speedup;
  auto robot = std::make_shared<c::SimRobot>(map_->house(), options);
  robots_[id] = robot;
  agent.add_operator(std::make_shared<c::CourierRobotOperator>(robot, map_));
  return agent;
}

void FleetBase::start_all() {
  for (auto& a : agents_) a->start();
}

void FleetBase::stop_all() {
  for (auto& a : agents_) a->stop();
}

bool FleetBase::converged() {
  for (auto& a : agents_) {
    if (a->call([&] { return a->neighbors().size(); }) != agents_.size() - 1) return false;
  }
  return true;
}

}  // namespace coros_test
