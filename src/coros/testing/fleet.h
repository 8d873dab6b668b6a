// Test support for COROS: a fleet of agents in one process on real loopback UDP sockets, on a
// broadcast port of their own, signed with one fresh fleet key, with timings that hold on a
// loaded machine under sanitizers; and a thread-safe log of every agent's events.
#pragma once

#include <spdlog/logger.h>

#include <asio/io_context.hpp>
#include <asio/ip/udp.hpp>
#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "icars/coros/agent.h"
#include "icars/coros/authentication.h"
#include "icars/coros/courier.h"
#include "icars/coros/robot.h"

namespace coros_test {

// Every event of every agent, thread-safe.
class EventLog {
 public:
  icars::coros::Agent::EventSink sink();
  std::vector<nlohmann::json> find(const std::string& kind) const;
  std::size_t count(const std::string& kind) const { return find(kind).size(); }
  std::string dump() const;

 private:
  mutable std::mutex mutex_;
  std::vector<nlohmann::json> events_;
};

// A key holder that misbehaves: a socket of its own on loopback sending datagrams signed with
// the fleet's key, under any sender id, to one agent, and reading what the agent sends back.
class KeyHolder {
 public:
  KeyHolder(const icars::coros::FleetKey& key, asio::ip::udp::endpoint to);
  // `truncate`: the datagram loses its last byte before it is signed (well signed, malformed).
  template <icars::coros::Message M>
  void send(const std::string& sender, const M& message, bool truncate = false) {
    auto d = icars::coros::encode_datagram(sender, message);
    if (truncate) d.pop_back();
    send_signed(std::move(d));
  }
  // Reads what has come back without waiting; true when something did.
  bool receive();
  // Every reply of M's kind so far, in the order the agent sent them.
  template <icars::coros::Message M>
  std::vector<M> replies() const {
    std::vector<M> out;
    for (const auto& d : replies_) {
      if (d.code == M::kCode) out.push_back(d.body_as<M>());
    }
    return out;
  }
  const std::vector<icars::coros::Datagram>& all_replies() const { return replies_; }

 private:
  void send_signed(std::vector<std::byte> datagram);
  asio::io_context io_;
  asio::ip::udp::socket socket_;
  asio::ip::udp::endpoint to_;
  icars::coros::DatagramSigner signer_;
  std::vector<icars::coros::Datagram> replies_;
};

// Inherit it beside ::testing::Test (or hold one): agents it adds are stopped when it goes.
class FleetBase {
 public:
  explicit FleetBase(const std::string& map_file);
  virtual ~FleetBase();
  FleetBase(const FleetBase&) = delete;
  FleetBase& operator=(const FleetBase&) = delete;

  // An agent's configuration on this fleet: its port, key (or insecure_), faults_ with a seed
  // of its own, logger_ when set, fast HELLOs and generous expiry, bid window and retries.
  icars::coros::AgentConfiguration config(const std::string& id, const std::string& role);
  // An agent logging into log_, with the DiscoveryOperator.
  icars::coros::Agent& add_agent(const icars::coros::AgentConfiguration& c);
  // A courier robot at (x, y) of the map, simulated `speedup` times faster than real time.
  icars::coros::Agent& add_robot(const std::string& id, double x, double y, double speedup = 200);
  void start_all();
  void stop_all();
  // Every agent knows every other one.
  bool converged();

 protected:
  std::uint16_t port_;
  icars::coros::FleetKey key_ = icars::coros::FleetKey::generate();
  bool insecure_ = false;
  icars::coros::FaultInjection faults_;
  std::uint64_t seed_ = 1;
  std::shared_ptr<spdlog::logger> logger_;
  std::chrono::milliseconds bid_window_{2000};
  std::string map_file_;
  std::shared_ptr<const icars::coros::MapPlanner> map_;
  EventLog log_;
  std::vector<std::unique_ptr<icars::coros::Agent>> agents_;
  std::map<std::string, std::shared_ptr<icars::coros::SimRobot>> robots_;
};

}  // namespace coros_test
