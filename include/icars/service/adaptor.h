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

// The service that wraps one capability of a registered device.
// Not to be confused with icars::planet::ObjectAdapter (include/icars/planet/servant.h),
// PLANET's table of servants by path.
class Adaptor : public Service {
 public:
  Adaptor(std::string type, const df::DeviceInfo& device, const df::CapabilityInfo& capability);
  ~Adaptor() override;

  const std::string& interface_id() const { return interface_id_; }
  const std::string& path() const { return path_; }
  const std::string& device_id() const { return device_; }
  // The connection the capability is bound to (events are accepted only over it); 0: unbound.
  std::uint64_t bound_connection() const { return bound_connection_.load(); }
  // The link it is bound to (null: unbound): where a relay forwards other servers' calls.
  std::shared_ptr<planet::Link> bound_link() const;

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
  // The registry removed this service for good (its device was unregistered or forgotten): it
  // releases what it registered in the device's name (a sensor's listener), so the device can
  // register again under the same id while behaviors still hold this object.
  void retire() { on_removed(); }
  // Reports the two-way calls made through proxy() from the next bind on (the server's record
  // of the commands it sent to devices); null: none.
  void set_call_observer(std::shared_ptr<planet::CallObserver> observer);
  // The observer for calls to this capability: the registry's (if any), and the adaptor's own
  // record of acknowledged commands (stateful capabilities). Its proxy uses it, and so does a
  // relay forwarding another server's calls (service::SharedDirectory), so that a command sent
  // from there is the acknowledged state an outage restores.
  std::shared_ptr<planet::CallObserver> call_observer();

 protected:
  // Hooks for subclasses, called with the adaptor's lock released.
  virtual void on_bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link) = 0;
  virtual void on_unbind() {}
  virtual void on_removed() {}
  void log_failure(planet::Communicator& communicator, std::string_view what,
                   std::exception_ptr error) const;
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
  std::weak_ptr<planet::Link> bound_link_;  // under observer_mutex_
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
// every bind, so events flow again after the device comes back. `OnEvent` is the listener's
// one-way operation (an IDL `oneway void on_x(Event e)`); the sensor's interface has
// `subscribe(Listener)`, whose proxy method subscribe_async the adaptor calls:
//
//   class ThermometerService final
//       : public SensorAdaptor<ThermometerPrx, TemperatureListener, TemperatureEvent,
//                              TemperatureListener::on_temperature> { ... };
template <class Prx, class ListenerInterface, class Event, const planet::OneWay<Event>& OnEvent>
class SensorAdaptor : public AdaptorOf<Prx> {
 public:
  using Base = AdaptorOf<Prx>;
  using Base::Base;
  ~SensorAdaptor() override { release_listener(); }

  // `fn(event)` runs for every event the sensor publishes. Returns an id for unsubscribe.
  std::uint64_t subscribe(std::function<void(const Event&)> fn) { return events_.add(std::move(fn)); }
  void unsubscribe(std::uint64_t id) { events_.remove(id); }
  std::uint64_t events_received() const { return received_.load(); }

 protected:
  void deliver(const Event& e, const planet::Current& current) {
    this->check_own_link(current);
    {
      std::lock_guard lock(last_mutex_);
      ++events_since_bind_;
      last_ = e;
    }
    ++received_;
    events_.notify(e);
  }
  // Delivers `e` (a reading taken when the sensor was bound) unless it says what the last event
  // said: a change missed while the device was away reaches listeners. The first reading, before
  // any event, is only the baseline (what a behavior reads when it starts), not an event. A
  // reading is dropped when an event arrived after it was asked for: the event is at least as
  // new (the sensor may have changed between the reading and the event reaching this server).
  void deliver_if_changed(const Event& e) {
    {
      std::lock_guard lock(last_mutex_);
      if (events_since_bind_ != 0) return;
      if (!last_) {
        last_ = e;
        return;
      }
      if (!changed_from(*last_, e)) return;
      last_ = e;
    }
    ++received_;
    events_.notify(e);
  }
  // Sensors whose current value can be read implement these: `reread` reads it and calls
  // deliver_if_changed; `changed_from` compares a reading with the last event.
  virtual void reread(const Prx&) {}
  virtual bool changed_from(const Event& /*last*/, const Event& /*reading*/) const { return true; }
  std::optional<Event> last_event() const {
    std::lock_guard lock(last_mutex_);
    return last_;
  }

  void on_bind(planet::Communicator& communicator, const std::shared_ptr<planet::Link>& link) override {
    Base::on_bind(communicator, link);
    if (!communicator_) {
      communicator_ = &communicator;
      auto servant = std::make_shared<planet::Servant>(std::string(ListenerInterface::type_id));
      servant->implement(OnEvent, [this](const Event& e, const planet::Current& c) { deliver(e, c); });
      communicator.adapter().add(listener_path(), servant);
      listener_ = servant.get();
    }
    {
      std::lock_guard lock(last_mutex_);
      events_since_bind_ = 0;
    }
    const auto ref = communicator.reference<ListenerInterface>(listener_path());
    this->proxy().subscribe_async(ref, [weak = this->weak_from_this(), &communicator](std::exception_ptr e) {
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
  std::string listener_path() const { return "/sf/listeners/" + this->id(); }
  void on_removed() override { release_listener(); }
  // Removes the listener servant if it is still this adaptor's (a successor may hold the path).
  void release_listener() {
    if (communicator_ && listener_) communicator_->adapter().remove(listener_path(), listener_);
    listener_ = nullptr;
  }

  planet::Communicator* communicator_ = nullptr;
  const planet::Servant* listener_ = nullptr;
  mutable std::mutex last_mutex_;
  std::optional<Event> last_;
  std::uint64_t events_since_bind_ = 0;  // events delivered since the reading was asked for
  Listeners<Event> events_;
  std::atomic<std::uint64_t> received_{0};
};

// A capability whose interface SF has no adaptor type for: still discoverable, by its
// interface id, and callable through a plain proxy.
class GenericAdaptor final : public AdaptorOf<planet::Proxy> {
 public:
  GenericAdaptor(const df::DeviceInfo& d, const df::CapabilityInfo& c)
      : AdaptorOf(c.interface_id, d, c) {}
};

}  // namespace icars::service
