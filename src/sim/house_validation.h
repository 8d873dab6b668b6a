// Checking a parsed house (docs/house.md, "What is checked"): every element placed inside a
// room, every name known, robots and users starting free, waypoints and schedule targets
// reachable; and completing it: the rooms' bounds and anchors, furniture approach spots.
// Internal to the simulator: house_parser.cc reads a file, then calls validate_house.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "icars/sim/house.h"

namespace icars::sim::detail {

inline constexpr double kEpsilon = 1e-6;

// Everything parsed, plus the line each item came from (for validation errors).
struct HouseLines {
  std::size_t house = 0;
  std::vector<std::size_t> rooms, doors, furniture, waypoints, devices, robots, users;
  std::vector<std::vector<std::size_t>> entries;  // per user
};

// Checks `house` and completes it; throws HouseError(source, line, ...) at the first problem,
// with the line from `lines`.
void validate_house(House& house, const HouseLines& lines, std::string_view source);

[[noreturn]] void house_error(std::string_view source, std::size_t line, const std::string& problem);
std::string fmt_point(Point p);
std::string join(const std::vector<std::string>& items);

}  // namespace icars::sim::detail
