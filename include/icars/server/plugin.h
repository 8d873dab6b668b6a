// Plugins: shared libraries that add behavior types, adaptor types and composers of adaptive
// services to a mediating server, the way BehaviorTree.CPP's plugins add node types.
// `icars run|validate|behaviors --plugin PATH.so` (repeatable) loads them.
//
// A plugin is one ICARS_PLUGIN entry in a shared library:
//
//   #include "icars/server/plugin.h"
//
//   ICARS_PLUGIN(registrar) {
//     registrar.behaviors.add<CoolDown>("CoolDown", "keeps a room below a temperature", {...});
//     registrar.adaptors.add<tutorial::Fan, FanService>();
//     registrar.composers.push_back(my_composer());
//   }
//
// It links no ICARS library: the program that loads it provides every ICARS symbol (`icars` is
// linked to export them), so there is one copy of each class, registry and type_info in the
// process. It must be built against the same ICARS version, with the same compiler and flags.
//
// load_plugin() refuses a plugin, with a PluginError naming the file and the reason, when the
// file cannot be loaded (missing, not a shared library, a symbol the program lacks), has no
// ICARS_PLUGIN entry, was built against another ICARS version or plugin API, throws from its
// registration, or adds a behavior type or an adaptor for an interface that is already there.
// A refused plugin adds nothing.
#pragma once

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <typeinfo>
#include <utility>
#include <vector>

#include "icars/behavior/registry.h"
#include "icars/service/device_registry.h"
#include "icars/service/service_framework.h"
#include "icars/version.h"

namespace icars::server {

// Changes whenever what a plugin is handed changes shape (PluginRegistrar, the registries).
inline constexpr std::uint32_t kPluginApi = 1;

class PluginError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A registry a program offers its plugins beyond the three every server has, such as the
// home's simulated device types (home::SimDeviceTypes) that `icars run` offers. A program wraps
// each of its registries in an Extension; a plugin reaches one with
// PluginRegistrar::extension<Registry>().
class PluginExtension {
 public:
  virtual ~PluginExtension() = default;
  virtual const std::string& kind() const = 0;            // "simulated device types"
  virtual const std::type_info& registry_type() const = 0;
  virtual void* registry() = 0;
  // An empty registry of the same kind, for a plugin to register into before it is checked.
  virtual std::unique_ptr<PluginExtension> fresh() const = 0;
  virtual std::vector<std::string> names() const = 0;     // what it holds
  virtual bool has(const std::string& name) const = 0;
  virtual void merge(PluginExtension& from) = 0;          // `from` is of the same kind
};

// The PluginExtension of a registry: default-constructible, with names(), has(name) and
// merge(Registry&&) (which may assume that none of the other's names is already there).
template <class Registry>
class Extension final : public PluginExtension {
 public:
  Extension(std::string kind, Registry& registry) : kind_(std::move(kind)), registry_(&registry) {}

  const std::string& kind() const override { return kind_; }
  const std::type_info& registry_type() const override { return typeid(Registry); }
  void* registry() override { return registry_; }
  std::unique_ptr<PluginExtension> fresh() const override {
    auto owned = std::make_unique<Registry>();
    auto e = std::make_unique<Extension>(kind_, *owned);
    e->owned_ = std::move(owned);
    return e;
  }
  std::vector<std::string> names() const override { return registry_->names(); }
  bool has(const std::string& name) const override { return registry_->has(name); }
  void merge(PluginExtension& from) override {
    registry_->merge(std::move(*static_cast<Registry*>(from.registry())));
  }

 private:
  std::string kind_;
  Registry* registry_;
  std::unique_ptr<Registry> owned_;  // a fresh() one's
};

// What a plugin's registration adds to: a server's behavior types, adaptor types and composers,
// and whatever registries the program loading it offers besides.
struct PluginRegistrar {
  behavior::BehaviorRegistry& behaviors;
  service::AdaptorFactory& adaptors;
  std::vector<service::MakeComposer>& composers;
  std::vector<PluginExtension*> extensions = {};

  // The program's registry of type Registry; throws PluginError when it offers none (the
  // plugin is then refused: a plugin for `icars run` loaded by a program without a house).
  template <class Registry>
  Registry& extension() {
    for (auto* e : extensions) {
      if (e->registry_type() == typeid(Registry)) return *static_cast<Registry*>(e->registry());
    }
    no_extension(typeid(Registry));
  }

 private:
  [[noreturn]] static void no_extension(const std::type_info& type);
};

// Every plugin exports one, `icars_plugin_abi`, read before any of its code runs.
struct PluginAbi {
  std::uint32_t api;    // kPluginApi of the ICARS it was built against
  const char* version;  // ICARS_VERSION of the ICARS it was built against
};

// What a loaded plugin added.
struct LoadedPlugin {
  std::string path;
  std::vector<std::string> behaviors;   // behavior types
  std::vector<std::string> interfaces;  // interface ids it has adaptors for
  std::size_t composers = 0;
  // For each extension that it added to: its kind and what it added.
  std::vector<std::pair<std::string, std::vector<std::string>>> extended;
};

// Loads the plugin at `path` and adds what it registers to `into`. The library stays loaded
// until the process ends: what it registered runs its code. Throws PluginError.
LoadedPlugin load_plugin(const std::string& path, PluginRegistrar into);

}  // namespace icars::server

// Defines a plugin's entry point; the block that follows is its registration, given a
// PluginRegistrar named by the argument. Use once per plugin, at namespace scope.
#define ICARS_PLUGIN(registrar)                                                                 \
  static void icars_plugin_registration(::icars::server::PluginRegistrar& registrar);          \
  extern "C" __attribute__((visibility("default"))) const ::icars::server::PluginAbi          \
      icars_plugin_abi{::icars::server::kPluginApi, ICARS_VERSION};                           \
  extern "C" __attribute__((visibility("default"))) void icars_plugin_register(               \
      ::icars::server::PluginRegistrar& into) {                                               \
    icars_plugin_registration(into);                                                          \
  }                                                                                           \
  static void icars_plugin_registration(::icars::server::PluginRegistrar& registrar)
