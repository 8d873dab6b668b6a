// House behaviors as a user runs them (`icars run` on the paper house, read back from the trace).
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <map>
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

}  // namespace
