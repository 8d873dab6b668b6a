// Conditions: literals, names, operators and precedence, comparisons across types, absent
// properties, functions, parse errors with their columns, and robustness on arbitrary input.
#include "icars/behavior/condition.h"

#include <gtest/gtest.h>

#include <array>
#include <charconv>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace icars::behavior {
namespace {


// A value as the test reads it: absent, true/false, a number in shortest form, 'text'.
std::string show(const ConditionValue& v) {
  if (std::holds_alternative<std::monostate>(v)) return "absent";
  if (const auto* b = std::get_if<bool>(&v)) return *b ? "true" : "false";
  if (const auto* s = std::get_if<std::string>(&v)) return "'" + *s + "'";
  std::array<char, 64> buffer{};
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(),
                                    std::get<double>(v), std::chars_format::fixed);
  return std::string(buffer.data(), result.ptr);
}

// A living-room event with one property of each readable type.
planet::Event sit_event() {
  planet::Event e("SitEvent");
  e.set<std::string>("place", "Sofa")
      .set<std::int32_t>("volume", 7)
      .set<std::int64_t>("since", 5'000'000'000)
      .set<bool>("awake", true)
      .set<double>("level", 0.25)
      .set<std::uint8_t>("channel", 3)
      .set<std::int16_t>("offset", -4)
      .set<float>("gain", 1.5F)
      .set<std::vector<std::int32_t>>("samples", {1, 2})
      .set<planet::Binary>("image", planet::Binary{{std::byte{1}}});
  return e;
}

std::string value_of(std::string_view text, const planet::Event& e = sit_event(),
                     const ConditionScope& scope = {}) {
  return show(Condition::parse(text).value(e, scope));
}
bool holds(std::string_view text, const planet::Event& e = sit_event(),
           const ConditionScope& scope = {}) {
  return Condition::parse(text).evaluate(e, scope);
}

TEST(Condition, EmptyOrBlankTextIsAlwaysTrue) {
  const Condition none;
  EXPECT_TRUE(none.empty());
  EXPECT_EQ(none.text(), "");
  EXPECT_TRUE(none.evaluate(planet::Event("Anything")));
  EXPECT_EQ(show(none.value(planet::Event())), "true");
  EXPECT_TRUE(none.identifiers().empty());
  for (const std::string_view blank : {"", " ", " \t\n\r "}) {
    const auto c = Condition::parse(blank);
    EXPECT_TRUE(c.empty()) << "'" << blank << "'";
    EXPECT_EQ(c.text(), "");
    EXPECT_TRUE(c.evaluate(planet::Event()));
  }
  EXPECT_FALSE(Condition::parse("true").empty());
  EXPECT_EQ(Condition::parse(" volume > 3 ").text(), " volume > 3 ");
}

TEST(Condition, Literals) {
  EXPECT_EQ(value_of("3"), "3");
  EXPECT_EQ(value_of("-2.5"), "-2.5");
  EXPECT_EQ(value_of("- 4"), "-4");
  EXPECT_EQ(value_of("'sofa'"), "'sofa'");
  EXPECT_EQ(value_of("\"it's\""), "'it's'");
  EXPECT_EQ(value_of(R"('it\'s a \\ and a \"')"), R"('it's a \ and a "')");
  EXPECT_EQ(value_of("true"), "true");
  EXPECT_EQ(value_of("false"), "false");
  EXPECT_EQ(value_of("21:30"), "77400000");
  EXPECT_EQ(value_of("07:05:30"), "25530000");
  EXPECT_EQ(value_of("00:00"), "0");
  EXPECT_EQ(value_of("500ms"), "500");
  EXPECT_EQ(value_of("30s"), "30000");
  EXPECT_EQ(value_of("5min"), "300000");
  EXPECT_EQ(value_of("2h"), "7200000");
  EXPECT_EQ(value_of("1.5h"), "5400000");
  EXPECT_EQ(value_of("-30s"), "-30000");
}

TEST(Condition, BooleanOperatorsAndTheirSpellings) {
  ConditionScope s;
  s.variables = {{"t", true}, {"f", false}};
  const planet::Event e;
  EXPECT_TRUE(holds("t and t", e, s));
  EXPECT_FALSE(holds("t and f", e, s));
  EXPECT_TRUE(holds("t && t", e, s));
  EXPECT_FALSE(holds("f && t", e, s));
  EXPECT_TRUE(holds("f or t", e, s));
  EXPECT_FALSE(holds("f or f", e, s));
  EXPECT_TRUE(holds("f || t", e, s));
  EXPECT_TRUE(holds("not f", e, s));
  EXPECT_FALSE(holds("not t", e, s));
  EXPECT_TRUE(holds("!f", e, s));
  EXPECT_TRUE(holds("not not t", e, s));
  EXPECT_TRUE(holds("!!t", e, s));
  EXPECT_TRUE(holds("f or f or f or t", e, s));
  EXPECT_FALSE(holds("t and t and t and f", e, s));
  // and/or yield a bool, whatever their operands are.
  EXPECT_EQ(value_of("1 and 'x'", e, s), "true");
  EXPECT_EQ(value_of("0 or ''", e, s), "false");
}

TEST(Condition, Precedence) {
  ConditionScope s;
  s.variables = {{"a", true}, {"b", false}, {"c", false}};
  const planet::Event e;
  EXPECT_TRUE(holds("a or b and c", e, s));     // a or (b and c)
  EXPECT_FALSE(holds("(a or b) and c", e, s));  // parentheses regroup
  EXPECT_TRUE(holds("b and c or a", e, s));     // (b and c) or a
  EXPECT_FALSE(holds("not a and b", e, s));     // (not a) and b
  EXPECT_TRUE(holds("not b and a", e, s));
  EXPECT_TRUE(holds("not 1 == 2", e, s));  // not (1 == 2)
  EXPECT_TRUE(holds("1 < 2 and 'a' == 'a'", e, s));
  EXPECT_TRUE(holds("a || b && c", e, s));
  EXPECT_TRUE(holds("!b && a", e, s));
}

TEST(Condition, ComparesNumbersStringsAndBools) {
  EXPECT_TRUE(holds("volume == 7"));
  EXPECT_TRUE(holds("volume != 8"));
  EXPECT_TRUE(holds("volume < 8"));
  EXPECT_FALSE(holds("volume < 7"));
  EXPECT_TRUE(holds("volume <= 7"));
  EXPECT_TRUE(holds("volume > 6.5"));
  EXPECT_FALSE(holds("volume > 7"));
  EXPECT_TRUE(holds("volume >= 7"));
  EXPECT_TRUE(holds("place == 'Sofa'"));
  EXPECT_FALSE(holds("place == 'sofa'"));  // == is exact; contains() ignores case
  EXPECT_TRUE(holds("'apple' < 'banana'"));
  EXPECT_TRUE(holds("'b' >= 'abc'"));
  EXPECT_TRUE(holds("awake == true"));
  EXPECT_TRUE(holds("awake != false"));
  EXPECT_FALSE(holds("true > false"));  // bools compare with == and != only
  EXPECT_FALSE(holds("true <= true"));
}

TEST(Condition, ValuesOfDifferentTypesAreNeverEqual) {
  EXPECT_FALSE(holds("1 == '1'"));
  EXPECT_TRUE(holds("1 != '1'"));
  EXPECT_FALSE(holds("1 < '2'"));
  EXPECT_FALSE(holds("'2' > 1"));
  EXPECT_FALSE(holds("true == 1"));
  EXPECT_TRUE(holds("true != 1"));
}

TEST(Condition, AbsentValues) {
  EXPECT_EQ(value_of("missing"), "absent");
  EXPECT_FALSE(holds("missing"));
  EXPECT_TRUE(holds("not missing"));
  EXPECT_FALSE(holds("missing == 1"));
  EXPECT_TRUE(holds("missing != 1"));
  EXPECT_FALSE(holds("missing < 1"));
  EXPECT_FALSE(holds("missing >= 1"));
  EXPECT_FALSE(holds("1 > missing"));
  EXPECT_FALSE(holds("missing == missing"));
  EXPECT_TRUE(holds("missing != missing"));
  EXPECT_TRUE(holds("missing or volume == 7"));
}

TEST(Condition, Truthiness) {
  EXPECT_FALSE(holds("0"));
  EXPECT_TRUE(holds("2"));
  EXPECT_TRUE(holds("-0.5"));
  EXPECT_FALSE(holds("''"));
  EXPECT_TRUE(holds("'x'"));
  EXPECT_TRUE(holds("awake"));
  EXPECT_TRUE(holds("volume"));
  EXPECT_TRUE(holds("place"));
}

TEST(Condition, PropertyTypes) {
  EXPECT_EQ(value_of("place"), "'Sofa'");
  EXPECT_EQ(value_of("volume"), "7");          // int32
  EXPECT_EQ(value_of("since"), "5000000000");  // int64
  EXPECT_EQ(value_of("awake"), "true");
  EXPECT_EQ(value_of("level"), "0.25");      // double
  EXPECT_EQ(value_of("channel"), "3");       // byte
  EXPECT_EQ(value_of("offset"), "-4");       // short
  EXPECT_EQ(value_of("gain"), "1.5");        // float
  EXPECT_EQ(value_of("samples"), "absent");  // sequences cannot be read
  EXPECT_EQ(value_of("image"), "absent");    // nor can binary
  EXPECT_TRUE(holds("since > 4000000000 and level < 0.5 and offset < 0"));
}

TEST(Condition, EventTimeAndDay) {
  const planet::Event sound("SoundEvent");
  ConditionScope s;
  s.now = at_time(2, 21, 30, 15);
  EXPECT_TRUE(holds("event == 'SoundEvent'", sound, s));
  EXPECT_FALSE(holds("event == 'SitEvent'", sound, s));
  EXPECT_TRUE(holds("time == 21:30:15", sound, s));
  EXPECT_TRUE(holds("time > 21:30 and time < 21:31", sound, s));
  EXPECT_EQ(value_of("day", sound, s), "2");
  s.now = at_time(0, 0, 0) - std::chrono::hours(1);  // before day 0: day -1, 23:00
  EXPECT_EQ(value_of("day", sound, s), "-1");
  EXPECT_TRUE(holds("time == 23:00", sound, s));
}

TEST(Condition, Between) {
  EXPECT_TRUE(holds("between(5, 1, 10)"));
  EXPECT_TRUE(holds("between(1, 1, 10)"));    // lo included
  EXPECT_FALSE(holds("between(10, 1, 10)"));  // hi excluded
  EXPECT_FALSE(holds("between(0, 1, 10)"));
  EXPECT_FALSE(holds("between(5, 5, 5)"));  // empty range
  EXPECT_TRUE(holds("between(volume, 5, 10)"));
  ConditionScope s;
  const auto night = Condition::parse("between(time, 21:00, 06:00)");
  for (const auto& [hours, minutes, expected] :
       std::vector<std::tuple<int, int, bool>>{{23, 0, true},
                                               {3, 0, true},
                                               {21, 0, true},
                                               {0, 0, true},
                                               {5, 59, true},
                                               {6, 0, false},
                                               {12, 0, false},
                                               {20, 59, false}}) {
    s.now = at_time(4, hours, minutes);
    EXPECT_EQ(night.evaluate(planet::Event(), s), expected) << hours << ":" << minutes;
  }
  EXPECT_EQ(value_of("between('5', 1, 10)"), "absent");  // a type mismatch is absent, not an error
  EXPECT_EQ(value_of("between(missing, 1, 10)"), "absent");
  EXPECT_FALSE(holds("between(missing, 1, 10)"));
}

TEST(Condition, StringFunctionsIgnoreCase) {
  EXPECT_TRUE(holds("contains(place, 'OF')"));
  EXPECT_TRUE(holds("contains('Living Room', 'room')"));
  EXPECT_FALSE(holds("contains(place, 'bed')"));
  EXPECT_TRUE(holds("contains(place, '')"));
  EXPECT_TRUE(holds("starts_with(place, 'so')"));
  EXPECT_TRUE(holds("starts_with(place, 'SOFA')"));
  EXPECT_FALSE(holds("starts_with(place, 'ofa')"));
  EXPECT_EQ(value_of("lower('Kitchen 2')"), "'kitchen 2'");
  EXPECT_TRUE(holds("lower(place) == 'sofa'"));
  EXPECT_EQ(value_of("contains(volume, '7')"), "absent");
  EXPECT_EQ(value_of("lower(3)"), "absent");
}

TEST(Condition, Exists) {
  ConditionScope s;
  s.variables = {{"room", std::string("kitchen")}, {"nothing", std::monostate{}}};
  EXPECT_TRUE(holds("exists(volume)", sit_event(), s));
  EXPECT_FALSE(holds("exists(missing)", sit_event(), s));
  EXPECT_TRUE(holds("exists(room)", sit_event(), s));
  EXPECT_FALSE(holds("exists(nothing)", sit_event(), s));
  EXPECT_TRUE(holds("exists(time) and exists(event) and exists(day)", sit_event(), s));
  EXPECT_FALSE(holds("exists(samples)", sit_event(), s));  // present but unreadable
  EXPECT_TRUE(holds("not exists(missing) or missing > 3", sit_event(), s));
}

TEST(Condition, Number) {
  EXPECT_EQ(value_of("number('42')"), "42");
  EXPECT_EQ(value_of("number(' -2.5 ')"), "-2.5");
  EXPECT_EQ(value_of("number('+3')"), "3");
  EXPECT_EQ(value_of("number(volume)"), "7");
  EXPECT_EQ(value_of("number('abc')"), "absent");
  EXPECT_EQ(value_of("number('4x')"), "absent");
  EXPECT_EQ(value_of("number('')"), "absent");
  EXPECT_EQ(value_of("number('nan')"), "absent");
  EXPECT_EQ(value_of("number(true)"), "absent");
  ConditionScope s;
  s.variables = {{"reading", std::string("21.5")}};
  EXPECT_TRUE(holds("number(reading) > 20", sit_event(), s));
}

TEST(Condition, VariablesShadowPropertiesButNotBuiltIns) {
  ConditionScope s;
  s.now = at_time(0, 8, 0);
  s.variables = {{"place", std::string("bed")},
                 {"time", 1.0},
                 {"event", std::string("X")},
                 {"robot.battery", 0.8}};
  EXPECT_TRUE(holds("place == 'bed'", sit_event(), s));
  EXPECT_TRUE(holds("time == 08:00", sit_event(), s));
  EXPECT_TRUE(holds("event == 'SitEvent'", sit_event(), s));
  EXPECT_TRUE(holds("robot.battery > 0.5", sit_event(), s));
  EXPECT_TRUE(holds("place == 'Sofa'"));  // without the variable, the property
}

TEST(Condition, IdentifiersInFirstUseOrderEachOnce) {
  const auto c = Condition::parse(
      "a and between(time, b, 06:00) or exists(c) and a == 'x' or lower(d.e) == b");
  EXPECT_EQ(c.identifiers(), (std::vector<std::string>{"a", "time", "b", "c", "d.e"}));
  EXPECT_TRUE(Condition::parse("true and 3 > 2").identifiers().empty());
}

TEST(Condition, CopiesShareTheParsedForm) {
  auto original = std::make_unique<Condition>(Condition::parse("volume > 5"));
  Condition copy = *original;
  Condition assigned;
  assigned = copy;
  EXPECT_EQ(copy.text().data(), original->text().data());  // shared, not duplicated
  original.reset();
  EXPECT_EQ(copy.text(), "volume > 5");
  EXPECT_TRUE(copy.evaluate(sit_event()));
  EXPECT_TRUE(assigned.evaluate(sit_event()));
  EXPECT_EQ(assigned.identifiers(), std::vector<std::string>{"volume"});
  Condition moved = std::move(assigned);
  EXPECT_TRUE(moved.evaluate(sit_event()));
}

TEST(Condition, ErrorMessagesNameTheColumnAndWhatWasExpected) {
  const auto message = [](std::string_view text) -> std::string {
    try {
      Condition::parse(text);
    } catch (const ConditionError& e) {
      return e.what();
    }
    return "parsed";
  };
  EXPECT_EQ(message("between(time, 1, 2 3)"),
            "column 20: expected ')' after the arguments of between, found '3'");
  EXPECT_EQ(message("betwen(time, 21:00, 06:00)"),
            "column 1: unknown function 'betwen' (known: between, contains, exists, lower, "
            "number, starts_with)");
  EXPECT_EQ(message("temp >"), "column 7: expected an expression, found end of condition");
  EXPECT_EQ(message("(a"),
            "column 3: expected ')' to close the '(' at column 1, found end of "
            "condition");
  EXPECT_EQ(message("time > 25:00"),
            "column 8: '25:00' is not a time of day (expected HH:MM or HH:MM:SS, hours 00-23, "
            "minutes and seconds 00-59)");
  // A string literal is shown as written, in its own quotes, not quoted a second time.
  EXPECT_EQ(message("exists('index')"),
            "column 8: exists takes a bare name, e.g. exists(battery), found string 'index'");
  EXPECT_EQ(message("place == \"sofa\" \"bed\""),
            "column 17: expected 'and', 'or' or end of condition, found string \"bed\"");
  EXPECT_EQ(message("lower('a' 'b')"),
            "column 11: expected ')' after the arguments of lower, found string 'b'");
}

struct BadCondition {
  std::string text;
  std::size_t column;
  std::string says;  // part of the message
};

TEST(Condition, MalformedInputsReportTheColumn) {
  const std::vector<BadCondition> cases = {
      {"place == 'sofa", 10, "unterminated string"},
      {"place == \"sofa\\\"", 10, "unterminated string"},
      {"'a\\q'", 3, "unknown escape '\\q'"},
      {"a ==", 5, "expected an expression, found end of condition"},
      {"a ==   ", 8, "found end of condition"},
      {"a and", 6, "expected an expression"},
      {"not", 4, "expected an expression"},
      {"()", 2, "expected an expression, found ')'"},
      {"(a", 3, "expected ')' to close the '(' at column 1"},
      {"((a) or (b)", 12, "expected ')' to close the '(' at column 1"},
      {"a b", 3, "expected 'and', 'or' or end of condition, found 'b'"},
      {"a)", 2, "found ')'"},
      {"a < b < c", 7, "comparisons do not chain"},
      {"(a == b != c)", 9, "comparisons do not chain"},
      {"betwen(time, 1, 2)", 1, "unknown function 'betwen'"},
      {"x and foo()", 7, "unknown function 'foo'"},
      {"x and between(time, 1)", 7, "between takes 3 arguments (x, lo, hi), found 2"},
      {"between(1, 2, 3, 4)", 1, "between takes 3 arguments (x, lo, hi), found 4"},
      {"lower('a', 'b')", 1, "lower takes 1 argument (s), found 2"},
      {"lower()", 1, "lower takes 1 argument (s), found 0"},
      {"contains(a b)", 12, "expected ',' or ')' after the arguments of contains, found 'b'"},
      {"between(1, 2, 3,)", 17, "expected an expression, found ')'"},
      {"exists('a')", 8, "exists takes a bare name"},
      {"exists(a, b)", 9, "expected ')' after the argument of exists"},
      {"time > 25:00", 8, "'25:00' is not a time of day"},
      {"time > 21:60", 8, "not a time of day"},
      {"time > 07:00pm", 8, "'07:00pm' is not a time of day"},
      {"time > 1:", 8, "not a time of day"},
      {"5kg", 2, "unknown unit 'kg' after 5 (known: ms, s, min, h)"},
      {"3.", 1, "malformed number '3.'"},
      {"1.2.3", 1, "malformed number"},
      {"-a", 2, "expected a number or duration after '-', found 'a'"},
      {"time > -21:00", 9, "expected a number or duration after '-'"},
      {"a # b", 3, "unexpected character '#'"},
      {"a = 1", 3, "compare with '=='"},
      {"time - 1", 6, "expected 'and', 'or' or end of condition, found '-'"},
      {"a & b", 3, "write '&&' or 'and'"},
      {"a | b", 3, "write '||' or 'or'"},
      {"'\xC3\xA9' == #", 8, "unexpected character '#'"},  // columns count characters
      {"\xC3\xA9", 1, "unexpected character '\\xC3'"},
      {"a == 'x' @", 10, "unexpected character '@'"},
  };
  for (const auto& bad : cases) {
    try {
      Condition::parse(bad.text);
      ADD_FAILURE() << "parsed: " << bad.text;
    } catch (const ConditionError& e) {
      EXPECT_EQ(e.column(), bad.column) << bad.text << " -> " << e.what();
      EXPECT_NE(std::string(e.what()).find(bad.says), std::string::npos)
          << bad.text << " -> " << e.what();
      EXPECT_EQ(std::string(e.what()).rfind("column " + std::to_string(bad.column) + ": ", 0), 0u)
          << e.what();
    }
  }
}

TEST(Condition, NestingIsLimitedTo64Levels) {
  const auto nested = [](std::size_t depth) {
    return std::string(depth, '(') + "a" + std::string(depth, ')');
  };
  ConditionScope s;
  s.variables = {{"a", true}};
  EXPECT_TRUE(Condition::parse(nested(64)).evaluate(planet::Event(), s));
  try {
    Condition::parse(nested(65));
    ADD_FAILURE() << "65 levels parsed";
  } catch (const ConditionError& e) {
    EXPECT_EQ(e.column(), 65u);
    EXPECT_NE(std::string(e.what()).find("nested too deeply"), std::string::npos) << e.what();
  }
  std::string nots;
  for (int i = 0; i < 65; ++i) nots += "not ";
  EXPECT_THROW(Condition::parse(nots + "a"), ConditionError);
  EXPECT_THROW(Condition::parse(std::string(65, '!') + "a"), ConditionError);
  std::string calls;
  for (int i = 0; i < 65; ++i) calls += "lower(";
  EXPECT_THROW(Condition::parse(calls + "a" + std::string(65, ')')), ConditionError);
  EXPECT_THROW(Condition::parse(std::string(100'000, '(')), ConditionError);
}

TEST(Condition, LongFlatChainsNeedNoDeepRecursion) {
  std::string text = "a";
  for (int i = 0; i < 100'000; ++i) text += i % 2 == 0 ? " or a" : " and a";
  ConditionScope s;
  s.variables = {{"a", true}};
  const auto c = Condition::parse(text);
  EXPECT_TRUE(c.evaluate(planet::Event(), s));
  EXPECT_EQ(c.identifiers(), std::vector<std::string>{"a"});
}

// Arbitrary input either parses or throws ConditionError with a column inside the text; what
// parses evaluates without throwing.
TEST(Condition, ArbitraryInputParsesOrFailsCleanly) {
  std::mt19937 random(20240611);
  // clang-format off
  const std::vector<std::string> pieces = {
      "(", ")", ",", " ", "a", "b.c", "volume", "place", "time", "day", "event", "and", "or",
      "not", "!", "&&", "||", "==", "!=", "<", "<=", ">", ">=", "=", "-", "3", "2.5", "21:30",
      "25:00", "30s", "5min", "'x'", "\"y\"", "'", "\\", "true", "false", "between(", "contains(",
      "starts_with(", "lower(", "exists(", "number(", "betwen(", "#", "\xC3\xA9",
      std::string(1, '\0')};
  // clang-format on
  ConditionScope scope;
  scope.now = at_time(1, 22, 0);
  scope.variables = {{"a", 1.0}};
  const auto event = sit_event();
  const auto check = [&](const std::string& text) {
    try {
      const auto c = Condition::parse(text);
      (void)c.evaluate(event, scope);
      (void)c.identifiers();
    } catch (const ConditionError& e) {
      EXPECT_GE(e.column(), 1u) << text;
      EXPECT_LE(e.column(), text.size() + 1) << text;
    } catch (const std::exception& e) {
      ADD_FAILURE() << "unexpected exception for '" << text << "': " << e.what();
    }
  };
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<std::size_t> length(0, 40);
  std::uniform_int_distribution<std::size_t> piece(0, pieces.size() - 1);
  for (int i = 0; i < 20'000; ++i) {
    std::string bytes(length(random), '\0');
    for (char& c : bytes) c = static_cast<char>(byte(random));
    check(bytes);
    std::string tokens;
    for (std::size_t n = length(random); n > 0; --n) tokens += pieces[piece(random)];
    check(tokens);
  }
}

}  // namespace
}  // namespace icars::behavior
