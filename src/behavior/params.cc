#include "icars/behavior/params.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>

namespace icars::behavior {

namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
  return s;
}

std::string lower(std::string_view s) {
  std::string out(s);
  std::transform(out.begin(), out.end(), out.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return out;
}

std::optional<double> to_double(std::string_view s) {
  s = trim(s);
  if (s.empty()) return std::nullopt;
  double v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || end != s.data() + s.size() || !std::isfinite(v)) return std::nullopt;
  return v;
}

}  // namespace

std::string_view to_string(ParamType type) {
  switch (type) {
    case ParamType::string: return "string";
    case ParamType::number: return "number";
    case ParamType::integer: return "integer";
    case ParamType::boolean: return "boolean";
    case ParamType::duration: return "duration";
    case ParamType::time_of_day: return "time of day";
    case ParamType::list: return "list";
  }
  return "?";
}

ParamSpec param(std::string name, ParamType type, std::optional<std::string> default_value,
                std::string doc) {
  ParamSpec spec;
  spec.name = std::move(name);
  spec.type = type;
  spec.default_value = std::move(default_value);
  spec.doc = std::move(doc);
  return spec;
}

double parse_number(std::string_view name, std::string_view text) {
  if (auto v = to_double(text)) return *v;
  throw ParamError(fmt::format("parameter '{}': '{}' is not a number", name, text));
}

long long parse_integer(std::string_view name, std::string_view text) {
  const auto s = trim(text);
  long long v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (s.empty() || ec != std::errc() || end != s.data() + s.size()) {
    throw ParamError(fmt::format("parameter '{}': '{}' is not an integer", name, text));
  }
  return v;
}

bool parse_boolean(std::string_view name, std::string_view text) {
  const auto s = lower(trim(text));
  if (s == "true" || s == "yes" || s == "on" || s == "1") return true;
  if (s == "false" || s == "no" || s == "off" || s == "0") return false;
  throw ParamError(fmt::format("parameter '{}': '{}' is not a boolean (true or false)", name, text));
}

Time parse_duration(std::string_view name, std::string_view text) {
  const auto s = trim(text);
  std::size_t split = 0;
  while (split < s.size() && (std::isdigit(static_cast<unsigned char>(s[split])) || s[split] == '.')) {
    ++split;
  }
  const auto number = to_double(s.substr(0, split));
  const auto unit = s.substr(split);
  double scale = -1;
  if (unit.empty() || unit == "s") scale = 1000;
  else if (unit == "ms") scale = 1;
  else if (unit == "min") scale = 60'000;
  else if (unit == "h") scale = 3'600'000;
  if (!number || scale < 0 || *number * scale > 1e15) {
    throw ParamError(fmt::format(
        "parameter '{}': '{}' is not a duration (a number with ms, s, min or h: 30s, 5min)", name, text));
  }
  return Time(static_cast<std::int64_t>(std::llround(*number * scale)));
}

Time parse_time_param(std::string_view name, std::string_view text) {
  if (auto t = parse_time_of_day(trim(text))) return *t;
  throw ParamError(fmt::format("parameter '{}': '{}' is not a time of day (HH:MM)", name, text));
}

std::vector<std::string> parse_list(std::string_view text) {
  std::vector<std::string> out;
  while (true) {
    const auto comma = text.find(',');
    const auto item = trim(text.substr(0, comma));
    if (!item.empty()) out.emplace_back(item);
    if (comma == std::string_view::npos) break;
    text.remove_prefix(comma + 1);
  }
  return out;
}

void check_param(std::string_view name, ParamType type, std::string_view text) {
  switch (type) {
    case ParamType::string:
    case ParamType::list: return;
    case ParamType::number: parse_number(name, text); return;
    case ParamType::integer: parse_integer(name, text); return;
    case ParamType::boolean: parse_boolean(name, text); return;
    case ParamType::duration: parse_duration(name, text); return;
    case ParamType::time_of_day: parse_time_param(name, text); return;
  }
}

const std::string& Params::string(std::string_view name) const {
  auto it = values_.find(name);
  if (it == values_.end()) throw ParamError(fmt::format("parameter '{}' is not set", name));
  return it->second;
}
double Params::number(std::string_view name) const { return parse_number(name, string(name)); }
long long Params::integer(std::string_view name) const { return parse_integer(name, string(name)); }
bool Params::boolean(std::string_view name) const { return parse_boolean(name, string(name)); }
Time Params::duration(std::string_view name) const { return parse_duration(name, string(name)); }
Time Params::time_of_day(std::string_view name) const {
  return parse_time_param(name, string(name));
}
std::vector<std::string> Params::list(std::string_view name) const { return parse_list(string(name)); }

}  // namespace icars::behavior
