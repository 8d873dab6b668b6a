#include "icars/service/device_registry.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <asio/post.hpp>
#include <future>

#include "icars/device/device_manager.h"

namespace icars::service {

std::vector<std::string> AdaptorFactory::interface_ids() const {
  std::vector<std::string> ids;
  ids.reserve(makers_.size());
  for (const auto& [id, make] : makers_) ids.push_back(id);
  return ids;
}

void AdaptorFactory::merge(AdaptorFactory&& other) {
  for (const auto& [id, make] : other.makers_) {
    if (makers_.contains(id)) throw std::invalid_argument("interface " + id + " already has an adaptor");
  }
  makers_.merge(other.makers_);
}

std::shared_ptr<Adaptor> AdaptorFactory::make(const df::DeviceInfo& device,
                                              const df::CapabilityInfo& capability) const {
  if (auto it = makers_.find(capability.interface_id); it != makers_.end()) {
    return it->second(device, capability);
  }
  return std::make_shared<GenericAdaptor>(device, capability);
}


namespace {

std::string holder_name(const std::string& holder) {
  return holder.empty() ? std::string("an unauthenticated client") : fmt::format("principal '{}'", holder);
}

}  // namespace

DeviceRegistry::DeviceRegistry(planet::Communicator& communicator, ServiceContainer& container,
                               AdaptorFactory factory, RegistryOptions options)
    : communicator_(communicator),
      container_(container),
      factory_(std::move(factory)),
      options_(options),
      forget_timer_(std::make_unique<asio::steady_timer>(communicator.io())) {
  listener_ = communicator_.connections().add_listener([this](const planet::ConnectionEvent& e) {
    if (e.kind == planet::LinkEventKind::disconnected && e.connection) {
      on_disconnected(e.connection->id(), e.reason);
    }
  });
}

DeviceRegistry::~DeviceRegistry() {
  communicator_.connections().remove_listener(listener_);
  // Handlers on the io thread (the forget timer, restore replies) check alive_ before they use
  // this registry; once the io thread has run the cancel below, none is running or will.
  alive_.reset();
  if (communicator_.in_io_thread() || communicator_.io().stopped()) {
    forget_timer_->cancel();
    return;
  }
  std::promise<void> cancelled;
  asio::post(communicator_.io(), [this, &cancelled] {
    forget_timer_->cancel();
    cancelled.set_value();
  });
  cancelled.get_future().wait();
}

void DeviceRegistry::register_device(const df::DeviceInfo& device, const planet::Current& current) {
  if (device.id.empty()) throw df::RegistrationRefused(device.id, "the device has no id");
  if (device.capabilities.empty()) {
    throw df::RegistrationRefused(device.id, "the device declares no capabilities");
  }
  const auto principal = current.connection->principal();
  const std::string holder = principal ? principal->name : std::string();
  if (principal && !principal->may_register(device.id)) {
    communicator_.log().warn("refused device {} from principal '{}': not in its access entry", device.id,
                             holder);
    throw df::RegistrationRefused(
        device.id, fmt::format("principal '{}' may not register device '{}': its access entry's \"devices\" "
                               "do not list it",
                               holder, device.id));
  }
  // A device another server shared holds the ids here: the device registering here takes them.
  std::function<bool(const std::string&)> make_room;
  {
    std::lock_guard lock(mutex_);
    if (!devices_.contains(device.id)) make_room = make_room_;
  }
  if (make_room) {
    for (const auto& c : device.capabilities) {
      if (container_.get(device.id + "." + c.name)) {
        make_room(device.id);
        break;
      }
    }
  }
  std::vector<std::shared_ptr<Adaptor>> services;
  bool back = false;
  {
    std::lock_guard lock(mutex_);
    auto it = devices_.find(device.id);
    if (it != devices_.end() && it->second.holder != holder) {
      communicator_.log().warn("refused device {} from {}: held by {}", device.id, holder_name(holder),
                               holder_name(it->second.holder));
      throw df::RegistrationRefused(
          device.id, fmt::format("device '{}' is held by {}; {} may not take it over", device.id,
                                 holder_name(it->second.holder), holder_name(holder)));
    }
    if (it == devices_.end()) {
      std::size_t held = 0;
      for (const auto& [id, r] : devices_) held += r.holder == holder;
      const std::size_t limit = principal ? principal->max_devices : options_.max_anonymous_devices;
      if (held >= limit) {
        communicator_.log().warn("refused device {} from {}: it holds {} devices", device.id,
                                 holder_name(holder), held);
        throw df::RegistrationRefused(
            device.id, fmt::format("{} holds {} devices, its limit ({})", holder_name(holder), held,
                                   principal ? "max_devices in its access entry" : "max_anonymous_devices"));
      }
      Registered r;
      r.info = device;
      r.holder = holder;
      for (const auto& c : device.capabilities) {
        r.services.push_back(factory_.make(device, c));
        // Another server's device mirrored here (docs/distribution.md) holds the id.
        if (container_.get(r.services.back()->id())) {
          throw df::RegistrationRefused(
              device.id, fmt::format("service '{}' exists already on this server (a device of another server "
                                     "with the same id)",
                                     r.services.back()->id()));
        }
      }
      it = devices_.emplace(device.id, std::move(r)).first;
      for (const auto& s : it->second.services) container_.add(s);
      communicator_.log().info("device {} ({}) registered by {}: {} services", device.id, device.type,
                               holder_name(holder), it->second.services.size());
    } else {
      const bool moved = it->second.connection_id != 0 && it->second.connection_id != current.connection->id();
      if (moved) {
        // Its old link may not have closed yet (a manager restarted faster than the heartbeat
        // timeout): the same holder's newest registration wins, and the device behind it may
        // have lost its state just as if the old link had been seen to close.
        communicator_.log().info("device {} moved to {}", device.id, current.connection->describe());
      }
      back = it->second.lost || moved;
      it->second.lost = false;
    }
    it->second.connection_id = current.connection->id();
    services = it->second.services;
    for (const auto& s : services) s->set_call_observer(call_observer_);
  }
  for (const auto& s : services) s->bind(communicator_, current.connection);
  if (back) came_back(device.id, services);
  changes_.notify(device.id);
}

void DeviceRegistry::came_back(const std::string& device_id,
                               const std::vector<std::shared_ptr<Adaptor>>& services) {
  communicator_.log().info("device {} is back", device_id);
  planet::Event back("DeviceBack");
  back.set("device", device_id);
  emit(std::move(back));
  for (const auto& adaptor : services) {
    if (!adaptor->keeps_state()) continue;
    adaptor->restore(options_.reapply_state, [this, alive = std::weak_ptr<const char>(alive_), adaptor,
                                              device_id](Restoration r) {
      if (!alive.lock()) return;
      if (r.differences.empty() && !r.error) return;  // it kept its state
      const std::string error = planet::describe(r.error);
      const auto text = describe(r.differences);
      communicator_.log().warn("device {} came back with another state ({}){}{}", device_id, text,
                               r.reapplied ? "; re-applied the acknowledged state" : "",
                               error.empty() ? "" : "; failed: " + error);
      planet::Event restored("DeviceRestored");
      restored.set("device", device_id)
          .set("capability", adaptor->attributes().capability)
          .set("service", adaptor->id())
          .set("differences", text)
          .set("reapplied", r.reapplied)
          .set("error", error);
      for (const auto& d : r.differences) {
        if (!d.wanted.empty()) restored.put(d.name, d.wanted);
        if (!d.found.empty()) restored.put("found_" + d.name, d.found);
      }
      emit(std::move(restored));
    });
  }
}

void DeviceRegistry::emit(planet::Event event) { container_.publish_device_event(event); }

void DeviceRegistry::unregister_device(const std::string& id, const planet::Current& current) {
  const auto principal = current.connection->principal();
  const std::string holder = principal ? principal->name : std::string();
  std::vector<std::shared_ptr<Adaptor>> services;
  {
    std::lock_guard lock(mutex_);
    auto it = devices_.find(id);
    if (it == devices_.end()) return;
    if (it->second.holder != holder) {
      communicator_.log().warn("refused to unregister device {} for {}: held by {}", id, holder_name(holder),
                               holder_name(it->second.holder));
      throw planet::Error(planet::ErrorKind::denied,
                          fmt::format("{} may not unregister device '{}': it is held by {}", holder_name(holder),
                                      id, holder_name(it->second.holder)));
    }
    services = std::move(it->second.services);
    devices_.erase(it);
  }
  remove_services(services);
  changes_.notify(id);
}

void DeviceRegistry::remove_services(const std::vector<std::shared_ptr<Adaptor>>& services) {
  for (const auto& s : services) {
    s->unbind();
    s->retire();
    container_.remove(s->id());
  }
}

std::vector<std::string> DeviceRegistry::devices(const planet::Current&) {
  std::lock_guard lock(mutex_);
  std::vector<std::string> out;
  for (const auto& [id, r] : devices_) out.push_back(id);
  return out;
}

std::optional<DeviceRegistry::DeviceView> DeviceRegistry::view(const std::string& device_id) const {
  std::lock_guard lock(mutex_);
  auto it = devices_.find(device_id);
  if (it == devices_.end()) return std::nullopt;
  return DeviceView{it->second.info, it->second.connection_id, it->second.services};
}

std::vector<DeviceRegistry::DeviceView> DeviceRegistry::views() const {
  std::lock_guard lock(mutex_);
  std::vector<DeviceView> out;
  out.reserve(devices_.size());
  for (const auto& [id, r] : devices_) out.push_back({r.info, r.connection_id, r.services});
  return out;
}

std::size_t DeviceRegistry::connected_devices() const {
  std::lock_guard lock(mutex_);
  std::size_t n = 0;
  for (const auto& [id, r] : devices_) n += r.connection_id != 0;
  return n;
}

std::size_t DeviceRegistry::registered_devices() const {
  std::lock_guard lock(mutex_);
  return devices_.size();
}

std::optional<std::string> DeviceRegistry::holder(const std::string& device_id) const {
  std::lock_guard lock(mutex_);
  auto it = devices_.find(device_id);
  if (it == devices_.end()) return std::nullopt;
  return it->second.holder;
}

std::size_t DeviceRegistry::forget_holder(const std::string& principal) {
  std::vector<std::shared_ptr<Adaptor>> services;
  std::vector<std::string> forgotten;
  {
    std::lock_guard lock(mutex_);
    for (auto it = devices_.begin(); it != devices_.end();) {
      if (it->second.holder != principal) {
        ++it;
        continue;
      }
      forgotten.push_back(it->first);
      services.insert(services.end(), it->second.services.begin(), it->second.services.end());
      it = devices_.erase(it);
    }
  }
  remove_services(services);
  for (const auto& id : forgotten) {
    planet::Event e("DeviceForgotten");
    e.set("device", id);
    emit(std::move(e));
    changes_.notify(id);
  }
  if (!forgotten.empty()) {
    communicator_.log().warn("forgot {} devices of principal '{}'", forgotten.size(), principal);
  }
  return forgotten.size();
}

void DeviceRegistry::set_make_room(std::function<bool(const std::string&)> fn) {
  std::lock_guard lock(mutex_);
  make_room_ = std::move(fn);
}

void DeviceRegistry::set_call_observer(std::shared_ptr<planet::CallObserver> observer) {
  std::lock_guard lock(mutex_);
  call_observer_ = std::move(observer);
}

void DeviceRegistry::on_disconnected(std::uint64_t connection_id, const std::string& reason) {
  std::vector<std::shared_ptr<Adaptor>> services;
  std::vector<std::string> lost;
  {
    std::lock_guard lock(mutex_);
    const auto now = std::chrono::steady_clock::now();
    for (auto& [id, r] : devices_) {
      if (r.connection_id != connection_id) continue;
      r.connection_id = 0;
      r.lost = true;
      r.disconnected_at = now;
      lost.push_back(id);
      services.insert(services.end(), r.services.begin(), r.services.end());
    }
  }
  if (lost.empty()) return;
  communicator_.log().warn("devices {} disconnected ({}); their services are unavailable",
                           fmt::join(lost, ", "), reason);
  for (const auto& s : services) s->unbind();
  for (const auto& id : lost) {
    planet::Event e("DeviceLost");
    e.set("device", id).set("reason", reason);
    emit(std::move(e));
    changes_.notify(id);
  }
  arm_forget(std::chrono::steady_clock::now() + options_.forget_after);
}

// On the io thread (connection listeners and the timer run there): the sweep runs at the
// earliest expiry; a later one waits for the sweep to re-arm it.
void DeviceRegistry::arm_forget(std::chrono::steady_clock::time_point at) {
  if (forget_at_ != std::chrono::steady_clock::time_point{} && forget_at_ <= at) return;
  forget_at_ = at;
  forget_timer_->expires_at(at);
  forget_timer_->async_wait([this, alive = std::weak_ptr<const char>(alive_)](const std::error_code& ec) {
    if (!ec && !alive.expired()) forget_expired();
  });
}

void DeviceRegistry::forget_expired() {
  forget_at_ = {};
  std::vector<std::shared_ptr<Adaptor>> services;
  std::vector<std::string> forgotten;
  std::optional<std::chrono::steady_clock::time_point> next;
  {
    std::lock_guard lock(mutex_);
    const auto now = std::chrono::steady_clock::now();
    for (auto it = devices_.begin(); it != devices_.end();) {
      auto& r = it->second;
      if (r.connection_id != 0) {
        ++it;
        continue;
      }
      const auto expiry = r.disconnected_at + options_.forget_after;
      if (expiry > now) {
        next = next ? std::min(*next, expiry) : expiry;
        ++it;
        continue;
      }
      forgotten.push_back(it->first);
      services.insert(services.end(), r.services.begin(), r.services.end());
      it = devices_.erase(it);
    }
  }
  remove_services(services);
  if (!forgotten.empty()) {
    communicator_.log().warn("forgot {} devices gone for {} s: {}", forgotten.size(),
                             std::chrono::duration_cast<std::chrono::seconds>(options_.forget_after).count(),
                             fmt::join(forgotten, ", "));
  }
  for (const auto& id : forgotten) {
    planet::Event e("DeviceForgotten");
    e.set("device", id);
    emit(std::move(e));
    changes_.notify(id);
  }
  if (next) arm_forget(*next);
}

}  // namespace icars::service
