// `icars` as a user runs it: real processes, the embedded simulated house over loopback PLANET,
// and the JSON-lines trace read back to check what happened, in order.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <algorithm>
#include <functional>
#include <set>
#include <string>
#include <unistd.h>
#include <vector>

#include "icars/sim/house.h"
#include "announcement.h"
#include "child_process.h"
#include "traced_run.h"
#include "broker.h"

using nlohmann::json;

namespace {

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kDeviceManager = ICARS_DEVICE_MANAGER_BINARY;
const std::string kMqttBridge = ICARS_MQTT_BRIDGE_BINARY;

struct Run {
  int exit_code = -1;
  std::string output;
  std::vector<json> trace;
};

Run run_icars(const std::string& args, bool with_trace = true) {
  if (!with_trace) {
    auto r = icars_test::run_program(kIcars, args);
    return {r.exit_code, std::move(r.output), {}};
  }
  auto r = icars_test::run_traced(kIcars, args);
  return {r.run.exit_code, std::move(r.run.output), std::move(r.trace)};
}

using icars_test::str;

// The index of the first record at or after `from` matching `pred`, or trace.size().
std::size_t find(const std::vector<json>& trace, std::size_t from, const std::function<bool(const json&)>& pred) {
  for (std::size_t i = from; i < trace.size(); ++i) {
    if (pred(trace[i])) return i;
  }
  return trace.size();
}

auto transition_to(const std::string& state) {
  return [state](const json& j) { return str(j, "kind") == "transition" && str(j, "to") == state; };
}
auto effect(const std::string& device, const std::string& what, const std::string& value) {
  return [=](const json& j) {
    return str(j, "kind") == "effect" && str(j, "device") == device && str(j, "what") == what && str(j, "value") == value;
  };
}
auto event(const std::string& type) {
  return [type](const json& j) { return str(j, "kind") == "event" && str(j, "event") == type; };
}
auto user(const std::string& posture, const std::string& furniture) {
  return [=](const json& j) {
    return str(j, "kind") == "user" && str(j, "posture") == posture && str(j, "furniture") == furniture;
  };
}

// What the paper policy does on the paper's house (or a house with the same rooms, devices and
// user, however its devices are reached), evening to morning, read from the trace.
void expect_the_paper_night(const Run& r) {
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto& t = r.trace;
  const auto n = t.size();
  ASSERT_GT(n, 100u) << r.output;

  // The user sits on the sofa → RestMode; the robot reaches the user.
  const auto sits = find(t, 0, user("sitting", "sofa"));
  ASSERT_LT(sits, n);
  const auto rest = find(t, sits, transition_to("RestMode"));
  ASSERT_LT(rest, n) << "no RestMode after the user sat down";
  const auto reached = find(t, rest, event("ReachedUser"));
  ASSERT_LT(reached, n) << "the robot did not reach the user";
  // "turn on the TV" → the TV is on, and the other commands of the evening are served.
  const auto heard = find(t, reached, [](const json& j) { return str(j, "kind") == "speech" && str(j, "words") == "turn on the tv"; });
  ASSERT_LT(heard, n);
  EXPECT_LT(find(t, heard, effect("tv", "power", "on")), n) << "the TV did not turn on";
  EXPECT_LT(find(t, heard, [](const json& j) { return str(j, "call").starts_with("robot1_wheels.wheels.turn_to("); }), n)
      << "LookAtSound did not turn the robot towards the voice";
  EXPECT_LT(find(t, heard, effect("tv", "channel", "5")), n);
  EXPECT_LT(find(t, heard, effect("robot1_speaker", "playing", "relaxing music")), n);

  // The user lies in bed at night → SleepMode: lights off, calm music, every patrol waypoint.
  const auto lies = find(t, reached, user("lying", "bed"));
  ASSERT_LT(lies, n);
  const auto sleep = find(t, lies, transition_to("SleepMode"));
  ASSERT_LT(sleep, n) << "no SleepMode after the user lay down";
  EXPECT_LT(find(t, sleep, effect("living_light", "power", "off")), n);
  EXPECT_LT(find(t, sleep, effect("bedroom_light", "power", "off")), n);
  const auto music = find(t, sleep, effect("robot1_speaker", "playing", "calm music"));
  EXPECT_LT(music, n);
  EXPECT_LT(find(t, music, effect("robot1_speaker", "stopped", "")), n) << "the calm music never stopped";
  const auto house = icars::sim::load_house(kSource + "/houses/paper_house.xml");
  std::size_t at = sleep;
  int patrol_points = 0;
  for (const auto& w : house.waypoints) {
    if (std::find(w.tags.begin(), w.tags.end(), "patrol") == w.tags.end()) continue;
    ++patrol_points;
    const auto visit = find(t, at, [&](const json& j) { return str(j, "event") == "WaypointReached" && j.value(json::json_pointer("/properties/waypoint"), std::string()) == w.name; });
    EXPECT_LT(visit, n) << "the patrol did not visit " << w.name;
    if (visit < n) at = visit;  // in the house's order
  }
  EXPECT_EQ(patrol_points, 6);

  // The user gets up in the morning → back to Observation.
  const auto gets_up = find(t, sleep, [](const json& j) { return str(j, "kind") == "user" && str(j, "posture") == "standing"; });
  ASSERT_LT(gets_up, n);
  EXPECT_LT(find(t, gets_up, transition_to("Observation")), n);

  // Nothing failed on the way.
  EXPECT_EQ(find(t, 0, [](const json& j) { return str(j, "kind") == "behavior" && str(j, "event") == "failure"; }), n);
  EXPECT_NE(r.output.find("voice commands heard: 5"), std::string::npos) << r.output;
}

}  // namespace

// The acceptance run: the shipped policy on the paper's house, evening to morning.
TEST(IcarsRun, ThePaperHomeFromEveningToMorning) {
  const auto plot = icars_test::temp_path("icars_run", "plot.svg");
  const auto r = run_icars("run " + kSource + "/examples/smart_home/paper_home.xml --world " + kSource +
                           "/houses/paper_house.xml --speed max --until 07:30 --quiet --plot " + plot);
  expect_the_paper_night(r);
  std::ifstream svg(plot);
  std::string drawing((std::istreambuf_iterator<char>(svg)), {});
  EXPECT_NE(drawing.find("<svg"), std::string::npos);
  EXPECT_NE(drawing.find("robot1"), std::string::npos);
  std::remove(plot.c_str());
}

// The same night on a house whose lights and bed and sofa sensors are MQTT devices: served on a
// real broker as zigbee2mqtt serves them and brought in by an MQTT bridge, the robot simulated.
// The policy is unchanged and the night the same; the lights' commands go through the broker
// and are done when the lamps' state topics confirm them.
TEST(IcarsRun, ThePaperHomeWithMqttLightsAndSensors) {
  bridge_test::Broker broker;
  const auto r = run_icars("run " + kSource + "/examples/smart_home/paper_home.xml --world " + kSource +
                           "/houses/paper_house_mqtt.xml --speed max --until 07:30 --quiet --mqtt mqtt://127.0.0.1:" +
                           std::to_string(broker.port()));
  expect_the_paper_night(r);
  // The lights' commands went through the MQTT bridge and none failed; in lock-step the lamp
  // turned off at the simulated instant of the command, as a PLANET lamp does.
  const auto& t = r.trace;
  const auto n = t.size();
  const auto off = find(t, 0, [](const json& j) {
    return str(j, "kind") == "call" && str(j, "call") == "living_light.light.set_power(false)";
  });
  ASSERT_LT(off, n);
  const auto effect_at = find(t, off, effect("living_light", "power", "off"));
  ASSERT_LT(effect_at, n);
  EXPECT_EQ(t[effect_at]["t"], t[off]["t"]) << t[off].dump() << "\n" << t[effect_at].dump();
  EXPECT_EQ(find(t, 0, [](const json& j) { return str(j, "kind") == "call" && j.contains("ok"); }), n)
      << "a call failed";
  // Without a broker, a house with MQTT devices is refused before anything starts.
  const auto refused = run_icars("run " + kSource + "/examples/smart_home/paper_home.xml --world " + kSource +
                                 "/houses/paper_house_mqtt.xml --speed max", false);
  EXPECT_EQ(refused.exit_code, 2);
  EXPECT_NE(refused.output.find("the house has MQTT devices"), std::string::npos) << refused.output;
}

// A second house and policy written only for tests: other names, guards, a hierarchical
// state, and a failure transition when the robot cannot reach the user.
TEST(IcarsRun, AnotherPolicyOnAnotherHouseTakesItsFailureTransition) {
  const auto r = run_icars("run " + kSource + "/apps/icars/testdata/night_light.xml --world " + kSource +
                           "/apps/icars/testdata/studio_house.xml --speed max --until 07:00 --quiet");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto& t = r.trace;
  const auto n = t.size();
  // A transition comes at the instant of what caused it, so it may be written just before the
  // record of the user's move (the world tells the sensor first, the trace after).
  const auto sat = find(t, 0, user("sitting", "couch"));
  const auto evening = find(t, 0, transition_to("Evening"));
  ASSERT_LT(sat, n) << r.output;
  ASSERT_LT(evening, n) << r.output;
  EXPECT_GE(t[evening]["t"].get<std::int64_t>(), t[sat]["t"].get<std::int64_t>());
  EXPECT_LT(find(t, evening, effect("desk_lamp", "power", "on")), n);
  EXPECT_LT(find(t, evening, effect("butler_voice", "spoke", "Good evening, Alice.")), n);
  const auto day = find(t, evening, transition_to("Day"));
  ASSERT_LT(day, n);
  const auto lay = find(t, day, user("lying", "futon"));
  const auto night = find(t, day, transition_to("Night"));
  ASSERT_LT(lay, n);
  ASSERT_LT(night, n);
  EXPECT_GE(t[night]["t"].get<std::int64_t>(), t[lay]["t"].get<std::int64_t>());
  EXPECT_LT(find(t, night, effect("desk_lamp", "power", "off")), n);
  const auto stranded = find(t, night, transition_to("Stranded"));
  ASSERT_LT(stranded, n) << "the unreachable user did not lead to the failure transition";
  EXPECT_EQ(str(t[stranded], "event"), "failed");
  EXPECT_NE(str(t[stranded], "text").find("alice not found in studio, loft"), std::string::npos) << t[stranded].dump();
  EXPECT_LT(find(t, stranded, effect("butler_voice", "spoke", "I cannot get to the loft.")), n);
  EXPECT_LT(find(t, stranded, transition_to("Day")), n) << "no way back in the morning";
}

TEST(IcarsValidate, TheShippedPoliciesAreValid) {
  const auto r = run_icars("validate " + kSource + "/examples/smart_home/paper_home.xml " + kSource +
                           "/apps/icars/testdata/night_light.xml", false);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("paper_home.xml: ok: policy paper_home, 4 tasks, 5 states, 0 warnings"), std::string::npos) << r.output;
}

TEST(IcarsValidate, BrokenPoliciesGetFileLineErrorsAndExitCodeOne) {
  const std::string dir = kSource + "/src/control/testdata/";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"malformed_xml.xml", "malformed_xml.xml:4:3: error: malformed XML: </task> closes <behavior> opened at line 3"},
      {"unknown_behavior.xml", "unknown_behavior.xml:4: error: unknown behavior type 'Wiat'"},
      {"bad_transition_target.xml", "bad_transition_target.xml:7: error: transition on 'Go' goes to state 'Nowhere'"},
      {"missing_attribute.xml", "missing_attribute.xml:3: error: <behavior> needs a 'type' attribute"},
  };
  for (const auto& [file, expected] : cases) {
    const auto r = run_icars("validate " + dir + file, false);
    EXPECT_EQ(r.exit_code, 1) << file << "\n" << r.output;
    EXPECT_NE(r.output.find(expected), std::string::npos) << r.output;
  }
  // A house policy naming a behavior the house registry lacks, or a file that is not there.
  const auto missing = run_icars("validate /nonexistent/policy.xml", false);
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_NE(missing.output.find("cannot read the policy file"), std::string::npos) << missing.output;
}

TEST(IcarsRun, BadInputIsAClearErrorBeforeAnythingStarts) {
  auto r = run_icars("run " + kSource + "/src/control/testdata/unknown_behavior.xml --world " + kSource +
                     "/houses/paper_house.xml", false);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("unknown behavior type 'Wiat'"), std::string::npos) << r.output;
  r = run_icars("run " + kSource + "/examples/smart_home/paper_home.xml --world /nonexistent/house.xml", false);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("/nonexistent/house.xml"), std::string::npos) << r.output;
  r = run_icars("run " + kSource + "/examples/smart_home/paper_home.xml --world " + kSource +
                "/houses/paper_house.xml --until 25:00", false);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("--until 25:00 is not a time of day"), std::string::npos) << r.output;
}

// The same binaries as separate processes: the mediator waits for a device manager started
// elsewhere and follows the house's simulated clock.
TEST(IcarsRun, ExternalDeviceManagerInItsOwnProcess) {
  const auto trace_file = icars_test::temp_path("icars_run", "external.jsonl");
  planet_test::ChildProcess mediator({kIcars, "run", kSource + "/examples/smart_home/paper_home.xml", "--world",
                                      kSource + "/houses/paper_house.xml", "--external", "--listen", "127.0.0.1:0",
                                      "--until", "18:30", "--trace", trace_file});
  std::string port;
  while (auto line = mediator.read_line(std::chrono::seconds(60))) {
    if (port = icars::app::announced_port(*line); !port.empty()) break;
  }
  ASSERT_FALSE(port.empty());
  planet_test::ChildProcess devices({kDeviceManager, "--house", kSource + "/houses/paper_house.xml", "--server",
                                     "127.0.0.1:" + port, "--speedup", "600"});
  bool summary = false;
  while (auto line = mediator.read_line(std::chrono::seconds(120))) summary |= line->starts_with("=== summary");
  const int status = mediator.wait();
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status;
  EXPECT_TRUE(summary);
  const auto t = icars_test::read_json_lines(trace_file);
  std::remove(trace_file.c_str());
  const auto n = t.size();
  const auto rest = find(t, 0, transition_to("RestMode"));
  ASSERT_LT(rest, n);
  const auto reached = find(t, rest, event("ReachedUser"));
  ASSERT_LT(reached, n);
  const auto heard = find(t, reached, [](const json& j) { return str(j, "kind") == "speech" && str(j, "words") == "turn on the tv"; });
  ASSERT_LT(heard, n);
  const auto call = find(t, heard, [](const json& j) { return str(j, "kind") == "call" && str(j, "call") == "tv.tv_control.set_power(true)"; });
  ASSERT_LT(call, n);
  EXPECT_EQ(find(t, call, [](const json& j) { return str(j, "kind") == "call" && j.contains("ok"); }), n) << "a call failed";
}

// The MQTT house as separate processes, as on a real home: the mediator, a device manager that
// serves the house's MQTT devices on a broker (as zigbee2mqtt would) and the rest over PLANET,
// and icars-mqtt-bridge placing the entities by the house file. The user sitting on the sofa
// reaches the policy through the broker and the bridge.
TEST(IcarsRun, ExternalMqttHouseThroughTheBridgeProgram) {
  bridge_test::Broker broker;
  const auto broker_uri = "mqtt://127.0.0.1:" + std::to_string(broker.port());
  const auto house = kSource + "/houses/paper_house_mqtt.xml";
  const auto trace_file = icars_test::temp_path("icars_run", "external_mqtt.jsonl");
  planet_test::ChildProcess mediator({kIcars, "run", kSource + "/examples/smart_home/paper_home.xml", "--world", house,
                                      "--external", "--listen", "127.0.0.1:0", "--until", "18:30", "--trace",
                                      trace_file});
  std::string port;
  while (auto line = mediator.read_line(std::chrono::seconds(60))) {
    if (port = icars::app::announced_port(*line); !port.empty()) break;
  }
  ASSERT_FALSE(port.empty());
  planet_test::ChildProcess bridge({kMqttBridge, "--broker", broker_uri, "--server", "127.0.0.1:" + port, "--house",
                                    house, "--client-id", "bridge-under-test"});
  planet_test::ChildProcess devices({kDeviceManager, "--house", house, "--server", "127.0.0.1:" + port, "--speedup",
                                     "300", "--mqtt", broker_uri});
  // The bridge names the entities as the house does.
  std::set<std::string> online;
  while (online.size() < 4) {
    const auto line = bridge.read_line(std::chrono::seconds(60));
    ASSERT_TRUE(line) << "the bridge did not bring the house's MQTT devices";
    if (line->starts_with("DEVICE ") && line->ends_with(" online")) online.insert(line->substr(7, line->find(' ', 7) - 7));
  }
  EXPECT_EQ(online, (std::set<std::string>{"living_light", "bedroom_light", "sofa_sensor", "bed_sensor"}));
  bool summary = false;
  std::string output;
  while (auto line = mediator.read_line(std::chrono::seconds(180))) {
    summary |= line->starts_with("=== summary");
    output += *line + "\n";
  }
  const int status = mediator.wait();
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status << "\n" << output;
  EXPECT_TRUE(summary) << output;
  const auto t = icars_test::read_json_lines(trace_file);
  std::remove(trace_file.c_str());
  const auto n = t.size();
  // Observation senses only the occupancy sensors, here MQTT devices: RestMode on TimeToRest
  // means the sofa's occupancy came through the broker and the bridge.
  const auto rest = find(t, 0, transition_to("RestMode"));
  ASSERT_LT(rest, n) << "the sofa's occupancy did not come through the broker; icars run said:\n" << output;
  EXPECT_EQ(str(t[rest], "event"), "TimeToRest");
}
