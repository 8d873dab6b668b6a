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
  registry_->set_make_room(nullptr);
  std::vector<std::shared_ptr<DirectoryMirror>> mirrors;
  {
    std::lock_guard lock(mirrors_mutex_);
    mirrors.swap(mirrors_);
  }
  for (const auto& m : mirrors) m->set_make_room(nullptr);
  mirrors.clear();  // a make-room request in progress on the io thread holds its mirrors until it ends
  shared_.reset();
  composers_.clear();
  registry_.reset();  // the last owner: stops listening to connection events
}

void ServiceFramework::share() {
  if (!shared_) shared_ = std::make_unique<SharedDirectory>(communicator_, *registry_);
}

DirectoryMirror& ServiceFramework::mirror(std::shared_ptr<planet::Peer> link, std::string name) {
  auto mirror = std::make_shared<DirectoryMirror>(communicator_, container_, adaptors_, std::move(link),
                                                  std::move(name));
  // Who holds a device id when several could (docs/distribution.md): a device registered here
  // before any mirrored one; a connected device before a disconnected one of another mirror.
  const auto* claimant = mirror.get();
  mirror->set_make_room([this, claimant](const std::string& device_id) {
    for (const auto& other : mirrors()) {
      if (other.get() != claimant && other->yield(device_id, /*only_if_disconnected=*/true)) return true;
    }
    return false;
  });
  std::lock_guard lock(mirrors_mutex_);
  if (mirrors_.empty()) {
    registry_->set_make_room([this](const std::string& device_id) {
      bool yielded = false;
      for (const auto& m : mirrors()) yielded |= m->yield(device_id, /*only_if_disconnected=*/false);
      return yielded;
    });
  }
  mirrors_.push_back(std::move(mirror));
  return *mirrors_.back();
}

std::vector<std::shared_ptr<DirectoryMirror>> ServiceFramework::mirrors() const {
  std::lock_guard lock(mirrors_mutex_);
  return mirrors_;
}

}  // namespace icars::service
