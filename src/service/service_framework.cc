#include "icars/service/service_framework.h"

#include "icars/device/device_manager.h"

namespace icars::service {

ServiceFramework::ServiceFramework(planet::Communicator& communicator, AdaptorFactory adaptors,
                                   RegistryOptions options, const std::vector<MakeComposer>& composers)
    : communicator_(communicator),
      adaptors_(adaptors),
      registry_(std::make_shared<DeviceRegistry>(communicator, container_, std::move(adaptors), options)) {
  for (const auto& make : composers) {
    if (auto composer = make(container_)) composers_.push_back(std::move(composer));
  }
  communicator_.adapter().add(std::string(device::kRegistryPath), registry_);
}

ServiceFramework::~ServiceFramework() {
  communicator_.adapter().remove(device::kRegistryPath);
  mirrors_.clear();
  shared_.reset();
  composers_.clear();
  registry_.reset();  // the last owner: stops listening to connection events
}

void ServiceFramework::share() {
  if (!shared_) shared_ = std::make_unique<SharedDirectory>(communicator_, *registry_);
}

DirectoryMirror& ServiceFramework::mirror(std::shared_ptr<planet::Peer> link, std::string name) {
  mirrors_.push_back(std::make_unique<DirectoryMirror>(communicator_, container_, adaptors_, std::move(link),
                                                       std::move(name)));
  return *mirrors_.back();
}

}  // namespace icars::service
