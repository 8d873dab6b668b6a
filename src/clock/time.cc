#include "icars/clock/time.h"

#include <fmt/format.h>

#include <array>
#include <charconv>

namespace icars {

std::string format_time(Time t) {
  const auto ms = t.count();
  const auto day = ms / kDay.count();
  auto rest = ms % kDay.count();
  const auto hours = rest / 3'600'000;
  rest %= 3'600'000;
  const auto minutes = rest / 60'000;
  rest %= 60'000;
  const auto seconds = rest / 1000;
  const auto millis = rest % 1000;
  if (millis != 0) {
    return fmt::format("d{} {:02}:{:02}:{:02}.{:03}", day, hours, minutes, seconds, millis);
  }
  return fmt::format("d{} {:02}:{:02}:{:02}", day, hours, minutes, seconds);
}

namespace {

// Exactly two decimal digits in [0, max].
std::optional<int> two_digits(std::string_view s, int max) {
  if (s.size() != 2) return std::nullopt;
  int value = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
  if (ec != std::errc{} || end != s.data() + s.size() || value < 0 || value > max) {
    return std::nullopt;
  }
  return value;
}

}  // namespace

std::optional<Time> parse_time_of_day(std::string_view text) {
  // "H:MM" is accepted too: people write 7:30.
  const auto colon = text.find(':');
  if (colon == std::string_view::npos) return std::nullopt;
  // Two digits for the hour, a leading '0' added to "7". (Built in a fixed array: GCC 12's
  // -Wrestrict misfires on std::string::insert at -O3.)
  const std::string_view hour_digits = text.substr(0, colon);
  if (hour_digits.empty() || hour_digits.size() > 2) return std::nullopt;
  std::array<char, 2> hour_text{'0', hour_digits.back()};
  if (hour_digits.size() == 2) hour_text[0] = hour_digits.front();
  const auto hours = two_digits(std::string_view(hour_text.data(), hour_text.size()), 23);
  auto rest = text.substr(colon + 1);
  std::optional<int> minutes;
  std::optional<int> seconds = 0;
  if (const auto colon2 = rest.find(':'); colon2 != std::string_view::npos) {
    minutes = two_digits(rest.substr(0, colon2), 59);
    seconds = two_digits(rest.substr(colon2 + 1), 59);
  } else {
    minutes = two_digits(rest, 59);
  }
  if (!hours || !minutes || !seconds) return std::nullopt;
  return std::chrono::hours(*hours) + std::chrono::minutes(*minutes) +
         std::chrono::seconds(*seconds);
}

}  // namespace icars
