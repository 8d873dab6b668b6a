#include "icars/service/adaptor.h"

#include <spdlog/spdlog.h>

namespace icars::service {

Adaptor::Adaptor(std::string type, const df::DeviceInfo& device, const df::CapabilityInfo& capability)
    : Service(device.id + "." + capability.name, std::move(type),
              ServiceAttributes{device.id, capability.name, device.room, device.carrier}),
      interface_id_(capability.interface_id),
      path_(capability.path) {}

Adaptor::~Adaptor() = default;

void Adaptor::bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link) {
  on_bind(communicator, link);
  set_available(true);
}

void Adaptor::log_failure(planet::Communicator& communicator, std::string_view what,
                          std::exception_ptr error) const {
  try {
    std::rethrow_exception(error);
  } catch (const std::exception& e) {
    communicator.log().warn("service {} {}: {}", id(), what, e.what());
  }
}

void Adaptor::set_call_observer(std::shared_ptr<planet::CallObserver> observer) {
  std::lock_guard lock(observer_mutex_);
  call_observer_ = std::move(observer);
}

std::shared_ptr<planet::CallObserver> Adaptor::call_observer() const {
  std::lock_guard lock(observer_mutex_);
  return call_observer_;
}

void Adaptor::unbind() {
  set_available(false);
  on_unbind();
}

}  // namespace icars::service
