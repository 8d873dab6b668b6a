// A plugin that adds a behavior type `icars` already has (Wait): refused.
#include "icars/server/plugin.h"

namespace {

class MyWait final : public icars::behavior::Behavior {
 public:
  explicit MyWait(const icars::behavior::Params&) {}

 protected:
  void entry() override {}
};

}  // namespace

ICARS_PLUGIN(registrar) { registrar.behaviors.add<MyWait>("Wait", "another Wait"); }
