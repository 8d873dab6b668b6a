// The elder-care example (examples/eldercare) as its user runs it, read back from the trace:
// a policy written without C++ — voice-controlled lights and TV through a command table, a
// parallel region watching the hall while the robot assists, a night without music — on a
// flat of its own.
#include <gtest/gtest.h>

#include <algorithm>

#include <nlohmann/json.hpp>

#include <functional>
#include <string>
#include <vector>

#include "traced_run.h"

namespace {

using nlohmann::json;

const std::string kIcars = ICARS_BINARY;
const std::string kExample = std::string(ICARS_SOURCE_DIR) + "/examples/eldercare";

using icars_test::str;

// Predicates over trace records.
using Pred = std::function<bool(const json&)>;
Pred effect(const std::string& device, const std::string& what, const std::string& value) {
  return [=](const json& j) { return str(j, "kind") == "effect" && str(j, "device") == device && str(j, "what") == what && str(j, "value") == value; };
}
Pred heard(const std::string& words) {
  return [=](const json& j) { return str(j, "kind") == "speech" && str(j, "words") == words; };
}
Pred entered(const std::string& state) {
  return [=](const json& j) { return str(j, "kind") == "state" && str(j, "event") == "enter" && str(j, "state") == state; };
}
Pred task(const std::string& name, const std::string& what) {
  return [=](const json& j) { return str(j, "kind") == "task" && str(j, "text") == "task " + name + " " + what; };
}

// One evening run, read section by section.
TEST(Eldercare, AnEveningInTheFlatReadFromItsTrace) {
  const auto validated = icars_test::run_program(kIcars, "validate " + kExample + "/eldercare.xml --world " + kExample + "/flat.xml", 60);
  EXPECT_EQ(validated.exit_code, 0) << validated.output;
  EXPECT_NE(validated.output.find("ok: policy eldercare, 5 tasks"), std::string::npos) << validated.output;

  const auto r = icars_test::run_traced(kIcars, "run " + kExample + "/eldercare.xml --world " + kExample +
                                                    "/flat.xml --speed max --until 21:45 --quiet", 600);
  const auto& t = r.trace;
  const std::size_t n = t.size();
  ASSERT_EQ(r.run.exit_code, 0) << r.run.output;
  ASSERT_GT(n, 100u) << r.run.output;
  // The first record at or after `from` matching `pred`, or n.
  const auto find = [&](std::size_t from, const Pred& pred) {
    for (std::size_t i = from; i < n; ++i) {
      if (pred(t[i])) return i;
    }
    return n;
  };

  {
    SCOPED_TRACE("both regions run while she sits in the armchair");
    const auto evening = find(0, entered("Evening"));
    ASSERT_LT(evening, n);
    EXPECT_LT(find(evening, task("Assist", "started")), n);
    EXPECT_LT(find(evening, task("WatchDoor", "started")), n);
  }
  {
    SCOPED_TRACE("the command table drives the lamp and the TV");
    const auto evening = find(0, entered("Evening"));
    const auto lights_on = find(evening, heard("lights on"));
    ASSERT_LT(lights_on, n) << "the robot did not hear her: it did not come to the armchair";
    EXPECT_LT(find(lights_on, effect("living_lamp", "power", "on")), n);
    const auto dim = find(lights_on, heard("dim the lights to 30"));
    ASSERT_LT(dim, n);
    EXPECT_LT(find(dim, effect("living_lamp", "intensity", "30")), n);
    // "(tv|television) (on|off)": either phrase is the same command.
    const auto tv_on = std::min(find(dim, heard("television on")), find(dim, heard("tv on")));
    ASSERT_LT(tv_on, n);
    EXPECT_LT(find(tv_on, effect("tv", "power", "on")), n);
    const auto tv_off = std::min(find(tv_on, heard("television off")), find(tv_on, heard("tv off")));
    ASSERT_LT(tv_off, n);
    EXPECT_LT(find(tv_off, effect("tv", "power", "off")), n);
  }
  {
    SCOPED_TRACE("the hall is watched while the robot assists");
    const auto reminding = find(0, entered("Reminding"));
    ASSERT_LT(reminding, n) << "nobody noticed her going to the front door";
    EXPECT_EQ(str(t[reminding], "time").substr(0, 8), "d0 19:00") << t[reminding].dump();
    EXPECT_LT(find(reminding, effect("hall_light", "intensity", "80")), n);
    EXPECT_LT(find(reminding, effect("hall_light", "power", "on")), n);
    EXPECT_LT(find(reminding, effect("companion_voice", "spoke", "Going out? Take your keys.")), n);
    // The assistance went on meanwhile: its task was not stopped, and she could still turn the TV off.
    const auto back = find(reminding, entered("Watching"));
    ASSERT_LT(back, n);
    EXPECT_GT(find(0, task("Assist", "stopped")), back);
    EXPECT_LT(find(back, effect("tv", "power", "off")), n);
  }
  {
    SCOPED_TRACE("at night the flat goes dark without music");
    const auto asleep = find(0, entered("Asleep"));
    ASSERT_LT(asleep, n);
    EXPECT_EQ(str(t[asleep], "time").substr(0, 8), "d0 21:30") << t[asleep].dump();
    EXPECT_LT(find(asleep, effect("living_lamp", "power", "off")), n);
    EXPECT_LT(find(asleep, effect("hall_light", "power", "off")), n);
    EXPECT_LT(find(0, task("Assist", "stopped")), n);
    EXPECT_EQ(find(0, [](const json& j) { return str(j, "kind") == "effect" && str(j, "what") == "playing"; }), n)
        << "no music all evening";
  }
}

}  // namespace
