// A device manager: hosts devices, serves their capabilities over PLANET and registers them
// with the mediating server's device registry (ICARS paper 3.2, Fig. 16b).
//
// It registers every device as soon as its link to the server is up, and again after each
// reconnection, so a restarted server (or a restarted manager) gets the devices back without
// anyone restarting anything. Devices never talk to each other: the server calls them.
#pragma once

#include <asio/steady_timer.hpp>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "icars/device/device.h"
#include "icars/planet/communicator.h"

namespace icars::device {

inline constexpr std::string_view kRegistryPath = "/sf/registry";  // where the server serves it

class DeviceManager {
 public:
  explicit DeviceManager(planet::Communicator& communicator);
  ~DeviceManager();
  DeviceManager(const DeviceManager&) = delete;
  DeviceManager& operator=(const DeviceManager&) = delete;

  // Serves the device's capabilities. Before connect() the device is registered with the
  // others on the first connection; added later (from any thread), it is registered at once
  // when the link is up. An offline device (`online` false) is served but not registered until
  // set_online(id, true). Throws std::invalid_argument on a duplicate device id.
  void add(std::shared_ptr<Device> device, bool online = true);
  std::vector<std::shared_ptr<Device>> devices() const;

  // Takes a device out of the server's registry while it cannot serve (a real device that went
  // offline) and puts it back: offline, it is unregistered now (its services leave the server)
  // and left out of the registration rounds of later reconnections (which unregister it, in
  // case it went offline while the link was down); online again, it is registered now. From any
  // thread; the calls take effect in order. Throws std::invalid_argument for an id this manager
  // does not host.
  void set_online(const std::string& device_id, bool online);
  bool online(const std::string& device_id) const;

  // Connects to the server and keeps the link up; every (re)connection registers all devices.
  void connect(const std::string& host, std::uint16_t port, planet::ReconnectPolicy policy = {});
  // Several servers of one logical mediating server (docs/distribution.md): connects to the
  // first and, whenever the link to the current one has been down (or never came up) for
  // `failover_after`, moves to the next (round robin), where every device registers again.
  struct ServerAddress {
    std::string host;
    std::uint16_t port = 0;
  };
  void connect(std::vector<ServerAddress> servers, std::chrono::milliseconds failover_after,
               planet::ReconnectPolicy policy = {});
  // The link to the current server (another one after a move to another server). Thread-safe.
  std::shared_ptr<planet::Peer> peer() const;
  // The server the manager uses now, "host:port" ("" before connect()). Thread-safe.
  std::string current_server() const;
  // Times it moved to another server.
  std::uint64_t failovers() const;

  // Rounds in which every device was registered (1 after the first connection, +1 per
  // reconnection); failures are logged and retried on the next reconnection.
  std::uint64_t registration_rounds() const;
  // Blocks (not on the io thread) until `rounds` registration rounds completed.
  bool wait_registered(std::uint64_t rounds, std::chrono::milliseconds timeout) const;
  std::string last_error() const;

 private:
  void register_all(std::shared_ptr<planet::Connection> connection);
  // On the io thread: registers (or unregisters) one device over the current link, if it is up.
  void update_one(const std::shared_ptr<Device>& device, bool online);
  void send_one(const std::shared_ptr<planet::Connection>& connection,
                const std::shared_ptr<Device>& device, bool online);
  // On the io thread: the failover timer while the current link is down.
  void arm_failover();
  void fail_over();

  planet::Communicator& communicator_;
  mutable std::mutex devices_mutex_;
  std::vector<std::shared_ptr<Device>> devices_;
  std::set<std::string> offline_;        // ids of devices not to register now
  std::shared_ptr<planet::Peer> peer_;   // set on the io thread (under mutex_), read there freely
  std::atomic<bool> connecting_{false};  // connect() was called
  std::shared_ptr<const char> alive_ = std::make_shared<const char>('\0');  // reset when destroyed
  std::uint64_t listener_ = 0;
  // Failover (several servers): all on the io thread but `server_` and `failovers_` (mutex_).
  std::vector<ServerAddress> servers_;
  std::size_t current_ = 0;
  std::chrono::milliseconds failover_after_{0};
  planet::ReconnectPolicy policy_;
  std::unique_ptr<asio::steady_timer> failover_timer_;
  std::string server_;
  std::uint64_t failovers_ = 0;

  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  std::uint64_t rounds_ = 0;
  std::string last_error_;
};

}  // namespace icars::device
