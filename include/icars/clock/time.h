// Time as ICARS counts and prints it, simulated or not.
//
// A Time is a duration since day 0, 00:00, in milliseconds: day 0 is the first day of a
// simulation, or the day a wall clock started. Time of day is `t % 24h`, the day number is
// `t / 24h`; nothing here knows about calendars or time zones. House files, policies and logs
// use "HH:MM[:SS]" for a time of day and "dN HH:MM:SS" for a point in time.
#pragma once

#include <chrono>
#include <optional>
#include <string>
#include <string_view>

namespace icars {

using Time = std::chrono::milliseconds;  // time since day 0, 00:00

inline constexpr Time kDay = std::chrono::hours(24);

// "d0 18:05:00"; milliseconds are appended (".250") only when not zero.
std::string format_time(Time t);

// Parses a time of day "HH:MM" or "HH:MM:SS" (hours 0-23, minutes and seconds 0-59);
// nullopt for anything else ("25:99", "7", "07:00pm").
std::optional<Time> parse_time_of_day(std::string_view text);

// Convenience for tests and demos: day `day` at hh:mm:ss.
constexpr Time at_time(int day, int hours, int minutes, int seconds = 0) {
  return kDay * day + std::chrono::hours(hours) + std::chrono::minutes(minutes) +
         std::chrono::seconds(seconds);
}

}  // namespace icars
