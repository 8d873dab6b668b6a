#include "cool_down.h"

#include <fmt/format.h>

namespace tutorial {

namespace b = icars::behavior;

CoolDown::CoolDown(const b::Params& params)
    : hot_(params.number("hot")),
      speed_(static_cast<int>(params.integer("speed"))),
      room_(params.string("room")) {}

void CoolDown::entry() {
  auto in_room = [this](std::string type) {
    auto query = of_type(std::move(type));
    if (!room_.empty()) query.in_room(room_);
    return query;
  };
  // A missing service fails the behavior (and so its task) with "no available Fan service".
  fan_ = require<FanService>(in_room("Fan"));
  thermometer_ = require<ThermometerService>(in_room("Thermometer"));
  listen(thermometer_);  // TemperatureEvents reach handle_event until exit
  cooling_.reset();
  // The thermometer publishes only changes: ask for the temperature now.
  invoke(
      *thermometer_, "celsius", [&](auto done) { thermometer_->proxy().celsius_async(done); },
      [this](std::exception_ptr error, double celsius = 0) {
        if (error) {
          fail(call_error("celsius", error));
          return;
        }
        react(celsius);
      });
}

void CoolDown::handle_event(const b::Event& event) {
  if (event.type() == "TemperatureEvent") react(event.get<double>("celsius"));
}

void CoolDown::react(double celsius) {
  const bool too_hot = celsius > hot_;
  if (cooling_ == too_hot) {
    note(fmt::format("{:.1f} C: the fan stays {}", celsius, too_hot ? "on" : "off"));
    return;
  }
  cooling_ = too_hot;
  const int speed = too_hot ? speed_ : 0;
  note(fmt::format("{:.1f} C: {}", celsius,
                   too_hot ? fmt::format("too hot, fan to {}%", speed) : "comfortable, fan off"));
  invoke(
      *fan_, fmt::format("set_speed({})", speed),
      [&](auto done) { fan_->proxy().set_speed_async(speed, done); },
      [this, too_hot, celsius](std::exception_ptr error) {
        if (error) {
          fail(call_error("set_speed", error));
          return;
        }
        b::Event out(too_hot ? "TooHot" : "Comfortable");
        out.set("celsius", celsius);
        out.set("room", fan_->attributes().room);
        propagate(std::move(out));
      });
}

void register_tutorial_behaviors(b::BehaviorRegistry& registry) {
  using b::param;
  using T = b::ParamType;
  registry.add<CoolDown>(
      "CoolDown", "runs a fan while the room is too hot; propagates TooHot and Comfortable",
      {param("hot", T::number, "26", "degrees Celsius above which the fan runs"),
       param("speed", T::integer, "100", "the fan's speed while it runs, in percent"),
       param("room", T::string, "", "the fan and thermometer of this room (default: any)").naming("room")});
  registry.declare_events("CoolDown", {{"TooHot", {"celsius", "room"}}, {"Comfortable", {"celsius", "room"}}});
}

}  // namespace tutorial
