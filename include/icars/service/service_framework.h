// The Service Framework of a mediating server, assembled: the service container, the device
// registry served at device::kRegistryPath, and the composers of adaptive services.
// Destroy it before its communicator (it stops taking registrations and connection events
// first, so no callback reaches a destroyed container).
#pragma once

#include <functional>
#include <memory>
#include <mutex>
#include <vector>

#include "icars/planet/communicator.h"
#include "icars/service/device_registry.h"
#include "icars/service/service_container.h"
#include "icars/service/shared_directory.h"

namespace icars::service {

// Builds adaptive services (ICARS paper 3.3, Fig. 4: composite and augmented services) out of
// the services in a container for as long as it lives: it watches the container, adds a
// composite once its parts are there and keeps it across their reconnections. The home's is
// home::CompositeFactory; a plugin may add its own.
class Composer {
 public:
  virtual ~Composer() = default;
};
using MakeComposer = std::function<std::unique_ptr<Composer>(ServiceContainer&)>;

class ServiceFramework {
 public:
  // `adaptors` makes the adaptor service of each capability a device registers (a capability
  // no maker knows becomes a GenericAdaptor); `composers` are made once, over the container,
  // and destroyed first.
  explicit ServiceFramework(planet::Communicator& communicator, AdaptorFactory adaptors = {},
                            RegistryOptions options = {}, const std::vector<MakeComposer>& composers = {});
  ~ServiceFramework();
  ServiceFramework(const ServiceFramework&) = delete;
  ServiceFramework& operator=(const ServiceFramework&) = delete;

  ServiceContainer& container() { return container_; }
  DeviceRegistry& registry() { return *registry_; }

  // One service directory over several servers (docs/distribution.md). share() lets other
  // servers use the devices registered here (once; later calls do nothing); mirror() makes the
  // devices `link`'s server shares services here, with this framework's adaptors, for as long
  // as the framework lives. Not on the io thread.
  void share();
  DirectoryMirror& mirror(std::shared_ptr<planet::Peer> link, std::string name);
  std::vector<std::shared_ptr<DirectoryMirror>> mirrors() const;

 private:
  planet::Communicator& communicator_;
  ServiceContainer container_;
  AdaptorFactory adaptors_;  // for mirrors
  std::shared_ptr<DeviceRegistry> registry_;
  std::vector<std::unique_ptr<Composer>> composers_;
  std::unique_ptr<SharedDirectory> shared_;
  mutable std::mutex mirrors_mutex_;  // mirror() against the io thread's make-room requests
  std::vector<std::shared_ptr<DirectoryMirror>> mirrors_;
};

}  // namespace icars::service
