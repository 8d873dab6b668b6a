// Behavior subtrees on other servers (idl/behavior.idl, docs/distribution.md): a node of a task's
// tree may run on another server, and the tree stays one tree.
//
// On the server that places the subtree, a RemoteSubtree stands in the tree where the subtree's
// root would be: it starts the subtree on the host (BehaviorHost::start, with the node's XML),
// propagates what the remote root propagates (to its parent and siblings, as the root would),
// hands its siblings' events to the remote root, succeeds or fails when the remote root does
// (with its reason), and halting it halts the subtree. A host that cannot be reached, refuses
// the subtree or whose link drops while it runs fails the node with the reason
// ("disconnected: ..."), which its parent handles as any failure.
//
// On the host, a SubtreeHost (the BehaviorHost servant) builds each subtree with its own
// behavior registry and runs it on its own runtime, with its own services and trace, under the
// placing tree's paths; a subtree whose parent's link closes is halted (nobody would hear it).
//
//   // host (server B):
//   auto host = std::make_shared<SubtreeHost>(env_b, registry_b, communicator_b);
//   communicator_b.adapter().add(std::string(kBehaviorHostPath), host);
//   // placing server (server A): the hosts it knows, by name
//   RemoteHosts hosts(communicator_a);
//   hosts.add("B", "10.0.0.2", 4711);
//   auto node = hosts.make("B", "<sequential name=\"Round\">...</sequential>");
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "behavior.planet.h"
#include "icars/behavior/behavior.h"
#include "icars/behavior/registry.h"
#include "icars/control/policy.h"
#include "icars/planet/communicator.h"

namespace icars::control {

// Where a server serves its BehaviorHost and its SubtreeParent.
inline constexpr std::string_view kBehaviorHostPath = "/control/behavior_host";
inline constexpr std::string_view kSubtreeParentPath = "/control/subtree_parent";

// One node of a policy's task (`xml`, as a policy file writes it: `<sequential name="Round">...`),
// read with every check of the policy parser; control::PolicyError when it is not one.
NodeSpec parse_subtree(const std::string& xml, const behavior::BehaviorRegistry& registry);

// An event as it crosses servers, and back.
remote::TreeEvent encode_tree_event(const behavior::Event& e);
behavior::Event decode_tree_event(const remote::TreeEvent& e);  // planet::Error(bad_data) if malformed

struct SubtreeHostOptions {
  std::size_t max_subtrees = 256;  // more start() calls are refused
};

// The host side. Servant calls arrive on the communicator's io thread; the subtrees run on
// env.runtime. Destroy it before the runtime and the communicator (it halts what still runs).
class SubtreeHost final : public remote::BehaviorHostServant {
 public:
  SubtreeHost(behavior::Environment& env, const behavior::BehaviorRegistry& registry, planet::Communicator& communicator,
              SubtreeHostOptions options = {});
  ~SubtreeHost() override;

  std::int64_t start(const std::string& path, const std::string& xml, const planet::Current& current) override;
  void deliver(std::int64_t subtree, const remote::TreeEvent& event, const planet::Current& current) override;
  void halt(std::int64_t subtree, const planet::Current& current) override;
  std::string status(std::int64_t subtree, const planet::Current& current) override;

  std::size_t running() const;  // subtrees started and not yet ended

 private:
  class Hosted;
  void end(std::int64_t id);  // on the runtime: forgets the subtree (after it completed or was halted)
  void halt_later(std::int64_t id);  // halts and forgets the subtree on the runtime, if it still runs
  std::shared_ptr<Hosted> find(std::int64_t id) const;

  behavior::Environment& env_;
  const behavior::BehaviorRegistry& registry_;
  planet::Communicator& communicator_;
  SubtreeHostOptions options_;
  std::uint64_t listener_ = 0;
  mutable std::mutex mutex_;
  std::int64_t next_id_ = 1;
  std::map<std::int64_t, std::shared_ptr<Hosted>> hosted_;
  std::map<std::int64_t, std::string> ended_;  // the status of subtrees that ended (bounded)
  std::shared_ptr<const char> alive_ = std::make_shared<const char>('\0');
};

class RemoteSubtree;

// The placing side: the hosts this server may place subtrees on, by name, and the SubtreeParent
// servant their subtrees report to. Thread-safe; destroy it after the trees that use it.
class RemoteHosts {
 public:
  explicit RemoteHosts(planet::Communicator& communicator);
  ~RemoteHosts();
  RemoteHosts(const RemoteHosts&) = delete;
  RemoteHosts& operator=(const RemoteHosts&) = delete;

  // A host named `name` at host:port (its BehaviorHost at kBehaviorHostPath); the link is opened
  // now and kept (reconnecting). Throws std::invalid_argument for a name given twice.
  void add(const std::string& name, const std::string& host, std::uint16_t port);
  bool knows(const std::string& name) const;
  // Waits until the link to `name` is up; false after `timeout`.
  bool wait_connected(const std::string& name, std::chrono::milliseconds timeout) const;
  // Waits until the links to every host are up; false after `timeout`.
  bool wait_all_connected(std::chrono::milliseconds timeout) const;

  // The node, named `node` in its tree, that runs the subtree `xml` (one node of a policy's task
  // named `node`) on host `name`. std::invalid_argument for an unknown host.
  std::unique_ptr<behavior::Behavior> make(const std::string& name, const std::string& node, const std::string& xml);

 private:
  friend class RemoteSubtree;
  // What a RemoteSubtree hears about its subtree, each callable from any thread (guarded: it
  // runs on the runtime while the node's activation lasts).
  struct Listener {
    std::function<void(behavior::Event)> propagated;
    std::function<void(bool, std::string)> completed;
    std::function<void(std::string)> lost;
  };
  struct Early {  // what arrived for a subtree before its node knew its id
    std::vector<behavior::Event> events;
    std::optional<std::pair<bool, std::string>> completion;
  };
  class Parent;
  std::shared_ptr<planet::Peer> peer(const std::string& name) const;
  void attach(std::uint64_t connection, std::int64_t id, Listener listener);
  void detach(std::uint64_t connection, std::int64_t id);
  void propagated(std::uint64_t connection, std::int64_t id, behavior::Event e);
  void completed(std::uint64_t connection, std::int64_t id, bool succeeded, const std::string& reason);
  void link_down(std::uint64_t connection, const std::string& reason);

  planet::Communicator& communicator_;
  std::uint64_t listener_ = 0;
  mutable std::mutex mutex_;
  std::map<std::string, std::shared_ptr<planet::Peer>> hosts_;
  std::map<std::pair<std::uint64_t, std::int64_t>, Listener> nodes_;  // by (connection, subtree)
  std::map<std::pair<std::uint64_t, std::int64_t>, Early> early_;     // bounded
  std::map<std::uint64_t, std::string> down_;  // host links that closed, and why (bounded)
};

}  // namespace icars::control
