// Behavior parameters: what a policy file supplies to a behavior factory, declared by each
// behavior type (like the ports of a BehaviorTree.CPP node) so that a policy is checked —
// unknown names, missing values, values of the wrong kind — before anything runs.
#pragma once

#include <functional>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "icars/clock/time.h"

namespace icars::behavior {

enum class ParamType { string, number, integer, boolean, duration, time_of_day, list };
std::string_view to_string(ParamType type);

struct ParamSpec {
  std::string name;
  ParamType type = ParamType::string;
  std::optional<std::string> default_value;  // nullopt: required
  std::string doc;
  // What the value (each item of a list) names: "" free text; a kind of name of the world
  // ("room", "waypoint", "place", "furniture", "device", "user", "robot"), checked against a
  // house before the policy runs; or "event", an event type the behavior propagates.
  std::string names;
  // A value with structure (a command table): `check` throws ParamError for a value the type
  // cannot use, before the policy runs; `names_in` lists the (kind, name) pairs it names, which
  // are checked against a house like `names`.
  std::function<void(std::string_view value)> check;
  std::function<std::vector<std::pair<std::string, std::string>>(std::string_view value)> names_in;

  ParamSpec naming(std::string kind) && {
    names = std::move(kind);
    return std::move(*this);
  }
  ParamSpec checked_by(std::function<void(std::string_view)> fn) && {
    check = std::move(fn);
    return std::move(*this);
  }
  ParamSpec naming_in(std::function<std::vector<std::pair<std::string, std::string>>(std::string_view)> fn) && {
    names_in = std::move(fn);
    return std::move(*this);
  }
};

// ParamSpec builders: param("track", ParamType::string, "calm", "what to play").
ParamSpec param(std::string name, ParamType type, std::optional<std::string> default_value,
                std::string doc);

class ParamError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Converts `text` to the type, or throws ParamError saying what a value of that type looks like.
// durations: "500ms", "30s", "5min", "2h" (a bare number is seconds); times of day: "21:30";
// booleans: true/false/yes/no/on/off; lists: comma-separated, blanks trimmed, empty items dropped.
double parse_number(std::string_view name, std::string_view text);
long long parse_integer(std::string_view name, std::string_view text);
bool parse_boolean(std::string_view name, std::string_view text);
Time parse_duration(std::string_view name, std::string_view text);
Time parse_time_param(std::string_view name, std::string_view text);
std::vector<std::string> parse_list(std::string_view text);
// Checks `text` against `type`; throws ParamError.
void check_param(std::string_view name, ParamType type, std::string_view text);

// The values given to one behavior, with the declared defaults filled in.
class Params {
 public:
  Params() = default;
  explicit Params(std::map<std::string, std::string, std::less<>> values) : values_(std::move(values)) {}

  bool has(std::string_view name) const { return values_.find(name) != values_.end(); }
  // Each throws ParamError when the parameter is absent or not of the type.
  const std::string& string(std::string_view name) const;
  double number(std::string_view name) const;
  long long integer(std::string_view name) const;
  bool boolean(std::string_view name) const;
  Time duration(std::string_view name) const;
  Time time_of_day(std::string_view name) const;
  std::vector<std::string> list(std::string_view name) const;

  const std::map<std::string, std::string, std::less<>>& values() const { return values_; }
  void set(std::string name, std::string value) { values_[std::move(name)] = std::move(value); }

 private:
  std::map<std::string, std::string, std::less<>> values_;
};

}  // namespace icars::behavior
