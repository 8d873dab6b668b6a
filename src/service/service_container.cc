#include "icars/service/service_container.h"

#include <stdexcept>

namespace icars::service {

void ServiceContainer::add(std::shared_ptr<Service> service) {
  std::weak_ptr<Service> weak = service;
  {
    std::lock_guard lock(mutex_);
    for (const auto& e : entries_) {
      if (e.service->id() == service->id()) {
        throw std::invalid_argument("a service with id '" + service->id() + "' already exists");
      }
    }
    const auto watch_id = service->watch([this, weak](const bool& available) {
      if (auto s = weak.lock()) {
        watchers_.notify(s, available ? ServiceChange::available : ServiceChange::unavailable);
      }
    });
    entries_.push_back(Entry{service, watch_id});
  }
  watchers_.notify(service, ServiceChange::added);
}

bool ServiceContainer::remove(const std::string& id) {
  std::shared_ptr<Service> removed;
  {
    std::lock_guard lock(mutex_);
    for (auto it = entries_.begin(); it != entries_.end(); ++it) {
      if (it->service->id() == id) {
        removed = it->service;
        removed->remove_watcher(it->watch_id);
        entries_.erase(it);
        break;
      }
    }
  }
  if (!removed) return false;
  watchers_.notify(removed, ServiceChange::removed);
  return true;
}

std::shared_ptr<Service> ServiceContainer::get(const std::string& id) const {
  std::lock_guard lock(mutex_);
  for (const auto& e : entries_) {
    if (e.service->id() == id) return e.service;
  }
  return nullptr;
}

std::vector<std::shared_ptr<Service>> ServiceContainer::find(const ServiceQuery& q) const {
  std::vector<std::shared_ptr<Service>> out;
  std::lock_guard lock(mutex_);
  for (const auto& e : entries_) {
    const auto& s = *e.service;
    const auto& a = s.attributes();
    if ((!q.type.empty() && s.type() != q.type) || (!q.room.empty() && a.room != q.room) ||
        (!q.device.empty() && a.device != q.device) ||
        (!q.carrier.empty() && a.carrier != q.carrier) || (q.available_only && !s.available())) {
      continue;
    }
    out.push_back(e.service);
  }
  return out;
}

}  // namespace icars::service
