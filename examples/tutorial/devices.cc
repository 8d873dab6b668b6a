#include "devices.h"

#include <sstream>
#include <stdexcept>

namespace tutorial {

namespace p = icars::planet;
using namespace std::chrono_literals;

void SimFan::set_speed(std::int32_t percent, const p::Current& current) {
  // A declared exception travels to the caller as the generated icars::home::OutOfRange.
  if (percent < 0 || percent > 100)
    throw icars::home::OutOfRange("speed", percent, 0, 100, "a fan runs at 0-100%");
  {
    std::lock_guard lock(mutex_);
    if (speed_ == percent) return;
    speed_ = percent;
  }
  if (changed_) changed_(percent, current.request_id);
}

std::int32_t SimFan::speed(const p::Current&) {
  std::lock_guard lock(mutex_);
  return speed_;
}

TemperatureProfile TemperatureProfile::parse(const std::string& text) {
  TemperatureProfile profile;
  std::istringstream steps(text);
  std::string step;
  while (std::getline(steps, step, ';')) {
    if (step.find_first_not_of(" \t\n") == std::string::npos) continue;
    std::istringstream in(step);
    int hours = -1, minutes = -1;
    char colon = 0;
    double celsius = 0;
    std::string rest;
    if (!(in >> hours >> colon >> minutes >> celsius) || colon != ':' || (in >> rest) || hours < 0 || hours > 23 ||
        minutes < 0 || minutes > 59) {
      throw std::invalid_argument("temperature step '" + step + "' is not 'HH:MM CELSIUS'");
    }
    profile.steps_[std::chrono::hours(hours) + std::chrono::minutes(minutes)] = celsius;
  }
  if (profile.steps_.empty()) throw std::invalid_argument("the temperature profile has no step");
  return profile;
}

double TemperatureProfile::at(icars::Time time) const {
  const icars::Time of_day = time % icars::Time(24h);
  auto it = steps_.upper_bound(of_day);
  if (it == steps_.begin()) return steps_.rbegin()->second;  // still yesterday's last step
  return std::prev(it)->second;
}

SimThermometer::SimThermometer(std::string device, std::string room, icars::Clock& clock,
                               TemperatureProfile profile, icars::Time period)
    : device_(std::move(device)),
      room_(std::move(room)),
      clock_(clock),
      profile_(std::move(profile)),
      period_(period),
      published_celsius_(profile_.at(clock.now())) {
  next_reading_ = clock_.schedule_after(period_, [this] { read(); });
}

SimThermometer::~SimThermometer() {
  std::lock_guard lock(mutex_);
  clock_.cancel(next_reading_);
}

double SimThermometer::celsius(const p::Current&) { return profile_.at(clock_.now()); }

void SimThermometer::subscribe(TemperatureListenerPrx listener, const p::Current&) {
  events_.subscribe(listener);
}

void SimThermometer::unsubscribe(TemperatureListenerPrx listener, const p::Current&) {
  events_.unsubscribe(listener);
}

void SimThermometer::read() {
  TemperatureEvent reading;
  bool changed = false;
  {
    std::lock_guard lock(mutex_);
    next_reading_ = clock_.schedule_after(period_, [this] { read(); });
    const double celsius = profile_.at(clock_.now());
    changed = celsius != published_celsius_;
    published_celsius_ = celsius;
    reading = TemperatureEvent{device_, room_, celsius, clock_.now().count()};
  }
  if (changed) events_.publish(reading);  // never blocks; a slow subscriber loses readings
}

}  // namespace tutorial
