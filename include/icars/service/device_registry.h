// The device registry of SF (ICARS paper 4.3.1): device managers register their devices here;
// for each capability the registry creates an adaptor service (through an AdaptorFactory) and
// puts it in the service container. When the device's connection drops, its services become
// unavailable; when the device registers again, the same service objects are rebound, so
// anything holding them keeps working.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <mutex>
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
  // capability)): factory.add<home::Light, LightService>().
  template <class I, class S>
  void add() {
    add(std::string(I::type_id), [](const df::DeviceInfo& d, const df::CapabilityInfo& c) -> std::shared_ptr<Adaptor> {
      return std::make_shared<S>(d, c);
    });
  }
  // The adaptor for `capability`; a GenericAdaptor when no maker knows its interface.
  std::shared_ptr<Adaptor> make(const df::DeviceInfo& device, const df::CapabilityInfo& capability) const;
  bool knows(const std::string& interface_id) const { return makers_.contains(interface_id); }

  // The adaptors of every capability in idl/home.idl.
  static AdaptorFactory house();

 private:
  std::map<std::string, Make> makers_;
};

class DeviceRegistry final : public df::DeviceRegistryServant {
 public:
  // Serve it with communicator.adapter().add(std::string(device::kRegistryPath), registry).
  DeviceRegistry(planet::Communicator& communicator, ServiceContainer& container,
                 AdaptorFactory factory);
  ~DeviceRegistry() override;

  void register_device(const df::DeviceInfo& device, const planet::Current& current) override;
  void unregister_device(const std::string& id, const planet::Current& current) override;
  std::vector<std::string> devices(const planet::Current& current) override;

  // Devices registered and connected right now.
  std::size_t connected_devices() const;
  // The calls through every adaptor bound from now on are reported to `observer` (see
  // planet::CallObserver); null: none. Set it before devices register.
  void set_call_observer(std::shared_ptr<planet::CallObserver> observer);

 private:
  struct Registered {
    df::DeviceInfo info;
    std::uint64_t connection_id = 0;
    std::vector<std::shared_ptr<Adaptor>> services;
  };
  void on_disconnected(std::uint64_t connection_id);

  planet::Communicator& communicator_;
  ServiceContainer& container_;
  AdaptorFactory factory_;
  std::uint64_t listener_ = 0;
  mutable std::mutex mutex_;
  std::map<std::string, Registered> devices_;
  std::shared_ptr<planet::CallObserver> call_observer_;
};

}  // namespace icars::service
