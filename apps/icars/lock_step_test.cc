// Lock-step, as `icars run` on the embedded house runs by default: the clock moves only when the
// mediator and the devices have finished reacting, so a reaction comes at the simulated instant
// of its cause, and the paper policy's evening is the same trace at 600x and as fast as the
// machine goes — its transitions, tasks, calls, commands and effects, times included.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "traced_run.h"

namespace {

using nlohmann::json;
using icars_test::str;

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;

icars_test::TracedRun paper_evening(const std::string& speed) {
  return icars_test::run_traced(kIcars, "run " + kSource + "/examples/smart_home/paper_home.xml --world " + kSource +
                                            "/houses/paper_house.xml --until 23:30 --quiet --speed " + speed,
                                600);
}

// What the policy did and what the house did about it: "<time> <kind> <text>", in order of
// time. Records of one instant are sorted: work that runs concurrently within an instant (two
// behaviors' calls) may be written in either order, at the same time.
std::vector<std::string> what_happened(const std::vector<json>& trace) {
  static const std::set<std::string> kinds = {"policy", "state", "transition", "task", "behavior",
                                              "event",  "call",  "command",    "speech", "effect"};
  std::map<std::string, std::vector<std::string>> by_time;  // "time" sorts as it reads
  for (const auto& r : trace) {
    if (!kinds.contains(str(r, "kind"))) continue;
    // Request ids number a run's commands: commands sent at one instant may be numbered in
    // another order, so a command is told by what it asked of which device.
    const auto what = str(r, "kind") == "command"
                          ? str(r, "event") + " " + str(r, "device") + "." + str(r, "capability") + "." + str(r, "method")
                          : str(r, "text");
    by_time[str(r, "time")].push_back(str(r, "kind") + " " + what);
  }
  std::vector<std::string> out;
  for (auto& [time, records] : by_time) {
    std::sort(records.begin(), records.end());
    for (auto& r : records) out.push_back(time + " " + r);
  }
  return out;
}

TEST(LockStep, ThePaperEveningIsTheSameTraceAt600xAndAtFullSpeed) {
  const auto paced = paper_evening("600");
  const auto fastest = paper_evening("max");
  ASSERT_EQ(paced.run.exit_code, 0) << paced.run.output;
  ASSERT_EQ(fastest.run.exit_code, 0) << fastest.run.output;
  EXPECT_NE(paced.run.output.find("lock-step at 600x"), std::string::npos) << paced.run.output;
  EXPECT_NE(fastest.run.output.find("lock-step as fast as possible"), std::string::npos) << fastest.run.output;

  const auto a = what_happened(paced.trace);
  const auto b = what_happened(fastest.trace);
  // The evening did happen: rest, voice commands, then sleep.
  const auto has = [&](const std::string& what) {
    return std::any_of(a.begin(), a.end(), [&](const std::string& line) { return line.find(what) != std::string::npos; });
  };
  EXPECT_TRUE(has("state entered RestMode"));
  EXPECT_TRUE(has("state entered SleepMode"));
  EXPECT_TRUE(has("speech robot1_mic heard"));
  EXPECT_TRUE(has("effect tv: power on"));
  ASSERT_GT(a.size(), 100u);
  // Identical, line by line; on a difference, the first one says where the runs parted.
  const auto parted = std::mismatch(a.begin(), a.end(), b.begin(), b.end());
  EXPECT_TRUE(parted.first == a.end() && parted.second == b.end())
      << "at 600x: " << (parted.first == a.end() ? "(end)" : *parted.first) << "\n"
      << "at max:  " << (parted.second == b.end() ? "(end)" : *parted.second);
  EXPECT_EQ(a.size(), b.size());
  for (const auto& r : fastest.trace) {
    EXPECT_NE(str(r, "text").find("lock-step: work started"), 0u) << "a settle timed out: " << r.dump();
  }
}

// At any speed a command's effect is at the instant the mediator sent it: the device heard it
// before the clock moved on.
TEST(LockStep, EveryCommandTakesEffectAtTheInstantItWasSent) {
  const auto r = paper_evening("max");
  ASSERT_EQ(r.run.exit_code, 0) << r.run.output;
  std::map<std::int64_t, std::string> sent;  // request -> time
  for (const auto& j : r.trace) {
    if (str(j, "kind") == "command" && str(j, "event") == "sent") sent[j.value("request", std::int64_t{0})] = str(j, "time");
  }
  int effects = 0;
  for (const auto& j : r.trace) {
    if (str(j, "kind") != "effect") continue;
    const auto request = j.value("request", std::int64_t{0});
    if (request == 0) continue;  // the world's own doing (a robot arriving)
    ++effects;
    const auto it = sent.find(request);
    ASSERT_NE(it, sent.end()) << j.dump();
    EXPECT_EQ(str(j, "time"), it->second) << "the effect of command " << request << " came later: " << j.dump();
  }
  EXPECT_GT(effects, 10);
}

TEST(LockStep, MaxSpeedNeedsTheLockStepClock) {
  for (const std::string extra : {" --free-running", " --external"}) {
    const auto r = icars_test::run_program(kIcars, "run " + kSource + "/examples/smart_home/paper_home.xml --world " +
                                                       kSource + "/houses/paper_house.xml --speed max" + extra, 60);
    EXPECT_EQ(r.exit_code, 2) << r.output;
    EXPECT_NE(r.output.find("--speed max needs the lock-step clock"), std::string::npos) << r.output;
  }
  const auto bad = icars_test::run_program(kIcars, "run " + kSource + "/examples/smart_home/paper_home.xml --world " +
                                                       kSource + "/houses/paper_house.xml --speed fast", 60);
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.output.find("fast is neither a number in [1, 100000] nor 'max'"), std::string::npos) << bad.output;
}

}  // namespace
