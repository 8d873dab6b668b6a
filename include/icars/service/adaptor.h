// Adaptor services: the Service object SF creates for each capability a device registers, by
// wrapping the capability's remote reference (ICARS paper 4.3.1, Fig. 10a). Sensor adaptors
// also subscribe to their capability's events and hand them to in-process listeners.
//
// An adaptor is bound while its device is registered over a live connection; calls through
// `proxy()` while it is unbound fail with planet::Error(disconnected). Event callbacks run on
// the server communicator's io thread and must not block.
#pragma once

#include <memory>
#include <mutex>
#include <string>

#include "device.planet.h"
#include "home.planet.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "icars/service/service.h"

namespace icars::service {

class Adaptor : public Service {
 public:
  Adaptor(std::string type, const df::DeviceInfo& device, const df::CapabilityInfo& capability);
  ~Adaptor() override;

  const std::string& interface_id() const { return interface_id_; }
  const std::string& path() const { return path_; }

  // The capability is (again) reachable over `link`: rebinds, resubscribes, becomes available.
  // Called by the device registry on the server's io thread.
  void bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link);
  // The device's link is gone: the service becomes unavailable until the next bind.
  void unbind();
  // Reports the two-way calls made through proxy() from the next bind on (the server's record
  // of the commands it sent to devices); null: none.
  void set_call_observer(std::shared_ptr<planet::CallObserver> observer);

 protected:
  // Hooks for subclasses, called with the adaptor's lock released.
  virtual void on_bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link) = 0;
  virtual void on_unbind() {}
  void log_failure(planet::Communicator& communicator, std::string_view what,
                   std::exception_ptr error) const;
  std::shared_ptr<planet::CallObserver> call_observer() const;

 private:
  std::string interface_id_;
  std::string path_;
  mutable std::mutex observer_mutex_;
  std::shared_ptr<planet::CallObserver> call_observer_;
};

// An adaptor whose capability is the IDL interface of stub `Prx`.
template <class Prx>
class AdaptorOf : public Adaptor {
 public:
  using Adaptor::Adaptor;
  Prx proxy() const {
    std::lock_guard lock(mutex_);
    return proxy_;
  }

 protected:
  void on_bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link) override {
    auto observer = call_observer();
    std::lock_guard lock(mutex_);
    proxy_ = Prx(communicator, link, path());
    proxy_.set_observer(std::move(observer));
  }

 private:
  mutable std::mutex mutex_;
  Prx proxy_;
};

// A sensor adaptor: serves a listener object on the server and subscribes it to the sensor on
// every bind, so events flow again after the device comes back.
template <class Prx, class ListenerInterface, class Event>
class SensorAdaptor : public AdaptorOf<Prx> {
 public:
  using Base = AdaptorOf<Prx>;
  using Base::Base;
  ~SensorAdaptor() override {
    if (communicator_) communicator_->adapter().remove(listener_path());
  }

  // `fn(event)` runs for every event the sensor publishes. Returns an id for unsubscribe.
  std::uint64_t subscribe(std::function<void(const Event&)> fn) { return events_.add(std::move(fn)); }
  void unsubscribe(std::uint64_t id) { events_.remove(id); }
  std::uint64_t events_received() const { return received_.load(); }

 protected:
  // The sensor's subscribe operation, called asynchronously with the listener reference.
  virtual void subscribe_listener(const Prx& sensor, const planet::Ref<ListenerInterface>& listener,
                                  std::function<void(std::exception_ptr)> done) = 0;
  // Registers the listener servant's one operation.
  virtual void implement_listener(planet::Servant& servant) = 0;
  void deliver(const Event& e) {
    ++received_;
    events_.notify(e);
  }

  void on_bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link) override {
    Base::on_bind(communicator, link);
    if (!communicator_) {
      communicator_ = &communicator;
      auto servant = std::make_shared<planet::Servant>(std::string(ListenerInterface::type_id));
      implement_listener(*servant);
      communicator.adapter().add(listener_path(), servant);
    }
    const auto ref = communicator.reference<ListenerInterface>(listener_path());
    subscribe_listener(this->proxy(), ref, [weak = this->weak_from_this(), &communicator](
                                               std::exception_ptr e) {
      auto self = std::static_pointer_cast<SensorAdaptor>(weak.lock());
      if (e && self) self->log_failure(communicator, "could not subscribe to its sensor", e);
    });
  }

 private:
  std::string listener_path() const { return "/sf/listeners/" + this->id(); }

  planet::Communicator* communicator_ = nullptr;
  Listeners<Event> events_;
  std::atomic<std::uint64_t> received_{0};
};

// --- The adaptors of the house's capabilities (idl/home.idl) ----------------------------------

class TVControlService final : public AdaptorOf<home::TVControlPrx> {
 public:
  TVControlService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("TVControl", d, c) {}
};

class LightService final : public AdaptorOf<home::LightPrx> {
 public:
  LightService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("LightControl", d, c) {}
};

class SpeakerService final : public AdaptorOf<home::SpeakerPrx> {
 public:
  SpeakerService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("AudioControl", d, c) {}
};

class SpeechRecognizerService final : public AdaptorOf<home::SpeechRecognizerPrx> {
 public:
  SpeechRecognizerService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("SpeechRecognizer", d, c) {}
};

class CameraService final : public AdaptorOf<home::CameraPrx> {
 public:
  CameraService(const df::DeviceInfo& d, const df::CapabilityInfo& c) : AdaptorOf("Camera", d, c) {}
};

class FaceRecognizerService final : public AdaptorOf<home::FaceRecognizerPrx> {
 public:
  FaceRecognizerService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("FaceRecognizer", d, c) {}
};

class ClockService final : public AdaptorOf<home::ClockPrx> {
 public:
  ClockService(const df::DeviceInfo& d, const df::CapabilityInfo& c) : AdaptorOf("Clock", d, c) {}
};

class SimulationService final : public AdaptorOf<home::SimulationPrx> {
 public:
  SimulationService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("Simulation", d, c) {}
};

class SoundSensor final : public SensorAdaptor<home::MicrophonePrx, home::SoundListener, home::SoundEvent> {
 public:
  SoundSensor(const df::DeviceInfo& d, const df::CapabilityInfo& c) : SensorAdaptor("SoundSensor", d, c) {}

 protected:
  void subscribe_listener(const home::MicrophonePrx& mic, const planet::Ref<home::SoundListener>& l,
                          std::function<void(std::exception_ptr)> done) override {
    mic.subscribe_async(l, std::move(done));
  }
  void implement_listener(planet::Servant& s) override {
    s.implement(home::SoundListener::on_sound, [this](const home::SoundEvent& e) { deliver(e); });
  }
};

// The robot's wheels as a navigation service: go_to/go_to_waypoint/stop and position events.
class NavigationService final
    : public SensorAdaptor<home::WheelsPrx, home::PositionListener, home::PositionEvent> {
 public:
  NavigationService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : SensorAdaptor("Navigation", d, c) {}

 protected:
  void subscribe_listener(const home::WheelsPrx& wheels, const planet::Ref<home::PositionListener>& l,
                          std::function<void(std::exception_ptr)> done) override {
    wheels.subscribe_async(l, std::move(done));
  }
  void implement_listener(planet::Servant& s) override {
    s.implement(home::PositionListener::on_position,
                [this](const home::PositionEvent& e) { deliver(e); });
  }
};

class MotionSensorService final
    : public SensorAdaptor<home::MotionSensorPrx, home::MotionListener, home::MotionEvent> {
 public:
  MotionSensorService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : SensorAdaptor("MotionSensor", d, c) {}

 protected:
  void subscribe_listener(const home::MotionSensorPrx& sensor, const planet::Ref<home::MotionListener>& l,
                          std::function<void(std::exception_ptr)> done) override {
    sensor.subscribe_async(l, std::move(done));
  }
  void implement_listener(planet::Servant& s) override {
    s.implement(home::MotionListener::on_motion, [this](const home::MotionEvent& e) { deliver(e); });
  }
};

class OccupancyService final
    : public SensorAdaptor<home::OccupancySensorPrx, home::OccupancyListener, home::OccupancyEvent> {
 public:
  OccupancyService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : SensorAdaptor("OccupancySensor", d, c) {}

 protected:
  void subscribe_listener(const home::OccupancySensorPrx& sensor,
                          const planet::Ref<home::OccupancyListener>& l,
                          std::function<void(std::exception_ptr)> done) override {
    sensor.subscribe_async(l, std::move(done));
  }
  void implement_listener(planet::Servant& s) override {
    s.implement(home::OccupancyListener::on_occupancy,
                [this](const home::OccupancyEvent& e) { deliver(e); });
  }
};

// A capability whose interface SF has no adaptor type for: still discoverable, by its
// interface id, and callable through a plain proxy.
class GenericAdaptor final : public AdaptorOf<planet::Proxy> {
 public:
  GenericAdaptor(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf(c.interface_id, d, c) {}
};

}  // namespace icars::service
