#include "icars/server/plugin.h"

#include <cxxabi.h>
#include <dlfcn.h>
#include <fmt/format.h>

#include <cstdlib>
#include <cstring>
#include <memory>

namespace icars::server {
namespace {

using Register = void (*)(PluginRegistrar&);

struct Library {
  void* handle = nullptr;
  ~Library() {
    if (handle != nullptr) ::dlclose(handle);
  }
  void keep() { handle = nullptr; }  // loaded until the process ends
};

std::string last_dl_error() {
  const char* e = ::dlerror();
  return e != nullptr ? e : "unknown error";
}

}  // namespace

void PluginRegistrar::no_extension(const std::type_info& type) {
  int status = 0;
  std::unique_ptr<char, void (*)(void*)> name(abi::__cxa_demangle(type.name(), nullptr, nullptr, &status), std::free);
  throw PluginError(fmt::format("this program offers plugins no {}", status == 0 ? name.get() : type.name()));
}

LoadedPlugin load_plugin(const std::string& path, PluginRegistrar into) {
  const auto refuse = [&](const std::string& why) { return PluginError(fmt::format("plugin {}: {}", path, why)); };
  Library library;
  // A path without '/' would be looked up in the library search path, not the working directory.
  const std::string file = path.find('/') == std::string::npos ? "./" + path : path;
  library.handle = ::dlopen(file.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (library.handle == nullptr) throw refuse("cannot be loaded: " + last_dl_error());

  const auto* abi = static_cast<const PluginAbi*>(::dlsym(library.handle, "icars_plugin_abi"));
  if (abi == nullptr) {
    throw refuse(
        "not an ICARS plugin: it exports no icars_plugin_abi (a plugin defines its entry with "
        "ICARS_PLUGIN, icars/server/plugin.h)");
  }
  const char* version = abi->version != nullptr ? abi->version : "(none)";
  if (abi->api != kPluginApi || std::strcmp(version, ICARS_VERSION) != 0) {
    throw refuse(fmt::format(
        "built against ICARS {} (plugin API {}), but this program is ICARS {} (plugin API {}): "
        "rebuild the plugin against this version",
        version, abi->api, ICARS_VERSION, kPluginApi));
  }
  auto* entry = reinterpret_cast<Register>(::dlsym(library.handle, "icars_plugin_register"));
  if (entry == nullptr) throw refuse("exports icars_plugin_abi but no icars_plugin_register entry");

  LoadedPlugin loaded;
  loaded.path = path;
  {
    // The plugin registers into registries of its own, checked against `into` before anything
    // is added: a refused plugin adds nothing, and its code is gone with these before dlclose.
    behavior::BehaviorRegistry behaviors;
    service::AdaptorFactory adaptors;
    std::vector<service::MakeComposer> composers;
    std::vector<std::unique_ptr<PluginExtension>> extensions;
    PluginRegistrar mine{behaviors, adaptors, composers};
    for (auto* e : into.extensions) {
      extensions.push_back(e->fresh());
      mine.extensions.push_back(extensions.back().get());
    }
    try {
      entry(mine);
    } catch (const std::exception& e) {
      throw refuse(std::string("its registration failed: ") + e.what());
    } catch (...) {
      throw refuse("its registration threw something that is not a std::exception");
    }
    for (const auto& type : behaviors.types()) {
      if (into.behaviors.find(type) != nullptr) {
        throw refuse(fmt::format("it adds behavior type '{}', which is already registered", type));
      }
    }
    for (const auto& id : adaptors.interface_ids()) {
      if (into.adaptors.knows(id)) {
        throw refuse(fmt::format("it adds an adaptor for interface '{}', which already has one", id));
      }
    }
    for (std::size_t i = 0; i < composers.size(); ++i) {
      if (!composers[i]) throw refuse(fmt::format("its composer {} is empty", i + 1));
    }
    for (std::size_t i = 0; i < extensions.size(); ++i) {
      for (const auto& name : extensions[i]->names()) {
        if (into.extensions[i]->has(name)) {
          throw refuse(fmt::format("it adds '{}' to the {}, which already has it", name, into.extensions[i]->kind()));
        }
      }
    }
    loaded.behaviors = behaviors.types();
    loaded.interfaces = adaptors.interface_ids();
    loaded.composers = composers.size();
    into.behaviors.merge(std::move(behaviors));
    into.adaptors.merge(std::move(adaptors));
    for (auto& c : composers) into.composers.push_back(std::move(c));
    for (std::size_t i = 0; i < extensions.size(); ++i) {
      auto names = extensions[i]->names();
      if (names.empty()) continue;
      into.extensions[i]->merge(*extensions[i]);
      loaded.extended.emplace_back(into.extensions[i]->kind(), std::move(names));
    }
  }
  library.keep();
  return loaded;
}

}  // namespace icars::server
