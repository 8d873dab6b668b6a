#include "devices.h"

namespace tutorial {

namespace p = icars::planet;

void SimFan::set_speed(std::int32_t percent, const p::Current&) {
  // A declared exception travels to the caller as the generated icars::home::OutOfRange.
  if (percent < 0 || percent > 100)
    throw icars::home::OutOfRange("speed", percent, 0, 100, "a fan runs at 0-100%");
  {
    std::lock_guard lock(mutex_);
    if (speed_ == percent) return;
    speed_ = percent;
  }
  if (changed_) changed_(percent);
}

std::int32_t SimFan::speed(const p::Current&) { return current_speed(); }

std::int32_t SimFan::current_speed() const {
  std::lock_guard lock(mutex_);
  return speed_;
}

SimThermometer::SimThermometer(std::string device, std::string room, icars::Clock& clock,
                               double celsius, icars::Time period)
    : device_(std::move(device)),
      room_(std::move(room)),
      clock_(clock),
      period_(period),
      room_celsius_(celsius),
      published_celsius_(celsius) {
  next_reading_ = clock_.schedule_after(period_, [this] { read(); });
}

SimThermometer::~SimThermometer() {
  std::lock_guard lock(mutex_);
  clock_.cancel(next_reading_);
}

double SimThermometer::celsius(const p::Current&) {
  std::lock_guard lock(mutex_);
  return room_celsius_;
}

void SimThermometer::subscribe(TemperatureListenerPrx listener, const p::Current&) {
  events_.subscribe(listener);
}

void SimThermometer::unsubscribe(TemperatureListenerPrx listener, const p::Current&) {
  events_.unsubscribe(listener);
}

void SimThermometer::set_room_temperature(double celsius) {
  std::lock_guard lock(mutex_);
  room_celsius_ = celsius;
}

void SimThermometer::read() {
  TemperatureEvent reading;
  bool changed = false;
  {
    std::lock_guard lock(mutex_);
    next_reading_ = clock_.schedule_after(period_, [this] { read(); });
    changed = room_celsius_ != published_celsius_;
    published_celsius_ = room_celsius_;
    reading = TemperatureEvent{device_, room_, room_celsius_, clock_.now().count()};
  }
  if (changed) events_.publish(reading);  // never blocks; a slow subscriber loses readings
}

}  // namespace tutorial
