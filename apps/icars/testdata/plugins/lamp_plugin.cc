// A working plugin for the plugin tests: a behavior type, an adaptor for an interface the home
// does not have, and a composer that counts the services it was shown.
#include "icars/behavior/behavior.h"
#include "icars/behavior/params.h"
#include "icars/server/plugin.h"
#include "icars/service/adaptor.h"

namespace {

// Emits `event` once at entry and succeeds.
class Blink final : public icars::behavior::Behavior {
 public:
  explicit Blink(const icars::behavior::Params& p) : event_(p.string("event")) {}

 protected:
  void entry() override {
    propagate(icars::behavior::Event(event_));
    succeed();
  }

 private:
  std::string event_;
};

class LampComposer final : public icars::service::Composer {
 public:
  explicit LampComposer(icars::service::ServiceContainer&) {}
};

}  // namespace

ICARS_PLUGIN(registrar) {
  registrar.behaviors.add<Blink>("Blink", "emits an event once and succeeds",
                                 {icars::behavior::param("event", icars::behavior::ParamType::string, std::nullopt, "the event to emit").naming("event")});
  registrar.behaviors.declare_events("Blink", {});
  registrar.adaptors.add("test::Lamp", [](const icars::df::DeviceInfo& d, const icars::df::CapabilityInfo& c)
                                           -> std::shared_ptr<icars::service::Adaptor> {
    return std::make_shared<icars::service::GenericAdaptor>(d, c);
  });
  registrar.composers.push_back([](icars::service::ServiceContainer& container) -> std::unique_ptr<icars::service::Composer> {
    return std::make_unique<LampComposer>(container);
  });
}
