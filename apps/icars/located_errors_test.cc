// Every broken house and policy in testdata/bad ends `icars run` and `icars validate --world`
// with its documented error at its file and line and exit code 2 (1 for a policy that
// validate rejects) — before anything runs, never an abort. Each fixture's first line says
// what it must give: <!-- expect LINE: MESSAGE -->.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "fixture_expectation.h"
#include "program_run.h"

namespace {

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kBad = kSource + "/apps/icars/testdata/bad";
const std::string kPaperHouse = kSource + "/houses/paper_house.xml";

std::vector<std::filesystem::path> fixtures(const std::string& dir) {
  std::vector<std::filesystem::path> out;
  for (const auto& entry : std::filesystem::directory_iterator(kBad + "/" + dir)) {
    if (entry.path().extension() == ".xml") out.push_back(entry.path());
  }
  std::sort(out.begin(), out.end());
  return out;
}

// The run's output has the fixture's expected error at its line, and no sign of an abort.
void expect_located(const icars_test::ProgramRun& r, const std::filesystem::path& fixture, int exit_code) {
  const auto expected = icars_test::expectation_of(fixture);
  ASSERT_GT(expected.line, 0u) << fixture << " has no <!-- expect LINE: MESSAGE --> first line";
  EXPECT_EQ(r.exit_code, exit_code) << fixture << "\n" << r.output;
  const auto at = fixture.string() + ":" + std::to_string(expected.line) + ":";
  const auto where = r.output.find(at);
  ASSERT_NE(where, std::string::npos) << "no error at " << at << "\n" << r.output;
  const auto line_end = r.output.find('\n', where);
  EXPECT_NE(r.output.substr(where, line_end - where).find(expected.message), std::string::npos)
      << "expected \"" << expected.message << "\"\n" << r.output;
  EXPECT_EQ(r.output.find("terminate called"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("device registered"), std::string::npos) << "it started anyway\n" << r.output;
}

TEST(LocatedErrors, BrokenHousesStopRunAndValidateAtTheirLine) {
  const auto all = fixtures("houses");
  ASSERT_GE(all.size(), 5u);
  for (const auto& house : all) {
    SCOPED_TRACE(house.string());
    expect_located(icars_test::run_program(kIcars, "run " + kBad + "/rest.xml --world " + house.string() +
                                                       " --until 18:05 --quiet", 120),
                   house, 2);
    // validate reads the house too; device parameters are only tried by making the devices.
    const auto validated = icars_test::run_program(kIcars, "validate " + kBad + "/rest.xml --world " + house.string(), 60);
    const auto name = house.stem().string();
    if (name == "unknown_device_type" || name == "malformed") {
      expect_located(validated, house, 2);
    } else {
      EXPECT_EQ(validated.exit_code, 0) << validated.output;
    }
  }
}

TEST(LocatedErrors, PoliciesNamingWhatTheHouseLacksStopRunAndValidateAtTheirLine) {
  const auto all = fixtures("policies");
  ASSERT_GE(all.size(), 7u);
  for (const auto& policy : all) {
    SCOPED_TRACE(policy.string());
    expect_located(icars_test::run_program(kIcars, "run " + policy.string() + " --world " + kPaperHouse +
                                                       " --until 18:05 --quiet", 120),
                   policy, 2);
    expect_located(icars_test::run_program(kIcars, "validate " + policy.string() + " --world " + kPaperHouse, 60),
                   policy, 1);
    // Without a house the names are not known; the events still are.
    const auto alone = icars_test::run_program(kIcars, "validate " + policy.string(), 60);
    const auto name = policy.stem().string();
    EXPECT_EQ(alone.exit_code, name == "misspelled_property" || name == "event_that_cannot_arrive" ? 1 : 0)
        << alone.output;
  }
}

TEST(LocatedErrors, TheShippedPoliciesFitTheirHouses) {
  for (const auto& [policy, house] : std::vector<std::pair<std::string, std::string>>{
           {"/examples/smart_home/paper_home.xml", "/houses/paper_house.xml"},
           {"/apps/icars/testdata/night_light.xml", "/apps/icars/testdata/studio_house.xml"},
           {"/apps/icars/testdata/hear_speech.xml", "/houses/paper_house.xml"}}) {
    const auto r = icars_test::run_program(kIcars, "validate " + kSource + policy + " --world " + kSource + house, 60);
    EXPECT_EQ(r.exit_code, 0) << policy << " on " << house << "\n" << r.output;
  }
  const auto r = icars_test::run_program(kIcars, "validate " + kSource + "/examples/smart_home/paper_home.xml --world /nonexistent.xml", 60);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("/nonexistent.xml: cannot open the file"), std::string::npos) << r.output;
}

}  // namespace
