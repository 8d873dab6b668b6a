// Conditions: the small expression language of behavior rules and collaboration policy files.
//
// A condition is parsed once (Condition::parse) and evaluated against an event and a scope
// (simulated time, extra variables); parse errors are ConditionErrors naming the column and what
// was expected, evaluation never fails. An empty or blank condition is always true.
//
// Language (docs/policy.md cites this):
//   literals     3  -2.5  'sofa'  "it's"  true  false
//                strings take single or double quotes; escapes \\ \' \"
//                21:30  07:05:30   time of day HH:MM[:SS] (H:MM too), as ms since midnight
//                500ms  30s  5min  2h   durations, as ms; a leading '-' only on numbers/durations
//   names        [A-Za-z_][A-Za-z0-9_.]*, resolved in this order:
//                  event -> the event's type name      time -> time of day of scope.now, in ms
//                  day   -> day number of scope.now     then scope.variables, then the event's
//                  property of that name. Properties: bool -> bool; byte, short, int, long,
//                  float, double -> number; string -> string; other types -> absent.
//                A name that resolves to nothing is absent.
//   operators    lowest to highest: or (||), and (&&), not (!), == != < <= > >=, then a
//                literal, name, function call or (parenthesised expression). Comparisons do
//                not chain: `a < b < c` is an error. and/or short-circuit and yield a bool.
//   comparing    number with number, string with string (bytewise), bool with bool (== and !=
//                only). With an absent value or values of different types, != is true and
//                every other comparison false.
//   truth        absent -> false, bool -> itself, number -> != 0, string -> non-empty.
//   functions    between(x, lo, hi)  lo <= x < hi; when lo > hi the range wraps midnight:
//                                    between(time, 21:00, 06:00) is true at night
//                contains(s, sub)    case-insensitive (ASCII)
//                starts_with(s, p)   case-insensitive (ASCII)
//                lower(s)            ASCII lower case
//                exists(name)        a bare name; true when it resolves to a present value
//                number(s)           a string as a number (absent when it is not one); a
//                                    number stays itself
//                Unknown functions and wrong argument counts are parse errors; arguments of
//                the wrong type make the result absent.
//   limits       nesting (parentheses, calls, not) at most 64 deep.
#pragma once

#include <cstddef>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <variant>
#include <vector>

#include "icars/clock/time.h"
#include "icars/planet/event.h"

namespace icars::behavior {

namespace detail {
struct ConditionProgram;  // the parsed form: text, syntax tree, names read (condition.cc)
}  // namespace detail

// A value during evaluation: absent (a missing property), bool, number, string.
using ConditionValue = std::variant<std::monostate, bool, double, std::string>;

// A condition that does not parse. what() is "column N: <message>"; column() is 1-based and
// counts characters (UTF-8 code points), the end of the text being column size + 1.
class ConditionError : public std::runtime_error {
 public:
  ConditionError(std::string message, std::size_t column);
  std::size_t column() const { return column_; }

 private:
  std::size_t column_;
};

// What a condition sees besides the event's properties.
struct ConditionScope {
  Time now{0};  // `time` = time of day of now, `day` = now / 24h
  std::map<std::string, ConditionValue, std::less<>> variables;  // checked before properties
};

// A parsed condition. Immutable; copies share the parsed form, so copying is cheap and a
// condition may be evaluated from several threads at once.
class Condition {
 public:
  Condition();                                    // the empty condition: always true, text() == ""
  static Condition parse(std::string_view text);  // throws ConditionError

  bool evaluate(const planet::Event& event, const ConditionScope& scope = {}) const;
  // The expression's value; the empty condition's value is true.
  ConditionValue value(const planet::Event& event, const ConditionScope& scope = {}) const;

  const std::string& text() const;  // as given to parse()
  bool empty() const { return program_ == nullptr; }
  // The names it reads (including event, time, day and the argument of exists, never function
  // names), in order of first use, each once.
  std::vector<std::string> identifiers() const;
  // The names compared for equality (== or !=) with a string literal, as (name, literal), in
  // order: `furniture == 'bed'` gives ("furniture", "bed"), `event != 'X'` ("event", "X").
  std::vector<std::pair<std::string, std::string>> compared_strings() const;

 private:
  explicit Condition(std::shared_ptr<const detail::ConditionProgram> program);

  std::shared_ptr<const detail::ConditionProgram> program_;  // null for the empty condition
};

}  // namespace icars::behavior
