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
    if (e.peer && e.peer == peer_ &&
        (e.kind == planet::LinkEventKind::connected ||
         e.kind == planet::LinkEventKind::reconnected)) {
      register_all(e.connection);
    }
  });
}

DeviceManager::~DeviceManager() {
  communicator_.connections().remove_listener(listener_);
  for (const auto& device : devices_) {
    for (const auto& c : device->capabilities()) communicator_.adapter().remove(device->path_of(c));
  }
}

void DeviceManager::add(std::shared_ptr<Device> device) {
  for (const auto& d : devices_) {
    if (d->id() == device->id()) {
      throw std::invalid_argument("device manager already hosts a device '" + device->id() + "'");
    }
  }
  for (const auto& c : device->capabilities()) {
    communicator_.adapter().add(device->path_of(c), c.servant);
  }
  devices_.push_back(std::move(device));
}

void DeviceManager::connect(const std::string& host, std::uint16_t port,
                            planet::ReconnectPolicy policy) {
  // The peer is created on this thread while the io thread may already report it connected;
  // running the assignment on the io thread orders it before that event is handled.
  std::promise<void> stored;
  asio::post(communicator_.io(), [&] {
    peer_ = communicator_.connect(host, port, policy);
    stored.set_value();
  });
  stored.get_future().wait();
}

void DeviceManager::register_all(std::shared_ptr<planet::Connection> connection) {
  auto remaining = std::make_shared<std::size_t>(devices_.size());
  auto failed = std::make_shared<bool>(false);
  planet::Proxy registry(communicator_, connection, std::string(kRegistryPath));
  if (devices_.empty()) {
    std::lock_guard lock(mutex_);
    ++rounds_;
    changed_.notify_all();
    return;
  }
  for (const auto& device : devices_) {
    registry.async_call(
        df::DeviceRegistry::register_device, {device->info()},
        [this, remaining, failed, id = device->id()](std::exception_ptr e) {
          if (e) {
            *failed = true;
            const auto error = planet::describe(e);
            communicator_.log().error("registering device {} failed: {}", id, error);
            std::lock_guard lock(mutex_);
            last_error_ = id + ": " + error;
          }
          if (--*remaining == 0 && !*failed) {
            communicator_.log().info("registered {} devices with the server", devices_.size());
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
