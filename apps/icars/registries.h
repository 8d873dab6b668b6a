// What `icars` knows, by name: the behavior types a policy can use, the adaptors of the
// capability interfaces, the composers of adaptive services and the device types a simulated
// house can hold. The home's, plus whatever the plugins given with --plugin add.
#pragma once

#include <string>
#include <vector>

#include "icars/behavior/registry.h"
#include "icars/home/sim/sim_devices.h"
#include "icars/server/plugin.h"
#include "icars/service/device_registry.h"
#include "icars/service/service_framework.h"

namespace icars::app {

struct Registries {
  behavior::BehaviorRegistry behaviors;
  service::AdaptorFactory adaptors;
  std::vector<service::MakeComposer> composers;
  home::SimDeviceTypes sim_devices;
  std::vector<server::LoadedPlugin> plugins;

  // The home's, then each plugin's, in order; throws server::PluginError for the first plugin
  // that cannot be used.
  explicit Registries(const std::vector<std::string>& plugin_paths);

  // The plugin that added behavior type `type`, or nullptr for one of the home's.
  const server::LoadedPlugin* plugin_of_behavior(const std::string& type) const;
};

}  // namespace icars::app
