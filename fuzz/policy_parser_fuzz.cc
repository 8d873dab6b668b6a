// Fuzz target: the collaboration policy parser (XML, tasks, behavior trees, conditions, the
// statechart and its checks) with the behaviors `icars` runs (generic + smart-home).
//
// The input is a policy file. The one expected failure is PolicyError, whose diagnostics must
// each carry a message. A policy the parser accepts must be buildable: every behavior node is
// created through the registry, which must then not reject its type or parameters, since the
// parser promises to have checked them.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string_view>

#include "fuzz_util.h"
#include "icars/control/policy.h"
#include "icars/home/behaviors.h"

namespace {

namespace b = icars::behavior;
namespace c = icars::control;
namespace home = icars::home;

[[noreturn]] void fail(const char* what, const char* detail) {
  std::fprintf(stderr, "policy_parser_fuzz: %s: %s\n", what, detail);
  std::abort();
}

void build(const c::NodeSpec& node, const b::BehaviorRegistry& registry) {
  if (node.kind == c::NodeSpec::Kind::behavior) {
    try {
      (void)registry.create(node.type, node.name, node.params);
    } catch (const std::exception& e) {
      fail("an accepted behavior node cannot be built", e.what());
    }
  }
  for (const c::NodeSpec& child : node.children) build(child, registry);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const b::BehaviorRegistry registry = home::behavior_registry();
  const std::string_view xml(reinterpret_cast<const char*>(data), size);
  try {
    const c::ParsedPolicy parsed = c::parse_policy(xml, "fuzz.xml", registry);
    for (const c::TaskSpec& task : parsed.policy.tasks) build(task.root, registry);
    for (const c::Diagnostic& warning : parsed.warnings) (void)warning.to_string();
  } catch (const c::PolicyError& e) {
    icars_fuzz::note_rejected("policy_parser_fuzz", e.what());
    if (e.diagnostics().empty()) fail("PolicyError without diagnostics", e.what());
    for (const c::Diagnostic& d : e.diagnostics()) {
      if (d.message.empty()) fail("a diagnostic without a message", e.what());
      (void)d.to_string();
    }
  }
  return 0;
}
