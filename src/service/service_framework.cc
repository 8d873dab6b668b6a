#include "icars/service/service_framework.h"

#include "icars/device/device_manager.h"

namespace icars::service {

ServiceFramework::ServiceFramework(planet::Communicator& communicator, AdaptorFactory adaptors,
                                   RegistryOptions options)
    : communicator_(communicator),
      registry_(std::make_shared<DeviceRegistry>(communicator, container_, std::move(adaptors), options)),
      composites_(std::make_unique<CompositeFactory>(container_)) {
  communicator_.adapter().add(std::string(device::kRegistryPath), registry_);
}

ServiceFramework::~ServiceFramework() {
  communicator_.adapter().remove(device::kRegistryPath);
  composites_.reset();
  registry_.reset();  // the last owner: stops listening to connection events
}

}  // namespace icars::service
