// Tutorial, step 6: the tutorial as a plugin of `icars` (docs/tutorial.md, docs/plugins.md).
//
//   icars run cooling.xml --world tutorial_house.xml --plugin tutorial.so
//
// One entry point teaches the ordinary `icars` program everything the tutorial adds: the
// CoolDown behavior type (for policies), the adaptors of fan.idl's capabilities (for the Service
// Framework) and the SmartFan device type (for the simulated house, which builds one for each
// <device type="SmartFan"> of the house file).
#include <fmt/format.h>

#include "cool_down.h"
#include "devices.h"
#include "icars/home/sim/sim_devices.h"
#include "icars/server/plugin.h"
#include "services.h"

namespace {

namespace home = icars::home;

// A SmartFan of the house file: a fan, and a thermometer reading the room temperature of the
// device's "temperatures" parameter (a TemperatureProfile, e.g. "12:00 22; 14:00 28.5").
std::shared_ptr<icars::device::Device> make_smart_fan(const icars::sim::DeviceSpec& spec, home::SimContext context) {
  const auto temperatures = spec.params.find("temperatures");
  if (temperatures == spec.params.end()) {
    throw std::invalid_argument("SmartFan " + spec.id + " needs a 'temperatures' parameter (e.g. \"12:00 22; 14:00 28\")");
  }
  tutorial::TemperatureProfile profile;
  try {
    profile = tutorial::TemperatureProfile::parse(temperatures->second);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument("SmartFan " + spec.id + ": " + e.what());
  }
  // What the fan does goes where the house reports its actuators' effects (icars run: the timeline).
  auto& clock = context.world.clock();
  auto fan = std::make_shared<tutorial::SimFan>(
      [id = spec.id, effects = context.effects, &clock](std::int32_t percent, std::uint32_t request_id) {
        if (effects) effects(home::DeviceEffect{clock.now(), id, "speed", fmt::format("{}%", percent), request_id});
      });
  auto thermometer = std::make_shared<tutorial::SimThermometer>(spec.id, spec.room, clock, std::move(profile));
  auto device = std::make_shared<icars::device::Device>(spec.id, spec.type, spec.room, spec.carrier);
  device->add("fan", fan).add("thermometer", thermometer);
  return device;
}

}  // namespace

ICARS_PLUGIN(registrar) {
  tutorial::register_tutorial_behaviors(registrar.behaviors);
  tutorial::add_adaptors(registrar.adaptors);
  registrar.extension<home::SimDeviceTypes>().add(
      "SmartFan", "a fan with a thermometer (tutorial): fan (tutorial::Fan), thermometer (tutorial::Thermometer); param temperatures",
      make_smart_fan);
}
