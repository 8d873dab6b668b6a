// Adaptor services: the Service object SF creates for each capability a device registers, by
// wrapping the capability's remote reference (ICARS paper 4.3.1, Fig. 10a). Sensor adaptors
// also subscribe to their capability's events and hand them to in-process listeners.
//
// An adaptor is bound while its device is registered over a live connection; calls through
// `proxy()` while it is unbound fail with planet::Error(disconnected). Event callbacks run on
// the server communicator's io thread and must not block.
#pragma once

#include <atomic>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "device.planet.h"
#include "home.planet.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "icars/service/service.h"

namespace icars::service {

// The state a device keeps that commands set, as typed named values ({"on": true,
// "channel": 5, "volume": 25}); empty for a capability that keeps none.
using DeviceState = planet::Properties;

// One value that differs between what the mediator last had acknowledged and what a device
// reports after it registered again.
struct StateDifference {
  std::string name;
  planet::Value wanted;  // read from the device after the last acknowledged command
  planet::Value found;   // read from the device when it came back
};

// What happened to a stateful capability when its device registered again.
struct Restoration {
  std::vector<StateDifference> differences;  // empty: the device kept its state
  bool reapplied = false;                    // the wanted state was sent again
  std::exception_ptr error;                  // reading or re-applying failed
};

// "channel 5 -> 1, on true -> false": the differences as a person reads them.
std::string describe(const std::vector<StateDifference>& differences);
std::string describe_value(const planet::Value& value);

class Adaptor : public Service {
 public:
  Adaptor(std::string type, const df::DeviceInfo& device, const df::CapabilityInfo& capability);
  ~Adaptor() override;

  const std::string& interface_id() const { return interface_id_; }
  const std::string& path() const { return path_; }
  const std::string& device_id() const { return device_; }
  // The connection the capability is bound to (events are accepted only over it); 0: unbound.
  std::uint64_t bound_connection() const { return bound_connection_.load(); }

  // --- Device state across outages ---
  // True when the capability keeps state that commands set (a TV, a light, a speaker).
  virtual bool keeps_state() const { return false; }
  // The state read from the device after the last acknowledged command; empty before one.
  DeviceState acknowledged_state() const;
  // After the device registered again: reads its state, compares it with the acknowledged one
  // and, when they differ and `reapply`, sends the acknowledged state again. `done` runs once
  // (on the io thread), with nothing to report (no differences) when no command was ever
  // acknowledged.
  void restore(bool reapply, std::function<void(Restoration)> done);

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
  // The observer for this adaptor's proxy: the registry's (if any), and the adaptor's own
  // record of acknowledged commands (stateful capabilities).
  std::shared_ptr<planet::CallObserver> call_observer();
  // Throws planet::Error(denied) unless `current` came over the link the capability is bound to:
  // only a device's own device manager delivers its events.
  void check_own_link(const planet::Current& current) const;

  // Stateful capabilities implement these three (called on the io thread, never blocking).
  // An operation that changes the state the device keeps.
  virtual bool is_command(std::string_view) const { return false; }
  virtual void read_state(std::function<void(std::exception_ptr, DeviceState)> done) {
    done(nullptr, {});
  }
  virtual void apply_state(const DeviceState&, std::function<void(std::exception_ptr)> done) {
    done(nullptr);
  }

 private:
  class CommandTracker;
  void command_acknowledged();

  std::string interface_id_;
  std::string path_;
  std::string device_;
  std::atomic<std::uint64_t> bound_connection_{0};
  mutable std::mutex observer_mutex_;
  std::shared_ptr<planet::CallObserver> call_observer_;
  DeviceState acknowledged_;
  std::uint64_t reads_started_ = 0;  // a state read answers only if no later one started
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
  void deliver(const Event& e, const planet::Current& current) {
    this->check_own_link(current);
    ++received_;
    remember(e);
    events_.notify(e);
  }
  // Delivers `e` (a reading taken when the sensor was bound) unless it says what the last event
  // said: a change missed while the device was away reaches listeners. The first reading, before
  // any event, is only the baseline (what a behavior reads when it starts), not an event.
  void deliver_if_changed(const Event& e) {
    if (!last_event()) {
      remember(e);
      return;
    }
    if (!changed(e)) return;
    ++received_;
    remember(e);
    events_.notify(e);
  }
  // Sensors whose current value can be read implement these: `reread` reads it and calls
  // deliver_if_changed; `changed` compares a reading with the last event.
  virtual void reread(const Prx&) {}
  virtual bool changed(const Event&) const { return true; }
  std::optional<Event> last_event() const {
    std::lock_guard lock(last_mutex_);
    return last_;
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
      if (!self) return;
      if (e) {
        self->log_failure(communicator, "could not subscribe to its sensor", e);
      } else {
        self->reread(self->proxy());  // the baseline, or what changed while it was away
      }
    });
  }

 private:
  void remember(const Event& e) {
    std::lock_guard lock(last_mutex_);
    last_ = e;
  }

  std::string listener_path() const { return "/sf/listeners/" + this->id(); }

  planet::Communicator* communicator_ = nullptr;
  mutable std::mutex last_mutex_;
  std::optional<Event> last_;
  Listeners<Event> events_;
  std::atomic<std::uint64_t> received_{0};
};

// --- The adaptors of the house's capabilities (idl/home.idl) ----------------------------------

// The stateful house adaptors remember the TV's, light's and speaker's state after every
// acknowledged command and restore it when the device comes back (Adaptor::restore).
class TVControlService final : public AdaptorOf<home::TVControlPrx> {
 public:
  TVControlService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("TVControl", d, c) {}
  bool keeps_state() const override { return true; }

 protected:
  bool is_command(std::string_view method) const override;
  void read_state(std::function<void(std::exception_ptr, DeviceState)> done) override;
  void apply_state(const DeviceState& wanted, std::function<void(std::exception_ptr)> done) override;
};

class LightService final : public AdaptorOf<home::LightPrx> {
 public:
  LightService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("LightControl", d, c) {}
  bool keeps_state() const override { return true; }

 protected:
  bool is_command(std::string_view method) const override;
  void read_state(std::function<void(std::exception_ptr, DeviceState)> done) override;
  void apply_state(const DeviceState& wanted, std::function<void(std::exception_ptr)> done) override;
};

class SpeakerService final : public AdaptorOf<home::SpeakerPrx> {
 public:
  SpeakerService(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf("AudioControl", d, c) {}
  bool keeps_state() const override { return true; }

 protected:
  // What it plays and how loud; what it last said is not state to restore.
  bool is_command(std::string_view method) const override;
  void read_state(std::function<void(std::exception_ptr, DeviceState)> done) override;
  void apply_state(const DeviceState& wanted, std::function<void(std::exception_ptr)> done) override;
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
    s.implement(home::SoundListener::on_sound, [this](const home::SoundEvent& e, const planet::Current& c) { deliver(e, c); });
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
                [this](const home::PositionEvent& e, const planet::Current& c) { deliver(e, c); });
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
    s.implement(home::MotionListener::on_motion, [this](const home::MotionEvent& e, const planet::Current& c) { deliver(e, c); });
  }
  void reread(const home::MotionSensorPrx& sensor) override;
  bool changed(const home::MotionEvent& e) const override {
    const auto last = last_event();
    return !last || last->motion != e.motion;
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
                [this](const home::OccupancyEvent& e, const planet::Current& c) { deliver(e, c); });
  }
  void reread(const home::OccupancySensorPrx& sensor) override;
  bool changed(const home::OccupancyEvent& e) const override {
    const auto last = last_event();
    return !last || last->occupied != e.occupied;
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
