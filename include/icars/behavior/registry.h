// Behavior factories registered by name in an explicit registry object (no global registry):
// a policy file names a behavior type and gives its parameters; the registry checks them
// against the type's declared parameters and builds the behavior.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "icars/behavior/behavior.h"
#include "icars/behavior/params.h"

namespace icars::behavior {

class BehaviorRegistry {
 public:
  using Factory = std::function<std::unique_ptr<Behavior>(const Params&)>;
  struct Entry {
    std::string type;
    std::string doc;
    std::vector<ParamSpec> params;
    Factory factory;
  };

  // Registers a behavior type; throws std::invalid_argument when the type is taken.
  void add(std::string type, std::string doc, std::vector<ParamSpec> params, Factory factory);
  // Registers B, built as B(params).
  template <class B>
  void add(std::string type, std::string doc, std::vector<ParamSpec> params = {}) {
    add(std::move(type), std::move(doc), std::move(params),
        [](const Params& p) -> std::unique_ptr<Behavior> { return std::make_unique<B>(p); });
  }

  const Entry* find(std::string_view type) const;
  std::vector<std::string> types() const;

  // The values of `given` checked against the type's parameters (unknown names, missing required
  // values, values of the wrong kind) with defaults filled in. Throws ParamError.
  Params check(std::string_view type, const std::map<std::string, std::string, std::less<>>& given) const;
  // Builds a behavior of `type` named `name` (the type when empty). Throws ParamError.
  std::unique_ptr<Behavior> create(std::string_view type, std::string name,
                                   const std::map<std::string, std::string, std::less<>>& given) const;

 private:
  std::map<std::string, Entry, std::less<>> entries_;
};

// The generic leaves: Wait (duration) and Emit (event, delay).
void register_generic_behaviors(BehaviorRegistry& registry);

}  // namespace icars::behavior
