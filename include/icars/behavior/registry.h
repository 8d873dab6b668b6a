// Behavior factories registered by name in an explicit registry object (no global registry):
// a policy file names a behavior type and gives its parameters; the registry checks them
// against the type's declared parameters and builds the behavior.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "icars/behavior/behavior.h"
#include "icars/behavior/params.h"
#include "icars/behavior/vocabulary.h"

namespace icars::behavior {

class BehaviorRegistry {
 public:
  using Factory = std::function<std::unique_ptr<Behavior>(const Params&)>;
  struct Entry {
    std::string type;
    std::string doc;
    std::vector<ParamSpec> params;
    Factory factory;
    // The events it propagates; nullopt when not declared (a policy check then assumes any).
    std::optional<std::vector<EventSpec>> emits;
  };

  // Registers a behavior type; throws std::invalid_argument when the type is taken.
  void add(std::string type, std::string doc, std::vector<ParamSpec> params, Factory factory);
  // Registers B, built as B(params).
  template <class B>
  void add(std::string type, std::string doc, std::vector<ParamSpec> params = {}) {
    add(std::move(type), std::move(doc), std::move(params),
        [](const Params& p) -> std::unique_ptr<Behavior> { return std::make_unique<B>(p); });
  }

  // Declares the events a registered type propagates (besides those of parameters naming an
  // "event"); throws std::invalid_argument for an unknown type.
  void declare_events(std::string_view type, std::vector<EventSpec> events);

  const Entry* find(std::string_view type) const;
  std::vector<std::string> types() const;
  // Adds every type of `other`; throws std::invalid_argument, adding none, if one is taken.
  void merge(BehaviorRegistry&& other);

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
