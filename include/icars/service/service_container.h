// The service container: every service of the house, discoverable by type and attributes.
#pragma once

#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "icars/planet/event.h"
#include "icars/service/service.h"

namespace icars::service {

// What discovery matches; empty fields match anything.
struct ServiceQuery {
  std::string type;
  std::string room;
  std::string device;
  std::string carrier;
  bool available_only = false;

  // ServiceQuery::of_type("LightControl").in_room("bedroom").available()
  static ServiceQuery of_type(std::string type) {
    ServiceQuery q;
    q.type = std::move(type);
    return q;
  }
  ServiceQuery& in_room(std::string r) { room = std::move(r); return *this; }
  ServiceQuery& on_device(std::string d) { device = std::move(d); return *this; }
  ServiceQuery& carried_by(std::string robot) { carrier = std::move(robot); return *this; }
  ServiceQuery& available() { available_only = true; return *this; }
};

enum class ServiceChange { added, removed, available, unavailable };

class ServiceContainer {
 public:
  ServiceContainer() = default;
  ServiceContainer(const ServiceContainer&) = delete;
  ServiceContainer& operator=(const ServiceContainer&) = delete;

  // Adds a service; throws std::invalid_argument when its id is taken.
  void add(std::shared_ptr<Service> service);
  bool remove(const std::string& id);
  std::shared_ptr<Service> get(const std::string& id) const;

  std::vector<std::shared_ptr<Service>> find(const ServiceQuery& query) const;
  std::vector<std::shared_ptr<Service>> all() const { return find({}); }
  // The first match of `query` as a T (a service class), or null.
  template <class T>
  std::shared_ptr<T> find_first(const ServiceQuery& query) const {
    for (auto& s : find(query)) {
      if (auto t = std::dynamic_pointer_cast<T>(s)) return t;
    }
    return nullptr;
  }

  // `fn(service, change)` runs when a service is added, removed, or changes availability.
  std::uint64_t watch(std::function<void(const std::shared_ptr<Service>&, const ServiceChange&)> fn) {
    return watchers_.add(std::move(fn));
  }
  void remove_watcher(std::uint64_t id) { watchers_.remove(id); }

  // Events about devices (DeviceLost, DeviceBack, DeviceRestored, DeviceForgotten: see
  // DeviceRegistry), for behaviors and tasks that react to a device's outages. `fn` runs on the
  // server's io thread and must not block.
  std::uint64_t watch_devices(std::function<void(const planet::Event&)> fn) {
    return device_watchers_.add(std::move(fn));
  }
  void remove_device_watcher(std::uint64_t id) { device_watchers_.remove(id); }
  void publish_device_event(const planet::Event& event) const { device_watchers_.notify(event); }

 private:
  struct Entry {
    std::shared_ptr<Service> service;
    std::uint64_t watch_id;
  };
  mutable std::mutex mutex_;
  std::vector<Entry> entries_;
  Listeners<std::shared_ptr<Service>, ServiceChange> watchers_;
  Listeners<planet::Event> device_watchers_;
};

}  // namespace icars::service
