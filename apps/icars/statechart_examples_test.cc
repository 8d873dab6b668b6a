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

std::vector<std::string> examples() {
  std::vector<std::string> out;
  for (const auto& entry : std::filesystem::directory_iterator(kSource + "/examples/policies")) {
    const auto name = entry.path().filename().string();
    if (name.starts_with("statechart_") && name.ends_with(".xml")) out.push_back(entry.path().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

// The example's <statechart> element, from its opening line to its closing one.
std::string statechart_of(const std::string& text) {
  const auto open = text.rfind('\n', text.find("<statechart")) + 1;
  const auto close = text.find("</statechart>");
  return text.substr(open, close + std::string("</statechart>").size() - open);
}

std::vector<json> run_with_trace(const std::string& policy, const std::string& until, std::string& output) {
  auto r = icars_test::run_traced(kIcars, "run " + policy + " --world " + kPaperHouse + " --until " + until + " --speed max --quiet", 300);
  output = r.run.output;
  EXPECT_EQ(r.run.exit_code, 0) << r.run.output;
  return std::move(r.trace);
}

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
  const auto doc = icars_test::read_file(kSource + "/docs/policy.md");
  const auto all = examples();
  ASSERT_GE(all.size(), 4u);
  for (const auto& example : all) {
    SCOPED_TRACE(example);
    const auto name = std::filesystem::path(example).filename().string();
    EXPECT_NE(doc.find("examples/policies/" + name), std::string::npos) << "docs/policy.md does not name it";
    const auto statechart = statechart_of(icars_test::read_file(example));
    EXPECT_NE(doc.find(statechart), std::string::npos) << "docs/policy.md does not show, verbatim:\n" << statechart;
    const auto validated = icars_test::run_program(kIcars, "validate " + example + " --world " + kPaperHouse, 120);
    EXPECT_EQ(validated.exit_code, 0) << validated.output;
    EXPECT_NE(validated.output.find(example + ": ok: policy " + std::filesystem::path(example).stem().string()),
              std::string::npos)
        << validated.output;
    EXPECT_NE(validated.output.find(", 0 warnings"), std::string::npos) << validated.output;
  }
}

TEST(StatechartExamples, TheParallelExampleRunsBothRegionsTasksAtOnce) {
  std::string output;
  const auto t = run_with_trace(kSource + "/examples/policies/statechart_parallel.xml", "18:30", output);
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
  const auto t = run_with_trace(kSource + "/examples/policies/statechart_final.xml", "18:15", output);
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
