#include "icars/service/service_framework.h"

#include "icars/device/device_manager.h"

namespace icars::service {

ServiceFramework::ServiceFramework(planet::Communicator& communicator, AdaptorFactory adaptors,
                                   RegistryOptions options, const std::vector<MakeComposer>& composers)
    : communicator_(communicator),
      registry_(std::make_shared<DeviceRegistry>(communicator, container_, std::move(adaptors), options)) {
  for (const auto& make : composers) {
    if (auto composer = make(container_)) composers_.push_back(std::move(composer));
  }
  communicator_.adapter().add(std::string(device::kRegistryPath), registry_);
}

ServiceFramework::~ServiceFramework() {
  communicator_.adapter().remove(device::kRegistryPath);
  composers_.clear();
  registry_.reset();  // the last owner: stops listening to connection events
}

}  // namespace icars::service
