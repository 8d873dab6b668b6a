// Where a PLANET server listens or a client connects: "host:port" as users write it on command
// lines and in configuration ("127.0.0.1:4711", "home.local:4711", "[::1]:4711").
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

namespace icars::planet {

struct Endpoint {
  std::string host;        // a name or an address, IPv6 without its brackets
  std::uint16_t port = 0;  // 0 (when allowed): the system picks a free port

  // "host:port", IPv6 addresses in brackets.
  std::string to_string() const;
};

// Parses "host:port" or "[ipv6]:port". The port is decimal digits only, 1-65535, or 0 when
// `allow_any_port` (a listener letting the system choose). Throws std::invalid_argument saying
// what is wrong with `text`.
Endpoint parse_endpoint(std::string_view text, bool allow_any_port = false);

}  // namespace icars::planet
