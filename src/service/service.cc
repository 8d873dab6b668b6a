#include "icars/service/service.h"

namespace icars::service {

Service::Service(std::string id, std::string type, ServiceAttributes attributes)
    : id_(std::move(id)), type_(std::move(type)), attributes_(std::move(attributes)) {}

bool Service::available() const {
  std::lock_guard lock(mutex_);
  return available_;
}

void Service::set_available(bool available) {
  {
    std::lock_guard lock(mutex_);
    if (available_ == available) return;
    available_ = available;
  }
  watchers_.notify(available);
}

}  // namespace icars::service
