// Tutorial, step 4 (application programmer): a behavior that keeps a room cool with a fan, and
// its registration under the name a policy file uses.
//
// CoolDown binds the room's Fan and Thermometer services at entry and listens to the
// thermometer. When the temperature rises above `hot` it runs the fan and, once the fan
// confirmed, propagates TooHot; when it falls to `hot` or below it stops the fan and propagates
// Comfortable. It acts only on a change (and on the first reading, taken at entry), and runs
// until its task is halted. A fan or thermometer that fails a call fails the behavior.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "icars/behavior/behavior.h"
#include "icars/behavior/registry.h"
#include "services.h"

namespace tutorial {

class CoolDown final : public icars::behavior::Behavior {
 public:
  explicit CoolDown(const icars::behavior::Params& params);

 protected:
  void entry() override;
  void handle_event(const icars::behavior::Event& event) override;

 private:
  void react(double celsius);

  double hot_;
  int speed_;
  std::string room_;
  std::shared_ptr<FanService> fan_;
  std::shared_ptr<ThermometerService> thermometer_;
  std::optional<bool> cooling_;  // what the fan was last told; empty before the first reading
};

// Adds CoolDown, with its declared parameters, to `registry`.
void register_tutorial_behaviors(icars::behavior::BehaviorRegistry& registry);

}  // namespace tutorial
