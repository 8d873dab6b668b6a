// Plugins loaded by the real `icars` program: a plugin's behavior type runs in a policy, `icars
// behaviors` lists what a plugin adds, and every way a plugin can be unusable (no file, not a
// shared library, a symbol nobody provides, no entry, another ICARS version, a registration
// that throws, a type that is already there) stops the command with exit code 2 and a message
// naming the file and the reason.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <iterator>
#include <string>

#include "program_run.h"

namespace {

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kHouse = kSource + "/houses/paper_house.xml";
const std::string kBlinkPolicy = kSource + "/apps/icars/testdata/blink.xml";
const std::string kLamp = ICARS_LAMP_PLUGIN;

icars_test::ProgramRun icars(const std::string& args) { return icars_test::run_program(kIcars, args, 300); }

std::string temp(const std::string& name) { return icars_test::temp_path("icars_plugin", name); }

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

TEST(IcarsPlugin, APluginsBehaviorRunsInAPolicyAndIsListed) {
  // Without the plugin the policy names an unknown behavior type...
  auto r = icars("validate " + kBlinkPolicy);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_TRUE(contains(r.output, "Blink")) << r.output;
  // ...with it, the policy is valid and runs: Blink propagates its event, and the statechart
  // takes the transition.
  r = icars("validate " + kBlinkPolicy + " --plugin " + kLamp);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  const auto trace = temp("trace.jsonl");
  r = icars("run " + kBlinkPolicy + " --plugin " + kLamp + " --world " + kHouse +
            " --until 18:05 --quiet --trace " + trace);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  std::ifstream t(trace);
  const std::string records((std::istreambuf_iterator<char>(t)), {});
  std::remove(trace.c_str());
  EXPECT_TRUE(contains(records, R"("text":"Starting -> Blinked on Blinked")")) << records.substr(0, 2000);

  r = icars("behaviors --plugin " + kLamp);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(contains(r.output, "Blink: emits an event once and succeeds (plugin " + kLamp + ")")) << r.output;
  EXPECT_TRUE(contains(r.output, "Wait: ")) << r.output;  // the built-in types are still there
  EXPECT_TRUE(contains(r.output, "plugin " + kLamp +
                                     ": 1 behavior types, adaptors for 1 interfaces: test::Lamp, 1 composers"))
      << r.output;
}

struct Broken {
  std::string plugin;
  std::string reason;
};

class IcarsBrokenPlugin : public ::testing::TestWithParam<Broken> {};

TEST_P(IcarsBrokenPlugin, StopsEveryCommandWithExitCodeTwoAndTheReason) {
  const auto& [plugin, reason] = GetParam();
  const std::string expected = "plugin " + plugin + ": ";
  for (const auto& command : {"behaviors --plugin " + plugin, "validate " + kBlinkPolicy + " --plugin " + plugin,
                              "run " + kBlinkPolicy + " --world " + kHouse + " --until 18:05 --quiet --plugin " + plugin}) {
    const auto r = icars(command);
    EXPECT_EQ(r.exit_code, 2) << command << "\n" << r.output;
    EXPECT_TRUE(contains(r.output, expected)) << command << "\n" << r.output;
    EXPECT_TRUE(contains(r.output, reason)) << command << "\n" << r.output;
  }
}

std::string text_file() {
  static const std::string path = [] {
    const auto p = temp("text.so");
    std::ofstream(p) << "this is not a shared library\n";
    return p;
  }();
  return path;
}

std::string broken_name(const ::testing::TestParamInfo<Broken>& info) {
  static const char* const names[] = {"NoFile",         "NotASharedLibrary",  "ASymbolNobodyProvides", "NoEntry",
                                      "AnotherVersion", "RegistrationThrows", "ATypeAlreadyThere"};
  return names[info.index];
}

INSTANTIATE_TEST_SUITE_P(
    EachWay, IcarsBrokenPlugin,
    ::testing::Values(
        Broken{"/nonexistent/lamp.so", "cannot be loaded: /nonexistent/lamp.so: cannot open shared object file"},
        Broken{text_file(), "cannot be loaded: "},
        Broken{ICARS_MISSING_SYMBOL_PLUGIN, "undefined symbol: icars_function_nobody_defines"},
        Broken{ICARS_NOT_A_PLUGIN, "not an ICARS plugin: it exports no icars_plugin_abi"},
        Broken{ICARS_OTHER_VERSION_PLUGIN, "built against ICARS 0.0.1 (plugin API 2), but this program is ICARS"},
        Broken{ICARS_THROWING_PLUGIN, "its registration failed: the lamp's licence file is missing"},
        Broken{ICARS_DUPLICATE_PLUGIN, "it adds behavior type 'Wait', which is already registered"}),
    broken_name);

TEST(IcarsPlugin, TheSamePluginTwiceIsADuplicate) {
  const auto r = icars("behaviors --plugin " + kLamp + " --plugin " + kLamp);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_TRUE(contains(r.output, "it adds behavior type 'Blink', which is already registered")) << r.output;
}

}  // namespace
