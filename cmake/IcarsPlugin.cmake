# icars_add_plugin(<name> <sources...>)
#
# Builds a plugin of the `icars` program (docs/plugins.md): a shared library <name>.so, loaded
# with `icars run|validate|behaviors --plugin <name>.so`, whose ICARS_PLUGIN entry
# (icars/server/plugin.h) registers behavior types, adaptors, composers and simulated device
# types. It links no ICARS library, only icars::plugin_api (headers and definitions): `icars`
# exports every ICARS symbol, so the process holds one copy of each class and registry. Build
# it with the compiler and flags ICARS was built with.
#
# In this project and, after find_package(ICARS), in any other.
include_guard(GLOBAL)

function(icars_add_plugin name)
  add_library(${name} MODULE ${ARGN})
  target_link_libraries(${name} PRIVATE icars::plugin_api)
  if(TARGET icars_warnings)
    target_link_libraries(${name} PRIVATE icars_warnings)
  endif()
  set_target_properties(${name} PROPERTIES PREFIX "")
endfunction()
