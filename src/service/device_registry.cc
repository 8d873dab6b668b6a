#include "icars/service/device_registry.h"

#include <spdlog/spdlog.h>

#include "icars/device/device_manager.h"

namespace icars::service {

std::shared_ptr<Adaptor> AdaptorFactory::make(const df::DeviceInfo& device,
                                              const df::CapabilityInfo& capability) const {
  if (auto it = makers_.find(capability.interface_id); it != makers_.end()) {
    return it->second(device, capability);
  }
  return std::make_shared<GenericAdaptor>(device, capability);
}

AdaptorFactory AdaptorFactory::house() {
  AdaptorFactory f;
  f.add<home::TVControl, TVControlService>();
  f.add<home::Light, LightService>();
  f.add<home::Speaker, SpeakerService>();
  f.add<home::Microphone, SoundSensor>();
  f.add<home::SpeechRecognizer, SpeechRecognizerService>();
  f.add<home::Wheels, NavigationService>();
  f.add<home::MotionSensor, MotionSensorService>();
  f.add<home::OccupancySensor, OccupancyService>();
  f.add<home::Camera, CameraService>();
  f.add<home::FaceRecognizer, FaceRecognizerService>();
  f.add<home::Clock, ClockService>();
  f.add<home::Simulation, SimulationService>();
  return f;
}

DeviceRegistry::DeviceRegistry(planet::Communicator& communicator, ServiceContainer& container,
                               AdaptorFactory factory)
    : communicator_(communicator), container_(container), factory_(std::move(factory)) {
  listener_ = communicator_.connections().add_listener([this](const planet::ConnectionEvent& e) {
    if (e.kind == planet::LinkEventKind::disconnected && e.connection) {
      on_disconnected(e.connection->id());
    }
  });
}

DeviceRegistry::~DeviceRegistry() { communicator_.connections().remove_listener(listener_); }

void DeviceRegistry::register_device(const df::DeviceInfo& device, const planet::Current& current) {
  if (device.id.empty()) throw df::RegistrationRefused(device.id, "the device has no id");
  if (device.capabilities.empty()) {
    throw df::RegistrationRefused(device.id, "the device declares no capabilities");
  }
  std::vector<std::shared_ptr<Adaptor>> services;
  {
    std::lock_guard lock(mutex_);
    auto it = devices_.find(device.id);
    if (it != devices_.end() && it->second.connection_id != current.connection->id() &&
        it->second.connection_id != 0) {
      // The same device over a new connection: its old connection may not have closed yet
      // (a manager restarted faster than the heartbeat timeout); the newest registration wins.
      communicator_.log().info("device {} moved to {}", device.id, current.connection->describe());
    }
    if (it == devices_.end()) {
      Registered r;
      r.info = device;
      for (const auto& c : device.capabilities) {
        r.services.push_back(factory_.make(device, c));
      }
      it = devices_.emplace(device.id, std::move(r)).first;
      for (const auto& s : it->second.services) container_.add(s);
      communicator_.log().info("device {} ({}) registered: {} services", device.id, device.type,
                               it->second.services.size());
    } else {
      communicator_.log().info("device {} registered again", device.id);
    }
    it->second.connection_id = current.connection->id();
    services = it->second.services;
    for (const auto& s : services) s->set_call_observer(call_observer_);
  }
  for (const auto& s : services) s->bind(communicator_, current.connection);
}

void DeviceRegistry::unregister_device(const std::string& id, const planet::Current&) {
  std::vector<std::shared_ptr<Adaptor>> services;
  {
    std::lock_guard lock(mutex_);
    auto it = devices_.find(id);
    if (it == devices_.end()) return;
    services = std::move(it->second.services);
    devices_.erase(it);
  }
  for (const auto& s : services) {
    s->unbind();
    container_.remove(s->id());
  }
}

std::vector<std::string> DeviceRegistry::devices(const planet::Current&) {
  std::lock_guard lock(mutex_);
  std::vector<std::string> out;
  for (const auto& [id, r] : devices_) out.push_back(id);
  return out;
}

std::size_t DeviceRegistry::connected_devices() const {
  std::lock_guard lock(mutex_);
  std::size_t n = 0;
  for (const auto& [id, r] : devices_) n += r.connection_id != 0;
  return n;
}

void DeviceRegistry::set_call_observer(std::shared_ptr<planet::CallObserver> observer) {
  std::lock_guard lock(mutex_);
  call_observer_ = std::move(observer);
}

void DeviceRegistry::on_disconnected(std::uint64_t connection_id) {
  std::vector<std::shared_ptr<Adaptor>> services;
  {
    std::lock_guard lock(mutex_);
    for (auto& [id, r] : devices_) {
      if (r.connection_id != connection_id) continue;
      r.connection_id = 0;
      communicator_.log().info("device {} disconnected; its services are unavailable", id);
      services.insert(services.end(), r.services.begin(), r.services.end());
    }
  }
  for (const auto& s : services) s->unbind();
}

}  // namespace icars::service
