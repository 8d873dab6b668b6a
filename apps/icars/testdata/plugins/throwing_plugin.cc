// A plugin whose registration throws: refused, and nothing it registered first is kept.
#include <stdexcept>

#include "icars/server/plugin.h"

namespace {

class Never final : public icars::behavior::Behavior {
 public:
  explicit Never(const icars::behavior::Params&) {}

 protected:
  void entry() override {}
};

}  // namespace

ICARS_PLUGIN(registrar) {
  registrar.behaviors.add<Never>("Never", "registered before the registration fails");
  throw std::runtime_error("the lamp's licence file is missing");
}
