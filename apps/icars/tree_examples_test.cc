// The behavior-tree examples of docs/policy.md (examples/policies/tree_*.xml: fallback, when,
// reactive sequence and fallback, retry, repeat, timeout, invert) are what the page shows,
// validate against the paper's house, and do what the page says when run on it.
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

// The index of the first record of `kind` whose text starts with `text`, or records.size().
std::size_t find(const std::vector<json>& records, const std::string& kind, const std::string& text) {
  for (std::size_t i = 0; i < records.size(); ++i) {
    if (str(records[i], "kind") == kind && str(records[i], "text").starts_with(text)) return i;
  }
  return records.size();
}

}  // namespace

TEST(TreeExamples, EachIsShownInTheDocsAndValidatesAgainstThePaperHouse) {
  const auto all = icars_test::example_policies(kSource, "tree_");
  ASSERT_EQ(all.size(), 8u);  // one per construct
  for (const auto& example : all) {
    SCOPED_TRACE(example);
    icars_test::expect_documented_and_valid(kIcars, kSource, example, "task", kPaperHouse);
  }
}

TEST(TreeExamples, WhenRunsItsChildOnTheWordsItWaitsFor) {
  std::string output;
  const auto t = icars_test::run_policy(kIcars, kSource + "/examples/policies/tree_when.xml", kPaperHouse, "19:05", output);
  const auto n = t.size();
  // "turn on the TV", "channel 5" and "volume up" start nothing; "play music" at 19:00 does.
  const auto started = find(t, "behavior", "MusicMood/Listen/OnMusic/sequential started");
  ASSERT_LT(started, n) << output;
  // At the instant the words were heard (the user says them at about 19:00).
  const auto heard = find(t, "speech", "robot1_mic heard \"play music\"");
  ASSERT_LT(heard, started) << output;
  // Right after the words ended: the speech record is stamped when they began.
  EXPECT_GE(t[started]["t"].get<std::int64_t>(), t[heard]["t"].get<std::int64_t>());
  EXPECT_LE(t[started]["t"].get<std::int64_t>(), t[heard]["t"].get<std::int64_t>() + 5000);
  EXPECT_GE(t[started]["t"].get<std::int64_t>(), 18 * 3'600'000 + 59 * 60'000);
  const auto spoke = find(t, "effect", "robot1_speaker: spoke Enjoy the music");
  EXPECT_LT(started, spoke);
  EXPECT_LT(spoke, n);
  // Its run done, the <when> waits for more: only the end of the run halts it.
  const auto halted = find(t, "behavior", "MusicMood/Listen/OnMusic halted");
  EXPECT_LT(spoke, halted);
  EXPECT_EQ(find(t, "behavior", "MusicMood/Listen/OnMusic succeeded"), n);
}

TEST(TreeExamples, TheReactiveSequenceOffersTheTVOnceTheUserSitsDown) {
  std::string output;
  const auto t = icars_test::run_policy(kIcars, kSource + "/examples/policies/tree_reactive_sequence.xml", kPaperHouse, "18:20", output);
  const auto n = t.size();
  const auto seated = find(t, "behavior", "OfferTV/Watch/OnSitDown/WhileSeated/Seated succeeded");
  const auto drive = find(t, "behavior", "OfferTV/Watch/OnSitDown/WhileSeated/GoTo started");
  const auto spoke = find(t, "effect", "robot1_speaker: spoke Shall I turn on the TV?");
  const auto done = find(t, "behavior", "OfferTV/Watch/OnSitDown/WhileSeated succeeded");
  ASSERT_LT(done, n) << output;
  EXPECT_GE(t[seated]["t"].get<std::int64_t>(), 18 * 3'600'000 + 10 * 60'000);  // the user sits at 18:10
  EXPECT_LT(seated, drive);
  EXPECT_LT(drive, spoke);
  EXPECT_LT(spoke, done);
}

TEST(TreeExamples, TheReactiveFallbackStopsThePatrolWhenTheUserSitsDown) {
  std::string output;
  const auto t = icars_test::run_policy(kIcars, kSource + "/examples/policies/tree_reactive_fallback.xml", kPaperHouse, "18:15", output);
  const auto n = t.size();
  const auto not_seated = find(t, "behavior", "PatrolUntilSeated/Watch/SeatedOrPatrol/Seated failed: 'occupied' is false");
  const auto patrol = find(t, "behavior", "PatrolUntilSeated/Watch/SeatedOrPatrol/PatrolHome started");
  const auto holds = find(t, "note", "PatrolUntilSeated/Watch/SeatedOrPatrol: Seated holds now");
  const auto halted = find(t, "behavior", "PatrolUntilSeated/Watch/SeatedOrPatrol/PatrolHome halted");
  const auto greeting = find(t, "transition", "Patrolling -> Greeting on done");
  const auto welcomed = find(t, "effect", "robot1_speaker: spoke Welcome back");
  ASSERT_LT(welcomed, n) << output;
  EXPECT_LT(not_seated, patrol);
  EXPECT_LT(patrol, holds);
  EXPECT_LT(holds, halted);
  EXPECT_LT(halted, greeting);
  EXPECT_LT(greeting, welcomed);
}
