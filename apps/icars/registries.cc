#include "registries.h"

#include <algorithm>

#include "icars/home/adaptors.h"
#include "icars/home/behaviors.h"
#include "icars/home/services.h"

namespace icars::app {

Registries::Registries(const std::vector<std::string>& plugin_paths)
    : behaviors(home::behavior_registry()),
      adaptors(home::adaptors()),
      composers{home::composer()},
      sim_devices(home::sim_device_types()) {
  server::Extension<home::SimDeviceTypes> devices("simulated device types", sim_devices);
  for (const auto& path : plugin_paths) {
    plugins.push_back(server::load_plugin(path, {behaviors, adaptors, composers, {&devices}}));
  }
}

const server::LoadedPlugin* Registries::plugin_of_behavior(const std::string& type) const {
  for (const auto& plugin : plugins) {
    if (std::find(plugin.behaviors.begin(), plugin.behaviors.end(), type) != plugin.behaviors.end()) return &plugin;
  }
  return nullptr;
}

}  // namespace icars::app
