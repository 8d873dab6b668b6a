// A plugin that needs a function no program provides: it cannot be loaded.
#include "icars/server/plugin.h"

extern "C" void icars_function_nobody_defines();

ICARS_PLUGIN(registrar) {
  (void)registrar;
  icars_function_nobody_defines();
}
