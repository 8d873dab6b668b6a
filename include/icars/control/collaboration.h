// The runtime task execution engine of ICARS (paper 4.3.3, Fig. 14): the Collaboration Manager
// loads a collaboration policy from the Policy Repository, has the Policy Parser read it and the
// Policy Factory turn it into a Coordinator, and starts it.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "icars/control/coordinator.h"
#include "icars/control/policy.h"

namespace icars::control {

// A directory of policy files (<name>.xml). A name with a '/' or ending in .xml is a path.
class PolicyRepository {
 public:
  explicit PolicyRepository(std::string directory) : directory_(std::move(directory)) {}
  const std::string& directory() const { return directory_; }
  std::string path_of(const std::string& name) const;
  std::vector<std::string> names() const;  // sorted

 private:
  std::string directory_;
};

// Policy → Coordinator with its tasks and behaviors.
class PolicyFactory {
 public:
  // `hosts`: where the policies' nodes with a host attribute run (remote_tree.h); null: none may.
  explicit PolicyFactory(const behavior::BehaviorRegistry& registry, RemoteHosts* hosts = nullptr)
      : registry_(registry), hosts_(hosts) {}
  std::unique_ptr<Coordinator> create(Policy policy, behavior::Environment& env) const;

 private:
  const behavior::BehaviorRegistry& registry_;
  RemoteHosts* hosts_;
};

class CollaborationManager {
 public:
  // `hosts`: where the policies' nodes with a host attribute run (remote_tree.h); null: none may.
  CollaborationManager(PolicyRepository repository, const behavior::BehaviorRegistry& registry,
                       behavior::Environment& env, RemoteHosts* hosts = nullptr);
  ~CollaborationManager();  // stops the running policy

  // Loads, checks and starts a policy, replacing the one running. Throws PolicyError (the
  // running policy, if any, keeps running).
  ParsedPolicy run(const std::string& name);
  void stop();
  Coordinator* coordinator() { return coordinator_.get(); }
  const PolicyRepository& repository() const { return repository_; }

 private:
  PolicyRepository repository_;
  const behavior::BehaviorRegistry& registry_;
  behavior::Environment& env_;
  RemoteHosts* hosts_;
  std::unique_ptr<Coordinator> coordinator_;
};

}  // namespace icars::control
