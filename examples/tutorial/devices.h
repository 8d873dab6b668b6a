// Tutorial, step 2 (device provider): servants that implement the Fan and Thermometer
// interfaces of fan.idl. A device::Device groups them as the capabilities of one device, a
// SmartFan, and a device manager serves it and registers it with the mediating server. In this
// tutorial the device manager is the simulated house of `icars run`, which builds a SmartFan for
// each <device type="SmartFan"> of the house file (plugin.cc teaches it the type).
//
// Both are simulated: the fan remembers its speed, the thermometer reads the room temperature
// of a daily profile. A real device would talk to hardware in the same places.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "fan.planet.h"
#include "icars/clock/clock.h"
#include "icars/planet/publisher.h"

namespace tutorial {

// Servant methods run on the device manager's communicator thread: they must not block.
class SimFan final : public FanServant {
 public:
  // `changed(percent, request_id)` runs whenever a call changed the speed (`icars run` puts it
  // in the timeline as an effect).
  using Changed = std::function<void(std::int32_t percent, std::uint32_t request_id)>;
  explicit SimFan(Changed changed = {}) : changed_(std::move(changed)) {}

  void set_speed(std::int32_t percent, const icars::planet::Current& current) override;
  std::int32_t speed(const icars::planet::Current& current) override;

 private:
  Changed changed_;
  mutable std::mutex mutex_;
  std::int32_t speed_ = 0;
};

// A room's temperature over the day: steps at times of day, repeating daily. Written in a
// house file as "12:00 22; 14:00 28.5; 18:00 23.5": from noon 22 C, from 14:00 28.5 C, ...;
// before the first step of a day the last step of the day before holds.
class TemperatureProfile {
 public:
  // Throws std::invalid_argument naming what it could not read.
  static TemperatureProfile parse(const std::string& text);
  double at(icars::Time time) const;

 private:
  std::map<icars::Time, double> steps_;  // time of day -> celsius
};

// Reads the room's temperature every `period` of simulated time and publishes a
// TemperatureEvent to its subscribers when the reading changed.
class SimThermometer final : public ThermometerServant {
 public:
  SimThermometer(std::string device, std::string room, icars::Clock& clock, TemperatureProfile profile,
                 icars::Time period = std::chrono::minutes(1));
  ~SimThermometer() override;  // stops reading; the clock must not be advancing meanwhile

  double celsius(const icars::planet::Current& current) override;
  void subscribe(TemperatureListenerPrx listener, const icars::planet::Current& current) override;
  void unsubscribe(TemperatureListenerPrx listener, const icars::planet::Current& current) override;

 private:
  void read();  // a clock event, on the thread advancing the clock

  std::string device_;
  std::string room_;
  icars::Clock& clock_;
  TemperatureProfile profile_;
  icars::Time period_;
  icars::planet::Publisher<TemperatureEvent> events_{TemperatureListener::on_temperature};
  mutable std::mutex mutex_;
  double published_celsius_;
  std::uint64_t next_reading_ = 0;
};

}  // namespace tutorial
