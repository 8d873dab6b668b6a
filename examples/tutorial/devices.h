// Tutorial, step 2 (device provider): servants that implement the Fan and Thermometer
// interfaces of fan.idl. A device::Device groups them as the capabilities of one device and a
// device::DeviceManager serves them and registers them with the mediating server (main.cc).
//
// Both are simulated: the fan remembers its speed, the thermometer reads a room temperature
// that main.cc sets. A real device would talk to hardware in the same places.
#pragma once

#include <cstdint>
#include <functional>
#include <mutex>
#include <string>

#include "fan.planet.h"
#include "icars/clock/clock.h"
#include "icars/planet/publisher.h"

namespace tutorial {

// Servant methods run on the device manager's communicator thread: they must not block.
class SimFan final : public FanServant {
 public:
  // `changed(percent)` runs whenever the speed changes (main.cc puts it in the timeline).
  explicit SimFan(std::function<void(std::int32_t)> changed = {}) : changed_(std::move(changed)) {}

  void set_speed(std::int32_t percent, const icars::planet::Current& current) override;
  std::int32_t speed(const icars::planet::Current& current) override;

  std::int32_t current_speed() const;  // for checks from outside

 private:
  std::function<void(std::int32_t)> changed_;
  mutable std::mutex mutex_;
  std::int32_t speed_ = 0;
};

// Reads the room's temperature every `period` of simulated time and publishes a
// TemperatureEvent to its subscribers when the reading changed.
class SimThermometer final : public ThermometerServant {
 public:
  SimThermometer(std::string device, std::string room, icars::Clock& clock, double celsius,
                 icars::Time period = std::chrono::minutes(1));
  ~SimThermometer() override;  // stops reading; the clock must not be advancing meanwhile

  double celsius(const icars::planet::Current& current) override;
  void subscribe(TemperatureListenerPrx listener, const icars::planet::Current& current) override;
  void unsubscribe(TemperatureListenerPrx listener, const icars::planet::Current& current) override;

  // The simulated room: what the next reading will measure.
  void set_room_temperature(double celsius);
  std::size_t subscribers() const { return events_.size(); }

 private:
  void read();  // a clock event, on the thread advancing the clock

  std::string device_;
  std::string room_;
  icars::Clock& clock_;
  icars::Time period_;
  icars::planet::Publisher<TemperatureEvent> events_{TemperatureListener::on_temperature};
  mutable std::mutex mutex_;
  double room_celsius_;
  double published_celsius_;
  std::uint64_t next_reading_ = 0;
};

}  // namespace tutorial
