#include "icars/control/collaboration.h"

#include <algorithm>
#include <filesystem>

namespace icars::control {

std::string PolicyRepository::path_of(const std::string& name) const {
  if (name.find('/') != std::string::npos || name.ends_with(".xml")) return name;
  return (std::filesystem::path(directory_) / (name + ".xml")).string();
}

std::vector<std::string> PolicyRepository::names() const {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(directory_, ec)) {
    if (entry.path().extension() == ".xml") out.push_back(entry.path().stem().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

std::unique_ptr<Coordinator> PolicyFactory::create(Policy policy, behavior::Environment& env) const {
  return std::make_unique<Coordinator>(std::move(policy), registry_, env, hosts_);
}

CollaborationManager::CollaborationManager(PolicyRepository repository,
                                           const behavior::BehaviorRegistry& registry,
                                           behavior::Environment& env, RemoteHosts* hosts)
    : repository_(std::move(repository)), registry_(registry), env_(env), hosts_(hosts) {}

CollaborationManager::~CollaborationManager() { stop(); }

ParsedPolicy CollaborationManager::run(const std::string& name) {
  auto parsed = parse_policy_file(repository_.path_of(name), registry_);
  auto next = PolicyFactory(registry_, hosts_).create(parsed.policy, env_);
  stop();
  coordinator_ = std::move(next);
  coordinator_->start();
  return parsed;
}

void CollaborationManager::stop() {
  if (coordinator_) coordinator_->stop();
  coordinator_.reset();
}

}  // namespace icars::control
