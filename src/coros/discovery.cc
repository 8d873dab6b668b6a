#include "icars/coros/discovery.h"

namespace icars::coros {

void DiscoveryOperator::init(Agent& agent) {
  SimpleOperator::init(agent);
  agent.processor().on<HelloMessage>([this](const HelloMessage& hello, const Envelope& e) {
    if (hello.id != e.sender) {
      throw CorosError("HELLO for '" + hello.id + "' sent by '" + e.sender + "'");
    }
    AgentState state = AgentState::from_hello(hello, Clock::now());
    // Replies go where the HELLO came from, whatever address it claims.
    state.ip = e.from.address().to_string();
    state.port = e.from.port();
    this->agent().neighbors().update(state);
  });
  agent.neighbors().on_change([this](const AgentState& s, bool joined) {
    this->agent().emit({{"event", joined ? "neighbor_joined" : "neighbor_left"},
                        {"neighbor", s.id},
                        {"role", s.role},
                        {"size", this->agent().neighbors().size()}});
  });
  announce();
  hello_timer_ = agent.every(agent.config().hello_period, [this] { announce(); });
  const auto check = std::max(std::chrono::milliseconds(10), agent.config().neighbor_expiry / 4);
  expiry_timer_ = agent.every(check, [this] { this->agent().neighbors().expire(Clock::now()); });
}

void DiscoveryOperator::shutdown() {
  if (hello_timer_) hello_timer_->cancel();
  if (expiry_timer_) expiry_timer_->cancel();
}

void DiscoveryOperator::announce() {
  Agent& a = agent();
  const auto self = a.transport().local_endpoint();
  HelloMessage hello;
  hello.id = a.id();
  hello.ip = self.address().to_string();
  hello.port = self.port();
  hello.role = a.config().role;
  hello.status = a.status();
  hello.timestamp = Agent::wall_seconds();
  std::tie(hello.x, hello.y) = a.position();
  hello.load = a.load();
  a.broadcast(hello);
}

}  // namespace icars::coros
