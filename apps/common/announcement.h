// The line `icars run` prints on stdout once its mediating server listens, and how the programs
// and tests that start `icars run` read the server's port back from it:
//
//   [icars] mediating server on 127.0.0.1:40731; policy paper_home.xml; house paper_house
#pragma once

#include <fmt/format.h>

#include <cstdint>
#include <string>
#include <string_view>

namespace icars::app {

inline constexpr std::string_view kServerAnnouncement = "[icars] mediating server on ";

inline std::string server_announcement(std::string_view host, std::uint16_t port, std::string_view policy,
                                       std::string_view house) {
  return fmt::format("{}{}:{}; policy {}; house {}", kServerAnnouncement, host, port, policy, house);
}

// The PORT of an announcement line; "" for any other line.
inline std::string announced_port(std::string_view line) {
  if (!line.starts_with(kServerAnnouncement)) return "";
  line.remove_prefix(kServerAnnouncement.size());
  const auto endpoint = line.substr(0, line.find(';'));
  const auto colon = endpoint.rfind(':');
  if (colon == std::string_view::npos) return "";
  return std::string(endpoint.substr(colon + 1));
}

}  // namespace icars::app
