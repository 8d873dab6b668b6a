#include "icars/device/device_manager.h"

#include <spdlog/spdlog.h>

#include <asio/post.hpp>
#include <future>
#include <stdexcept>

#include "icars/planet/proxy.h"

namespace icars::device {

DeviceManager::DeviceManager(planet::Communicator& communicator) : communicator_(communicator) {
  listener_ = communicator_.connections().add_listener([this](const planet::ConnectionEvent& e) {
    // Only the client link to the server carries registrations.
    if (!e.peer || e.peer != peer_) return;
    if (e.kind == planet::LinkEventKind::connected || e.kind == planet::LinkEventKind::reconnected) {
      if (failover_timer_) failover_timer_->cancel();
      register_all(e.connection);
    } else if (e.kind == planet::LinkEventKind::disconnected) {
      arm_failover();
    }
  });
}

DeviceManager::~DeviceManager() {
  communicator_.connections().remove_listener(listener_);
  if (failover_timer_ && !communicator_.in_io_thread() && !communicator_.io().stopped()) {
    auto cancelled = std::make_shared<std::promise<void>>();
    asio::post(communicator_.io(), [this, cancelled] {
      failover_timer_->cancel();
      cancelled->set_value();
    });
    cancelled->get_future().wait_for(std::chrono::seconds(10));
  }
  // What add() and set_online() left for the io thread checks alive_ first; once the io thread
  // has run the no-op below, none of it is running or will use this manager.
  alive_.reset();
  if (connecting_.load() && !communicator_.in_io_thread() && !communicator_.io().stopped()) {
    auto flushed = std::make_shared<std::promise<void>>();
    asio::post(communicator_.io(), [flushed] { flushed->set_value(); });
    flushed->get_future().wait_for(std::chrono::seconds(10));
  }
  for (const auto& device : devices()) {
    for (const auto& c : device->capabilities()) communicator_.adapter().remove(device->path_of(c));
  }
}

void DeviceManager::add(std::shared_ptr<Device> device, bool online) {
  {
    std::lock_guard lock(devices_mutex_);
    for (const auto& d : devices_) {
      if (d->id() == device->id()) {
        throw std::invalid_argument("device manager already hosts a device '" + device->id() + "'");
      }
    }
    for (const auto& c : device->capabilities()) {
      communicator_.adapter().add(device->path_of(c), c.servant);
    }
    devices_.push_back(device);
    if (!online) offline_.insert(device->id());
  }
  // Before connect() the first connection registers it with the others. After, the io thread
  // (which owns peer_) registers it if the link is up, or the next connection does.
  if (online && connecting_.load()) {
    asio::post(communicator_.io(), [this, alive = std::weak_ptr(alive_), device] {
      if (!alive.expired()) update_one(device, true);
    });
  }
}

std::vector<std::shared_ptr<Device>> DeviceManager::devices() const {
  std::lock_guard lock(devices_mutex_);
  return devices_;
}

void DeviceManager::set_online(const std::string& device_id, bool online) {
  std::shared_ptr<Device> device;
  {
    std::lock_guard lock(devices_mutex_);
    for (const auto& d : devices_) {
      if (d->id() == device_id) device = d;
    }
    if (!device) throw std::invalid_argument("device manager hosts no device '" + device_id + "'");
    if (online ? offline_.erase(device_id) == 0 : !offline_.insert(device_id).second) return;
  }
  if (connecting_.load()) {
    asio::post(communicator_.io(), [this, alive = std::weak_ptr(alive_), device, online] {
      if (!alive.expired()) update_one(device, online);
    });
  }
}

bool DeviceManager::online(const std::string& device_id) const {
  std::lock_guard lock(devices_mutex_);
  return !offline_.contains(device_id);
}

void DeviceManager::update_one(const std::shared_ptr<Device>& device, bool online) {
  if (!peer_) return;  // not connected yet: the first connection registers it
  const auto connection = peer_->connection();
  if (!connection) return;  // down: the reconnection's round registers it (if online then)
  send_one(connection, device, online);
}

void DeviceManager::send_one(const std::shared_ptr<planet::Connection>& connection,
                             const std::shared_ptr<Device>& device, bool online) {
  planet::Proxy registry(communicator_, connection, std::string(kRegistryPath));
  const auto done = [this, alive = std::weak_ptr(alive_), id = device->id(),
                     online](std::exception_ptr e) {
    if (alive.expired()) return;
    if (!e) {
      communicator_.log().info("{} device {} with the server",
                               online ? "registered" : "unregistered", id);
      return;
    }
    const auto error = planet::describe(e);
    communicator_.log().error("{} device {} failed: {}", online ? "registering" : "unregistering",
                              id, error);
    std::lock_guard lock(mutex_);
    last_error_ = id + ": " + error;
  };
  if (online) {
    registry.async_call(df::DeviceRegistry::register_device, {device->info()}, done);
  } else {
    registry.async_call(df::DeviceRegistry::unregister_device, {device->id()}, done);
  }
}

void DeviceManager::connect(const std::string& host, std::uint16_t port,
                            planet::ReconnectPolicy policy) {
  // The peer is created on this thread while the io thread may already report it connected;
  // running the assignment on the io thread orders it before that event is handled.
  connecting_ = true;
  std::promise<void> stored;
  asio::post(communicator_.io(), [&] {
    auto peer = communicator_.connect(host, port, policy);
    std::lock_guard lock(mutex_);
    peer_ = std::move(peer);
    stored.set_value();
  });
  stored.get_future().wait();
  std::lock_guard lock(mutex_);
  server_ = host + ":" + std::to_string(port);
}

void DeviceManager::connect(std::vector<ServerAddress> servers, std::chrono::milliseconds failover_after,
                            planet::ReconnectPolicy policy) {
  if (servers.empty()) throw std::invalid_argument("a device manager needs a server to connect to");
  if (servers.size() == 1) return connect(servers.front().host, servers.front().port, policy);
  connecting_ = true;
  std::promise<void> stored;
  asio::post(communicator_.io(), [&] {
    servers_ = std::move(servers);
    failover_after_ = failover_after;
    policy_ = policy;
    failover_timer_ = std::make_unique<asio::steady_timer>(communicator_.io());
    current_ = 0;
    auto peer = communicator_.connect(servers_[0].host, servers_[0].port, policy_);
    {
      std::lock_guard lock(mutex_);
      peer_ = std::move(peer);
      server_ = servers_[0].host + ":" + std::to_string(servers_[0].port);
    }
    arm_failover();  // also when the first server never answers
    stored.set_value();
  });
  stored.get_future().wait();
}

void DeviceManager::arm_failover() {
  if (!failover_timer_ || servers_.size() < 2) return;
  failover_timer_->expires_after(failover_after_);
  failover_timer_->async_wait([this, alive = std::weak_ptr(alive_)](const std::error_code& ec) {
    if (ec || alive.expired()) return;
    if (peer_ && peer_->is_connected()) return;
    fail_over();
  });
}

void DeviceManager::fail_over() {
  const auto from = server_;
  if (peer_) peer_->stop();
  current_ = (current_ + 1) % servers_.size();
  const auto& next = servers_[current_];
  auto peer = communicator_.connect(next.host, next.port, policy_);
  std::string to = next.host + ":" + std::to_string(next.port);
  communicator_.log().warn("server {} unreachable for {} ms: moving to {}", from, failover_after_.count(), to);
  {
    std::lock_guard lock(mutex_);
    peer_ = std::move(peer);
    server_ = std::move(to);
    ++failovers_;
  }
  arm_failover();
}

std::shared_ptr<planet::Peer> DeviceManager::peer() const {
  std::lock_guard lock(mutex_);
  return peer_;
}

std::string DeviceManager::current_server() const {
  std::lock_guard lock(mutex_);
  return server_;
}

std::uint64_t DeviceManager::failovers() const {
  std::lock_guard lock(mutex_);
  return failovers_;
}

void DeviceManager::register_all(std::shared_ptr<planet::Connection> connection) {
  std::vector<std::shared_ptr<Device>> online;
  std::vector<std::shared_ptr<Device>> offline;
  {
    std::lock_guard lock(devices_mutex_);
    for (const auto& d : devices_) (offline_.contains(d->id()) ? offline : online).push_back(d);
  }
  // A device that went offline while the link was down may still be registered (as lost): the
  // registry forgets it now rather than after its forget_after.
  for (const auto& device : offline) send_one(connection, device, false);
  auto remaining = std::make_shared<std::size_t>(online.size());
  auto failed = std::make_shared<bool>(false);
  planet::Proxy registry(communicator_, connection, std::string(kRegistryPath));
  if (online.empty()) {
    std::lock_guard lock(mutex_);
    ++rounds_;
    changed_.notify_all();
    return;
  }
  for (const auto& device : online) {
    registry.async_call(
        df::DeviceRegistry::register_device, {device->info()},
        [this, remaining, failed, count = online.size(), id = device->id()](std::exception_ptr e) {
          if (e) {
            *failed = true;
            const auto error = planet::describe(e);
            communicator_.log().error("registering device {} failed: {}", id, error);
            std::lock_guard lock(mutex_);
            last_error_ = id + ": " + error;
          }
          if (--*remaining == 0 && !*failed) {
            communicator_.log().info("registered {} devices with the server", count);
            std::lock_guard lock(mutex_);
            ++rounds_;
            changed_.notify_all();
          }
        });
  }
}

std::uint64_t DeviceManager::registration_rounds() const {
  std::lock_guard lock(mutex_);
  return rounds_;
}

bool DeviceManager::wait_registered(std::uint64_t rounds, std::chrono::milliseconds timeout) const {
  std::unique_lock lock(mutex_);
  return changed_.wait_for(lock, timeout, [&] { return rounds_ >= rounds; });
}

std::string DeviceManager::last_error() const {
  std::lock_guard lock(mutex_);
  return last_error_;
}

}  // namespace icars::device
