// The Policy Factory's half for behaviors: a task's tree of NodeSpecs, as the Policy Parser read
// it, turned into the behavior tree a Task runs — composites, decorators and reactive nodes
// from the behavior layer, leaves from the BehaviorRegistry.
#pragma once

#include <memory>

#include "icars/behavior/behavior.h"
#include "icars/behavior/registry.h"
#include "icars/control/policy.h"

namespace icars::control {

class RemoteHosts;

// Builds the behavior tree of a node spec. Throws behavior::ParamError for a leaf the registry
// refuses (a spec that parse_policy accepted has none). A node with a host (host="B") becomes a
// node that runs it there (remote_tree.h) through `hosts`; std::invalid_argument when `hosts` is
// null or does not know the host.
std::unique_ptr<behavior::Behavior> build_tree(const NodeSpec& spec, const behavior::BehaviorRegistry& registry,
                                               RemoteHosts* hosts = nullptr);

}  // namespace icars::control
