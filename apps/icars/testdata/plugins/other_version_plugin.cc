// A plugin built against another ICARS: its record says so, and it is refused before any of
// its code runs.
#include <cstdlib>

#include "icars/server/plugin.h"

extern "C" __attribute__((visibility("default"))) const icars::server::PluginAbi icars_plugin_abi{
    icars::server::kPluginApi + 1, "0.0.1"};

extern "C" __attribute__((visibility("default"))) void icars_plugin_register(icars::server::PluginRegistrar&) {
  std::abort();  // never called
}
