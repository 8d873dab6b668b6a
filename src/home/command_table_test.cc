// The voice-command table: patterns match what was said on word boundaries, captures fill the
// argument, and every mistake in a table names its entry and what was expected.
#include <gtest/gtest.h>

#include "icars/home/command_table.h"

namespace icars::home {
namespace {

const char* kTable = R"(
  # the study
  lights on                 => study_light.power(on)
  lights off                => study_light.power(off)
  dim the lights to {n}     => LightControl@study.intensity({n})
  (tv|television) (on|off)  => TVControl@*.power({2})
  volume (up|down)          => AudioControl@*.volume({1}); play {w} music => AudioControl@*.play({w} music)
  stop                      => AudioControl@*.stop()
)";

TEST(CommandTable, MatchesOnWordBoundariesAndFillsTheArgument) {
  const auto t = CommandTable::parse(kTable);
  ASSERT_EQ(t.entries().size(), 7u);
  auto m = t.match("Please turn the LIGHTS ON now");
  ASSERT_TRUE(m);
  EXPECT_EQ(m->entry->target, "study_light");
  EXPECT_EQ(m->entry->action, "power");
  EXPECT_EQ(m->argument, "on");
  EXPECT_FALSE(t.match("flights online")) << "words, not substrings";
  m = t.match("dim the lights to 30");
  ASSERT_TRUE(m);
  EXPECT_EQ(m->argument, "30");
  EXPECT_EQ(m->entry->service_type(), "LightControl");
  EXPECT_EQ(m->entry->room(), "study");
  m = t.match("television off");
  ASSERT_TRUE(m);
  EXPECT_EQ(m->argument, "off");
  EXPECT_EQ(m->entry->room(), "") << "@* is any room";
  m = t.match("volume   down");
  ASSERT_TRUE(m);
  EXPECT_EQ(m->argument, "down");
  m = t.match("play calm music");
  ASSERT_TRUE(m);
  EXPECT_EQ(m->argument, "calm music");
  m = t.match("stop");
  ASSERT_TRUE(m);
  EXPECT_EQ(m->argument, "");
  EXPECT_FALSE(t.match("open the door"));
}

TEST(CommandTable, TheFirstMatchingEntryWins) {
  const auto t = CommandTable::parse("lights => hall_light.power(on)\nlights off => hall_light.power(off)");
  EXPECT_EQ(t.match("lights off")->argument, "on");
}

TEST(CommandTable, EveryMistakeNamesItsEntryAndWhatWasExpected) {
  const auto error_of = [](const std::string& table) -> std::string {
    try {
      CommandTable::parse(table);
    } catch (const CommandTableError& e) {
      return e.what();
    }
    return "no error";
  };
  EXPECT_EQ(error_of("lights on study_light.power(on)"),
            "entry 1 (`lights on study_light.power(on)`): no '=>', expected PATTERN => TARGET.ACTION(ARGUMENT)");
  EXPECT_EQ(error_of("a => b.power(on)\nlights => study_light.shine(on)"),
            "entry 2 (`lights => study_light.shine(on)`): unknown action 'shine', expected power, intensity, channel, "
            "volume, play, stop or say");
  EXPECT_EQ(error_of("lights => LightControl@study.channel(3)"),
            "entry 1 (`lights => LightControl@study.channel(3)`): LightControl cannot channel, expected TVControl");
  EXPECT_EQ(error_of("lights => LightControl@.power(on)"),
            "entry 1 (`lights => LightControl@.power(on)`): 'LightControl@' names no room, expected Type@room or Type@*");
  EXPECT_EQ(error_of("dim to {x} => hall_light.intensity({x})"),
            "entry 1 (`dim to {x} => hall_light.intensity({x})`): unknown capture {x}, expected {n} (a number) or {w} (a word)");
  EXPECT_EQ(error_of("dim => hall_light.intensity({n})"),
            "entry 1 (`dim => hall_light.intensity({n})`): the argument uses {n}, which the pattern does not capture");
  EXPECT_EQ(error_of("stop => speaker.stop(now)"), "entry 1 (`stop => speaker.stop(now)`): stop() takes no argument");
  EXPECT_EQ(error_of("lights => hall_light.power()"), "entry 1 (`lights => hall_light.power()`): power() needs an argument");
  EXPECT_NE(error_of("(on|) => hall_light.power(on)").find("an empty or non-word alternative in (on|), expected (word|word)"), std::string::npos);
  EXPECT_EQ(error_of("lights! => hall_light.power(on)"),
            "entry 1 (`lights! => hall_light.power(on)`): unexpected '!' in the pattern, expected words, (a|b), {n} or {w}");
  EXPECT_EQ(error_of("lights => hall_light"), "entry 1 (`lights => hall_light`): 'hall_light' is not TARGET.ACTION(ARGUMENT), e.g. study_light.power(on)");
  EXPECT_EQ(error_of("  \n # nothing\n"), "the table has no entry, expected PATTERN => TARGET.ACTION(ARGUMENT)");
}

}  // namespace
}  // namespace icars::home
