#include "icars/server/mediating_server.h"

#include <algorithm>
#include <stdexcept>

namespace icars::server {

MediatingServer::MediatingServer(ServerOptions options)
    : options_(std::move(options)),
      endpoint_(planet::parse_endpoint(options_.listen, /*allow_any_port=*/true)),
      repository_(options_.policy_dir),
      communicator_(std::make_unique<planet::Communicator>(options_.planet)),
      framework_(std::make_unique<service::ServiceFramework>(*communicator_, options_.adaptors,
                                                             options_.registry, options_.composers)),
      access_(options_.planet.access) {
  if (!options_.behavior_hosts.empty()) {
    hosts_ = std::make_unique<control::RemoteHosts>(*communicator_);
    for (const auto& h : options_.behavior_hosts) hosts_->add(h.name, h.host, h.port);
  }
  if (options_.share_devices) framework_->share();
}

MediatingServer::~MediatingServer() {
  // Behaviors first (they call services), then the Service Framework (it stops taking
  // registrations), then the PLANET server with every connection.
  stop();
  hosts_.reset();
  framework_.reset();
  communicator_.reset();
}

std::uint16_t MediatingServer::listen() {
  endpoint_.port = communicator_->listen(endpoint_.host, endpoint_.port);
  // After listening: the links announce this server's name, which its references carry.
  if (framework_->mirrors().empty()) {
    for (const auto& d : options_.device_peers) framework_->mirror(communicator_->connect(d.host, d.port), d.name);
  }
  return endpoint_.port;
}

planet::Endpoint MediatingServer::endpoint() const { return endpoint_; }

void MediatingServer::use_clock(Clock& clock) {
  std::lock_guard lock(policy_mutex_);
  if (runtime_ && &runtime_->clock() != &clock) {
    throw std::logic_error("the mediating server's behaviors already run on another clock");
  }
  clock_ = &clock;
  // A behavior host runs others' subtrees from now on, with or without a policy of its own.
  if (options_.host_behaviors) start_runtime();
}

bool MediatingServer::wait_device_peers(std::chrono::milliseconds timeout) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  for (const auto& mirror : framework_->mirrors()) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(until - std::chrono::steady_clock::now());
    if (!mirror->wait_synced(std::max(left, std::chrono::milliseconds(0)))) return false;
  }
  return framework_->mirrors().size() == options_.device_peers.size();
}

bool MediatingServer::wait_behavior_hosts(std::chrono::milliseconds timeout) {
  return !hosts_ || hosts_->wait_all_connected(timeout);
}

// Under policy_mutex_, with a clock.
void MediatingServer::start_runtime() {
  if (manager_) return;
  runtime_ = std::make_unique<behavior::Runtime>(*clock_, options_.planet.connection.activity);
  environment_ = std::make_unique<behavior::Environment>(
      behavior::Environment{*runtime_, framework_->container(), trace_});
  if (options_.host_behaviors) {
    subtree_host_ = std::make_shared<control::SubtreeHost>(*environment_, options_.behaviors, *communicator_);
    communicator_->adapter().add(std::string(control::kBehaviorHostPath), subtree_host_);
  }
  manager_ = std::make_unique<control::CollaborationManager>(repository_, options_.behaviors, *environment_,
                                                             hosts_.get());
}

control::ParsedPolicy MediatingServer::run_policy(const std::string& name) {
  std::lock_guard lock(policy_mutex_);
  if (!manager_) {
    if (!clock_) throw std::logic_error("the mediating server has no clock: call use_clock() first");
    start_runtime();
  }
  return manager_->run(name);
}

void MediatingServer::stop_policy(std::chrono::milliseconds drain) {
  std::lock_guard lock(policy_mutex_);
  if (!manager_) return;
  manager_->stop();
  runtime_->drain(drain);
}

void MediatingServer::stop(std::chrono::milliseconds drain) {
  stop_policy(drain);
  std::lock_guard lock(policy_mutex_);
  manager_.reset();
  if (subtree_host_) {
    // Others' subtrees end here (halted, on the runtime that ran them).
    communicator_->adapter().remove(std::string(control::kBehaviorHostPath));
    subtree_host_.reset();
  }
  environment_.reset();
  runtime_.reset();
  clock_ = nullptr;
}

control::Coordinator* MediatingServer::coordinator() { return manager_ ? manager_->coordinator() : nullptr; }

bool MediatingServer::raise(behavior::Event event) {
  std::lock_guard lock(policy_mutex_);
  auto* c = coordinator();
  if (c == nullptr) return false;
  c->raise(std::move(event));
  return true;
}

std::string MediatingServer::policy_name() {
  std::lock_guard lock(policy_mutex_);
  const auto* c = coordinator();
  return c ? c->policy().name : std::string();
}

std::optional<control::Policy> MediatingServer::running_policy() {
  std::lock_guard lock(policy_mutex_);
  const auto* c = coordinator();
  if (!c) return std::nullopt;
  return c->policy();
}

std::vector<std::string> MediatingServer::policy_events() {
  std::lock_guard lock(policy_mutex_);
  const auto* c = coordinator();
  return c ? c->events() : std::vector<std::string>();
}

AccessReload MediatingServer::reload_access(std::shared_ptr<const planet::AccessPolicy> next) {
  if (!next) throw std::invalid_argument("no access policy to put in force");
  std::lock_guard lock(access_mutex_);
  if (!access_) {
    throw std::logic_error("the mediating server was started without an access policy; it admits anyone");
  }
  AccessReload result;
  result.changed = planet::reload_access_policy(communicator_->connections(), *access_, next);
  for (const auto& name : result.changed) {
    if (!next->find(name)) result.forgotten_devices += framework_->registry().forget_holder(name);
  }
  result.principals = next->principals().size();
  access_ = std::move(next);
  return result;
}

std::shared_ptr<const planet::AccessPolicy> MediatingServer::access() const {
  std::lock_guard lock(access_mutex_);
  return access_;
}

}  // namespace icars::server
