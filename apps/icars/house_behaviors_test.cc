// House behaviors as a user runs them (`icars run` on the paper house, read back from the trace).
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <iostream>
#include <map>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "traced_run.h"

namespace {

using nlohmann::json;

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;

std::vector<json> run_traced(const std::string& args) {
  auto r = icars_test::run_traced(kIcars, args + " --quiet", 300);
  EXPECT_EQ(r.run.exit_code, 0) << r.run.output;
  return std::move(r.trace);
}

// Two Sense siblings: every sensor event reaches the task once. (Each used to pass on the
// other's events, which bounced between them: thousands of copies of one event.)
TEST(HouseBehaviors, TwoSenseSiblingsPassOnEachEventOnce) {
  const auto trace = run_traced("run " + kSource + "/apps/icars/testdata/two_senses.xml --world " + kSource +
                                "/houses/paper_house.xml --speed max --until 18:25");
  std::map<std::string, int> copies;  // event record text (with its time) -> count
  int occupancy = 0;
  for (const auto& r : trace) {
    if (r.value("kind", "") != "event") continue;
    ++copies[r.value("time", "") + " " + r.value("text", "")];
    if (r.value("event", "") == "OccupancyEvent") ++occupancy;
  }
  EXPECT_GT(occupancy, 0) << "the user sat down on the sofa by 18:25";
  for (const auto& [text, n] : copies) EXPECT_EQ(n, 1) << text;
}

// LookAtSound turns the robot to each voice from what its four microphones heard: the user
// speaks from eight places around it, and every turn is within 20 degrees of the true bearing.
TEST(HouseBehaviors, LookAtSoundTurnsToVoicesFromEveryDirection) {
  const auto trace = run_traced("run " + kSource + "/apps/icars/testdata/look_at_sound.xml --world " + kSource +
                                "/apps/icars/testdata/voices_around.xml --speed max --until 18:20");
  const double degree = std::numbers::pi / 180;
  const std::vector<double> bearings = {0, 50, 100, 150, 200, 250, 300, 340};  // the waypoints, around (4, 4)
  int turned = 0;
  for (std::size_t i = 0; i < bearings.size(); ++i) {
    const auto said = static_cast<std::int64_t>((18 * 60 + 2 + 2 * static_cast<int>(i)) * 60000);
    std::optional<double> turn;
    for (const auto& r : trace) {
      const auto t = r.value("t", std::int64_t{0});
      const std::string call = r.value("call", "");
      if (r.value("kind", "") != "call" || t < said || t > said + 60000) continue;
      if (!call.starts_with("robot1_wheels.wheels.turn_to(")) continue;
      turn = std::stod(call.substr(call.find('(') + 1));
      break;
    }
    if (!turn) {
      ADD_FAILURE() << "no turn after the voice from " << bearings[i] << " degrees";
      continue;
    }
    ++turned;
    const double error = std::abs(std::remainder(*turn - bearings[i] * degree, 2 * std::numbers::pi)) / degree;
    EXPECT_LE(error, 20.0) << "the voice came from " << bearings[i] << " degrees, the robot turned to "
                           << *turn / degree;
    std::cout << "voice from " << bearings[i] << " deg: turned to " << *turn / degree << " deg (" << error
              << " deg off)\n";
  }
  EXPECT_EQ(turned, 8);
}

}  // namespace
