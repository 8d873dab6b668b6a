// The statechart examples of docs/policy.md (examples/policies/statechart_*.xml) are what the
// page shows, validate against the paper's house, and do what the page says when run: the
// parallel example's regions run their tasks at the same time, the final-state example ends.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "traced_run.h"

using nlohmann::json;

namespace {

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kPaperHouse = kSource + "/houses/paper_house.xml";

using icars_test::str;

// The index of the first record of `kind` whose text is `text`, or records.size().
std::size_t find(const std::vector<json>& records, const std::string& kind, const std::string& text) {
  for (std::size_t i = 0; i < records.size(); ++i) {
    if (str(records[i], "kind") == kind && str(records[i], "text") == text) return i;
  }
  return records.size();
}

}  // namespace

TEST(StatechartExamples, EachIsShownInTheDocsAndValidatesAgainstThePaperHouse) {
  const auto all = icars_test::example_policies(kSource, "statechart_");
  ASSERT_GE(all.size(), 4u);
  for (const auto& example : all) {
    SCOPED_TRACE(example);
    icars_test::expect_documented_and_valid(kIcars, kSource, example, "statechart", kPaperHouse);
  }
}

TEST(StatechartExamples, TheParallelExampleRunsBothRegionsTasksAtOnce) {
  std::string output;
  const auto t = icars_test::run_policy(kIcars, kSource + "/examples/policies/statechart_parallel.xml", kPaperHouse, "18:30", output);
  const auto n = t.size();
  ASSERT_GT(n, 0u) << output;
  const auto watch_started = find(t, "task", "task WatchBed started");
  const auto greet_started = find(t, "task", "task Greet started");
  ASSERT_LT(watch_started, n) << output;
  ASSERT_LT(greet_started, n) << output;
  // Both started before either stopped: the two regions' tasks ran at the same time.
  const auto first_stop = std::min(find(t, "task", "task WatchBed stopped"), find(t, "task", "task Greet stopped"));
  EXPECT_LT(std::max(watch_started, greet_started), first_stop);
  // The robot greeted the user (Assist reached its final state) while the bed was watched.
  const auto greeted = find(t, "transition", "Assist: Greeting -> Greeted on done");
  ASSERT_LT(greeted, n) << "the Assist region did not complete";
  EXPECT_LT(greeted, find(t, "task", "task WatchBed stopped"));
  EXPECT_EQ(str(t[greeted], "declared_in"), "Greeting");
  EXPECT_LT(find(t, "state", "entered Greeted"), find(t, "state", "left Watching"));
}

TEST(StatechartExamples, TheFinalStateExampleEndsThePolicy) {
  std::string output;
  const auto t = icars_test::run_policy(kIcars, kSource + "/examples/policies/statechart_final.xml", kPaperHouse, "18:15", output);
  const auto n = t.size();
  const auto finished = find(t, "policy", "policy statechart_final finished in Finished");
  ASSERT_LT(finished, n) << output;
  EXPECT_LT(find(t, "transition", "Welcome -> Finished on done"), finished);
  EXPECT_LT(find(t, "state", "left Welcome"), finished);
  // Nothing of the policy after it ended: no task, state or transition record, no stop.
  for (std::size_t i = finished + 1; i < n; ++i) {
    const auto kind = str(t[i], "kind");
    EXPECT_TRUE(kind != "task" && kind != "state" && kind != "transition" && kind != "policy") << t[i].dump();
  }
}
