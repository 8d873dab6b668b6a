// The tutorial as a user runs it (docs/tutorial.md, step 6): the ordinary `icars` program with
// the tutorial plugin, on the tutorial's flat through a hot afternoon, read back from its trace.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "house_processes.h"
#include "icars/clock/time.h"
#include "program_run.h"

namespace {

using json = nlohmann::json;
using icars_test::str;
using namespace std::chrono_literals;

const std::string kIcars = ICARS_BINARY;
const std::string kDir = ICARS_TUTORIAL_DIR;
const std::string kPlugin = ICARS_TUTORIAL_PLUGIN;
const std::string kPolicy = kDir + "/cooling.xml";
const std::string kHouse = kDir + "/tutorial_house.xml";

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

icars::Time at(const json& record) { return icars::Time(record.at("t").get<std::int64_t>()); }

// Whether `t` is within five minutes after hh:mm of day 0.
bool just_after(icars::Time t, int hh, int mm) {
  const auto from = icars::at_time(0, hh, mm);
  return t >= from && t <= from + 5min;
}

TEST(Tutorial, RunsAsAPluginOfIcarsThroughAHotAfternoon) {
  const auto trace_file = icars_test::temp_path("tutorial", "trace.jsonl");
  const auto r = icars_test::run_program(
      kIcars, "run " + kPolicy + " --world " + kHouse + " --plugin " + kPlugin + " --until 19:00 --speed 5000 --quiet --trace " + trace_file);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto trace = icars_test::read_json_lines(trace_file);
  std::remove(trace_file.c_str());

  std::vector<json> transitions, fan, stays_on;
  for (const auto& record : trace) {
    if (str(record, "kind") == "transition") transitions.push_back(record);
    if (str(record, "kind") == "effect" && str(record, "source") == "living_fan") fan.push_back(record);
    if (str(record, "kind") == "note" && str(record, "source") == "Cool/CoolDown" &&
        str(record, "text").ends_with("25.0 C: the fan stays on")) {
      stays_on.push_back(record);
    }
  }
  // The statechart: Normal until the afternoon sun (14:00, 28.5 C), Cooling until the evening
  // (18:00, 23.5 C); 25 C at 16:00 is between the two states' thresholds and changes nothing.
  ASSERT_EQ(transitions.size(), 2u) << r.output;
  EXPECT_EQ(str(transitions[0], "text"), "Normal -> Cooling on TooHot");
  EXPECT_TRUE(just_after(at(transitions[0]), 14, 0)) << transitions[0].dump();
  EXPECT_EQ(str(transitions[1], "text"), "Cooling -> Normal on Comfortable");
  EXPECT_TRUE(just_after(at(transitions[1]), 18, 0)) << transitions[1].dump();
  // The fan, as the simulated house saw it: on once, off once.
  ASSERT_EQ(fan.size(), 2u) << r.output;
  EXPECT_EQ(str(fan[0], "text"), "living_fan: speed 100%");
  EXPECT_TRUE(just_after(at(fan[0]), 14, 0)) << fan[0].dump();
  EXPECT_EQ(str(fan[1], "text"), "living_fan: speed 0%");
  EXPECT_TRUE(just_after(at(fan[1]), 18, 0)) << fan[1].dump();
  ASSERT_EQ(stays_on.size(), 1u) << r.output;
  EXPECT_TRUE(just_after(at(stays_on[0]), 16, 0)) << stays_on[0].dump();
}

TEST(Tutorial, IcarsListsWhatThePluginAdds) {
  const auto r = icars_test::run_program(kIcars, "behaviors --plugin " + kPlugin);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(contains(r.output, "CoolDown: ")) << r.output;
  EXPECT_TRUE(contains(r.output, "adaptors for 2 interfaces: tutorial::Fan, tutorial::Thermometer")) << r.output;
  EXPECT_TRUE(contains(r.output, ": simulated device types SmartFan")) << r.output;
}

TEST(Tutorial, AHouseWithAFanNeedsThePluginAndAProfile) {
  // Without the plugin, the house names a device type nobody simulates.
  auto r = icars_test::run_program(kIcars, "run " + std::string(ICARS_SOURCE_DIR) +
                                               "/examples/smart_home/paper_home.xml --world " + kHouse +
                                               " --until 12:30 --quiet");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_TRUE(contains(r.output, "device living_fan has type 'SmartFan', which has no simulated implementation"))
      << r.output;
  // A temperature profile the fan cannot read.
  std::ifstream in(kHouse);
  std::string house((std::istreambuf_iterator<char>(in)), {});
  const std::string good = "06:00 21; 12:00 22;";
  ASSERT_NE(house.find(good), std::string::npos);
  house.replace(house.find(good), good.size(), "06:00 21; noon 22;");
  const auto broken = icars_test::temp_path("tutorial", "broken_house.xml");
  std::ofstream(broken) << house;
  r = icars_test::run_program(kIcars, "run " + kPolicy + " --world " + broken + " --plugin " + kPlugin +
                                          " --until 12:30 --quiet");
  std::remove(broken.c_str());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_TRUE(contains(r.output, "SmartFan living_fan: temperature step ' noon 22' is not 'HH:MM CELSIUS'"))
      << r.output;
}

}  // namespace
