// A shared library without an ICARS_PLUGIN entry.
extern "C" __attribute__((visibility("default"))) int lamp_brightness() { return 42; }
