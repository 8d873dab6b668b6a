// The Service Framework of a mediating server, assembled: the service container, the device
// registry served at device::kRegistryPath, and the factories of the adaptive services.
// Destroy it before its communicator (it stops taking registrations and connection events
// first, so no callback reaches a destroyed container).
#pragma once

#include <memory>

#include "icars/planet/communicator.h"
#include "icars/service/composite.h"
#include "icars/service/device_registry.h"
#include "icars/service/service_container.h"

namespace icars::service {

class ServiceFramework {
 public:
  explicit ServiceFramework(planet::Communicator& communicator,
                            AdaptorFactory adaptors = AdaptorFactory::house(), RegistryOptions options = {});
  ~ServiceFramework();
  ServiceFramework(const ServiceFramework&) = delete;
  ServiceFramework& operator=(const ServiceFramework&) = delete;

  ServiceContainer& container() { return container_; }
  DeviceRegistry& registry() { return *registry_; }

 private:
  planet::Communicator& communicator_;
  ServiceContainer container_;
  std::shared_ptr<DeviceRegistry> registry_;
  std::unique_ptr<CompositeFactory> composites_;
};

}  // namespace icars::service
