// The mediating server of the ICARS paper (Fig. 2, 4.3): the PLANET server that device managers
// and clients connect to, the Service Framework that turns registered devices into services, the
// behavior runtime and the Collaboration Manager that runs a collaboration policy over them —
// assembled around one ServerOptions. `icars run`, the tutorial plugin and the tests all use it.
//
//   server::ServerOptions options;
//   options.listen = "0.0.0.0:4711";
//   options.policy_dir = "policies";
//   server::MediatingServer server(std::move(options));
//   server.listen();                 // device managers may register now
//   server.use_clock(house_clock);   // the time behaviors' timers follow
//   server.run_policy("paper_home"); // throws control::PolicyError
//
// What happens is told through trace(): transitions, tasks, behaviors, service calls. Reporting
// (a timeline, a summary, a plot) is an observer of the server (icars/report/), not part of it.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "icars/behavior/registry.h"
#include "icars/behavior/runtime.h"
#include "icars/behavior/trace.h"
#include "icars/control/collaboration.h"
#include "icars/control/remote_tree.h"
#include "icars/planet/communicator.h"
#include "icars/planet/endpoint.h"
#include "icars/planet/security.h"
#include "icars/service/service_framework.h"

namespace icars::server {

struct ServerOptions {
  ServerOptions() { planet.name = "icars"; }

  std::string listen = "127.0.0.1:0";  // host:port; port 0 lets the system choose
  // The PLANET server: `tls` (docs/security.md), `access` (who may connect and call what; null:
  // anyone, so listen on loopback only), `logger`, limits and timeouts (docs/protocol.md).
  // `planet.connection.activity` runs the server in lock-step with a simulated house of this
  // process (icars/clock/lock_step.h): its messages and its behaviors' handlers count as work.
  planet::CommunicatorOptions planet;
  // The adaptor services made for registered devices' capabilities (none known: every
  // capability is a GenericAdaptor), the registry's limits, and the composers of adaptive
  // services. A home's: home::adaptors() and home::composer() (icars/home/).
  service::AdaptorFactory adaptors;
  service::RegistryOptions registry;
  std::vector<service::MakeComposer> composers;
  // The behavior types policies may name.
  behavior::BehaviorRegistry behaviors;
  // Where policies are found by name (<dir>/<name>.xml); a path with '/' or .xml is used as is.
  std::string policy_dir = ".";
  // Distribution (docs/distribution.md): `host_behaviors` serves this server's BehaviorHost, so
  // other servers' policies may place subtrees here (they run on this server's runtime, from
  // use_clock() on); `behavior_hosts` are the servers this one's policies may place subtrees on
  // (host="NAME" on a node).
  bool host_behaviors = false;
  struct BehaviorHostAddress {
    std::string name;  // as policies name it
    std::string host;
    std::uint16_t port = 0;
  };
  std::vector<BehaviorHostAddress> behavior_hosts;
  // One service directory (docs/distribution.md): `share_devices` lets other servers use the
  // devices registered here (service::SharedDirectory); the devices the servers in
  // `device_peers` share become services here too (from listen() on), so behaviors find and
  // call them as their own.
  bool share_devices = false;
  std::vector<BehaviorHostAddress> device_peers;
};

// What reload_access() did.
struct AccessReload {
  std::size_t principals = 0;           // in the new policy
  std::vector<std::string> changed;     // removed or changed principals (their links were closed)
  std::size_t forgotten_devices = 0;    // devices the removed principals held
};

class MediatingServer {
 public:
  // Checks the options and builds the PLANET server and the Service Framework. Throws
  // std::invalid_argument for a bad listen endpoint and std::runtime_error for TLS files that
  // cannot be used; nothing listens yet.
  explicit MediatingServer(ServerOptions options);
  // Stops the running policy and lets its behaviors finish, then closes every connection.
  ~MediatingServer();
  MediatingServer(const MediatingServer&) = delete;
  MediatingServer& operator=(const MediatingServer&) = delete;

  // Starts accepting device managers and clients; returns the bound port. Throws when the
  // endpoint cannot be bound (in use, no such address).
  std::uint16_t listen();
  // The endpoint listened on, with the bound port (port 0 before listen()).
  planet::Endpoint endpoint() const;

  planet::Communicator& communicator() { return *communicator_; }
  service::ServiceFramework& services() { return *framework_; }
  service::ServiceContainer& container() { return framework_->container(); }
  behavior::Trace& trace() { return trace_; }
  const behavior::BehaviorRegistry& behaviors() const { return options_.behaviors; }
  const control::PolicyRepository& policies() const { return repository_; }

  // The clock that behaviors' timers follow (the simulated house's, or one following a remote
  // house's time). Needed before the first run_policy(); the clock must outlive the server, or
  // stop() must have returned before it goes.
  void use_clock(Clock& clock);
  // Waits until the links to every behavior host (ServerOptions::behavior_hosts) are up, so a
  // policy's first placed node finds its host; false after `timeout`.
  bool wait_behavior_hosts(std::chrono::milliseconds timeout);
  // Waits until the directories of every device peer (ServerOptions::device_peers) have been
  // read, so a policy's first behavior finds their services; false after `timeout`.
  bool wait_device_peers(std::chrono::milliseconds timeout);
  // The behavior runtime (null before the first run_policy()).
  behavior::Runtime* runtime() { return runtime_.get(); }

  // Loads, checks and starts a policy, replacing the one running. Throws control::PolicyError
  // (the running policy, if any, keeps running) and std::logic_error without a clock. May be
  // called from any thread (an operator switching policies).
  control::ParsedPolicy run_policy(const std::string& name);
  // Stops the running policy and waits up to `drain` for its behaviors to finish.
  void stop_policy(std::chrono::milliseconds drain = std::chrono::seconds(5));
  // Stops the running policy, ends the behavior runtime and lets go of the clock; the server
  // keeps serving devices and clients. A later run_policy() needs use_clock() again.
  void stop(std::chrono::milliseconds drain = std::chrono::seconds(5));
  // The running policy's Coordinator (null when none runs).
  control::Coordinator* coordinator();
  // An operator's command: raises `event` in the running policy (Coordinator::raise), from any
  // thread. False when no policy runs; std::invalid_argument for `done` and `failed`.
  bool raise(behavior::Event event);
  // The running policy's name and the events its transitions wait for (Coordinator::events);
  // empty when none runs. Thread-safe.
  std::string policy_name();
  // A copy of the running policy (nullopt when none runs). Thread-safe.
  std::optional<control::Policy> running_policy();
  std::vector<std::string> policy_events();

  // Puts another access policy in force: principals that `next` removes or changes lose their
  // links, and the devices of those removed are forgotten. Needs a server built with an access
  // policy (std::logic_error otherwise). Thread-safe.
  AccessReload reload_access(std::shared_ptr<const planet::AccessPolicy> next);
  std::shared_ptr<const planet::AccessPolicy> access() const;

 private:
  void start_runtime();

  ServerOptions options_;
  planet::Endpoint endpoint_;
  control::PolicyRepository repository_;
  behavior::Trace trace_;
  std::unique_ptr<planet::Communicator> communicator_;
  std::unique_ptr<service::ServiceFramework> framework_;
  Clock* clock_ = nullptr;
  std::unique_ptr<control::RemoteHosts> hosts_;  // with behavior_hosts
  std::unique_ptr<behavior::Runtime> runtime_;
  std::unique_ptr<behavior::Environment> environment_;
  std::shared_ptr<control::SubtreeHost> subtree_host_;  // with host_behaviors, while the runtime runs
  std::unique_ptr<control::CollaborationManager> manager_;
  std::mutex policy_mutex_;  // run_policy, stop_policy and stop against the thread-safe accessors
  mutable std::mutex access_mutex_;
  std::shared_ptr<const planet::AccessPolicy> access_;
};

}  // namespace icars::server
