// A plugin of `icars` built outside the ICARS tree: the behavior type DimLights, which sets
// every light of a room to a percentage through the home's light services (the LightControl
// adaptors of idl/home.idl's Light capability) and succeeds once all of them confirmed.
#include <fmt/format.h>

#include <memory>
#include <string>

#include "icars/behavior/behavior.h"
#include "icars/behavior/params.h"
#include "icars/home/adaptors.h"
#include "icars/server/plugin.h"

namespace {

namespace b = icars::behavior;

class DimLights final : public b::Behavior {
 public:
  explicit DimLights(const b::Params& p) : room_(p.string("room")), percent_(static_cast<int>(p.integer("percent"))) {}

 protected:
  void entry() override {
    pending_ = 0;
    for (const auto& service : services().find(of_type("LightControl").in_room(room_).available())) {
      auto light = std::static_pointer_cast<icars::home::LightService>(service);
      ++pending_;
      invoke(*light, fmt::format("set_intensity({})", percent_),
             [&](auto done) { light->proxy().set_intensity_async(percent_, done); },
             [this](std::exception_ptr error) {
               if (error) {
                 fail(call_error("set_intensity", error));
               } else if (--pending_ == 0) {
                 succeed();
               }
             });
    }
    if (pending_ == 0) fail("no available light in " + room_);
  }

 private:
  std::string room_;
  int percent_;
  int pending_ = 0;
};

}  // namespace

ICARS_PLUGIN(registrar) {
  registrar.behaviors.add<DimLights>(
      "DimLights", "sets every light of a room to a percentage and succeeds once all confirmed",
      {b::param("room", b::ParamType::string, std::nullopt, "the room").naming("room"),
       b::param("percent", b::ParamType::integer, "30", "the lights' intensity, 0-100")});
  registrar.behaviors.declare_events("DimLights", {});
}
