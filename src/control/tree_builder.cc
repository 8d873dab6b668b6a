#include "icars/control/tree_builder.h"

#include <stdexcept>

#include "icars/control/remote_tree.h"

namespace icars::control {

namespace b = icars::behavior;

std::unique_ptr<b::Behavior> build_tree(const NodeSpec& spec, const b::BehaviorRegistry& registry, RemoteHosts* hosts) {
  if (!spec.host.empty()) {
    if (hosts == nullptr || !hosts->knows(spec.host)) {
      throw std::invalid_argument("node '" + spec.name + "' runs on behavior host '" + spec.host +
                                  "', which this server does not know");
    }
    return hosts->make(spec.host, spec.name, spec.xml);
  }
  std::unique_ptr<b::Behavior> node;
  switch (spec.kind) {
    case NodeSpec::Kind::behavior:
      return registry.create(spec.type, spec.name, spec.params);
    case NodeSpec::Kind::sequential:
      node = std::make_unique<b::SequentialBehavior>(spec.sequence);
      break;
    case NodeSpec::Kind::concurrent:
      node = std::make_unique<b::ConcurrentBehavior>(spec.completion);
      break;
    case NodeSpec::Kind::filter:
      node = std::make_unique<b::FilterBehavior>(spec.pass, spec.completion);
      break;
    case NodeSpec::Kind::interpret:
      node = std::make_unique<b::InterpretBehavior>(spec.rules, spec.pass_unmatched, spec.completion);
      break;
    case NodeSpec::Kind::aggregate:
      node = std::make_unique<b::AggregateBehavior>(spec.aggregate, spec.completion);
      break;
    case NodeSpec::Kind::fallback:
      node = std::make_unique<b::FallbackBehavior>();
      break;
    case NodeSpec::Kind::reactive_sequence:
      node = std::make_unique<b::ReactiveSequenceBehavior>();
      break;
    case NodeSpec::Kind::reactive_fallback:
      node = std::make_unique<b::ReactiveFallbackBehavior>();
      break;
    case NodeSpec::Kind::condition:
      node = std::make_unique<b::ConditionBehavior>(spec.trigger);
      break;
    case NodeSpec::Kind::when:
      node = std::make_unique<b::WhenBehavior>(spec.when);
      break;
    case NodeSpec::Kind::retry:
      node = std::make_unique<b::RetryBehavior>(spec.times, spec.delay);
      break;
    case NodeSpec::Kind::repeat:
      node = std::make_unique<b::RepeatBehavior>(spec.times);
      break;
    case NodeSpec::Kind::timeout:
      node = std::make_unique<b::TimeoutBehavior>(spec.limit);
      break;
    case NodeSpec::Kind::invert:
      node = std::make_unique<b::InvertBehavior>();
      break;
  }
  node->set_identity(spec.type, spec.name);
  for (const auto& child : spec.children) node->add_child(build_tree(child, registry, hosts));
  return node;
}

}  // namespace icars::control
