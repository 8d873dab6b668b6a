// The device registry of SF (ICARS paper 4.3.1): device managers register their devices here;
// for each capability the registry creates an adaptor service (through an AdaptorFactory) and
// puts it in the service container. When the device's connection drops, its services become
// unavailable; when the device registers again, the same service objects are rebound, so
// anything holding them keeps working.
#pragma once

#include <asio/steady_timer.hpp>
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "device.planet.h"
#include "icars/planet/communicator.h"
#include "icars/service/adaptor.h"
#include "icars/service/service_container.h"

namespace icars::service {

// Makes the adaptor service for a capability, by the capability's interface id.
class AdaptorFactory {
 public:
  using Make = std::function<std::shared_ptr<Adaptor>(const df::DeviceInfo&, const df::CapabilityInfo&)>;

  void add(std::string interface_id, Make make) { makers_[std::move(interface_id)] = std::move(make); }
  // Capabilities of IDL interface I become services of adaptor class S (built as S(device,
  // capability)): factory.add<home::Light, home::LightService>().
  template <class I, class S>
  void add() {
    add(std::string(I::type_id), [](const df::DeviceInfo& d, const df::CapabilityInfo& c) -> std::shared_ptr<Adaptor> {
      return std::make_shared<S>(d, c);
    });
  }
  // The adaptor for `capability`; a GenericAdaptor when no maker knows its interface.
  std::shared_ptr<Adaptor> make(const df::DeviceInfo& device, const df::CapabilityInfo& capability) const;
  bool knows(const std::string& interface_id) const { return makers_.contains(interface_id); }
  std::vector<std::string> interface_ids() const;
  // Adds every maker of `other`; throws std::invalid_argument, adding none, if `other` has one
  // for an interface this factory already knows.
  void merge(AdaptorFactory&& other);

 private:
  std::map<std::string, Make> makers_;
};

struct RegistryOptions {
  // Devices held at once by clients that authenticated as no principal (a server without an
  // access policy); a principal's own bound is its `max_devices`.
  std::size_t max_anonymous_devices = 4096;
  // A device whose link has been gone this long is unregistered and its services removed: its
  // manager is gone for good (or was an impostor flooding the registry).
  std::chrono::milliseconds forget_after{std::chrono::minutes(10)};
  // When a device comes back with a state other than the one last acknowledged: send the
  // acknowledged state again (true), or only report it (DeviceRestored either way).
  bool reapply_state = true;
};

// What the registry tells about devices, as events (ServiceContainer::device_events):
//   DeviceLost     device, reason            its link went down; its services are unavailable
//   DeviceBack     device                    it registered again after a loss, or over a new link
//   DeviceRestored device, capability, service, differences (text), reapplied (bool),
//                  error (text, "" when none), and per differing value <name> (the wanted,
//                  acknowledged value) and found_<name> (what the device had)
//   DeviceForgotten device                   gone for longer than forget_after
class DeviceRegistry final : public df::DeviceRegistryServant {
 public:
  // Serve it with communicator.adapter().add(std::string(device::kRegistryPath), registry).
  DeviceRegistry(planet::Communicator& communicator, ServiceContainer& container,
                 AdaptorFactory factory, RegistryOptions options = {});
  ~DeviceRegistry() override;

  // Ownership: a device id belongs to the principal that first registered it (a client of a
  // server with an AccessPolicy) until it unregisters it or the device is forgotten. A
  // registration is refused (RegistrationRefused naming the principal and the device) when the
  // principal's access entry does not list the id, when another principal holds it, or when the
  // principal already holds its max_devices. The holder's own registration over a new link
  // moves the device there (a restarted manager). Without an access policy every client is the
  // same anonymous holder, bounded by max_anonymous_devices.
  void register_device(const df::DeviceInfo& device, const planet::Current& current) override;
  // Only the holder may unregister a device: others get planet::Error(denied).
  void unregister_device(const std::string& id, const planet::Current& current) override;
  std::vector<std::string> devices(const planet::Current& current) override;

  // Devices registered and connected right now.
  std::size_t connected_devices() const;
  // Devices registered, connected or not.
  std::size_t registered_devices() const;
  // The principal holding `device_id` ("" anonymous); nullopt when it is not registered.
  std::optional<std::string> holder(const std::string& device_id) const;
  // Unregisters every device `principal` holds (its access entry was removed); returns how many.
  std::size_t forget_holder(const std::string& principal);
  // One device as the registry holds it (what a SharedDirectory shares).
  struct DeviceView {
    df::DeviceInfo info;
    std::uint64_t connection_id = 0;  // its manager's link; 0: not connected
    std::vector<std::shared_ptr<Adaptor>> services;
  };
  std::optional<DeviceView> view(const std::string& device_id) const;
  std::vector<DeviceView> views() const;
  // `fn(device_id)` runs after a device registered or moved to another link, lost its link, or
  // was removed (unregistered, forgotten, its principal revoked); on the io thread, not
  // blocking. Returns an id for remove_device_watcher.
  std::uint64_t watch_devices(std::function<void(const std::string&)> fn) { return changes_.add(std::move(fn)); }
  void remove_device_watcher(std::uint64_t id) { changes_.remove(id); }

  // Asked when a device registers whose services' ids another server's mirrored device holds
  // here (docs/distribution.md): `fn(device_id)` removes that device and returns true, and the
  // registration goes on; false, or no `fn`, refuses it. On the io thread.
  void set_make_room(std::function<bool(const std::string&)> fn);

  // The calls through every adaptor bound from now on are reported to `observer` (see
  // planet::CallObserver); null: none. Set it before devices register.
  void set_call_observer(std::shared_ptr<planet::CallObserver> observer);

 private:
  struct Registered {
    df::DeviceInfo info;
    std::string holder;  // principal name; "" anonymous
    std::uint64_t connection_id = 0;
    bool lost = false;   // its link went down since it registered
    std::chrono::steady_clock::time_point disconnected_at;
    std::vector<std::shared_ptr<Adaptor>> services;
  };
  void on_disconnected(std::uint64_t connection_id, const std::string& reason);
  void came_back(const std::string& device_id, const std::vector<std::shared_ptr<Adaptor>>& services);
  void forget_expired();
  void arm_forget(std::chrono::steady_clock::time_point at);
  void remove_services(const std::vector<std::shared_ptr<Adaptor>>& services);
  void emit(planet::Event event);

  planet::Communicator& communicator_;
  ServiceContainer& container_;
  AdaptorFactory factory_;
  RegistryOptions options_;
  std::uint64_t listener_ = 0;
  mutable std::mutex mutex_;
  std::map<std::string, Registered> devices_;
  std::shared_ptr<planet::CallObserver> call_observer_;
  Listeners<std::string> changes_;
  std::function<bool(const std::string&)> make_room_;  // under mutex_
  std::unique_ptr<asio::steady_timer> forget_timer_;  // runs while devices are disconnected
  std::chrono::steady_clock::time_point forget_at_{};  // when it fires; {}: not armed
  std::shared_ptr<const char> alive_ = std::make_shared<const char>('\0');
};

}  // namespace icars::service
