#include "icars/planet/endpoint.h"

#include <fmt/format.h>

#include <algorithm>
#include <stdexcept>

namespace icars::planet {

std::string Endpoint::to_string() const {
  if (host.find(':') != std::string::npos) return fmt::format("[{}]:{}", host, port);
  return fmt::format("{}:{}", host, port);
}

Endpoint parse_endpoint(std::string_view text, bool allow_any_port) {
  auto bad = [&](std::string_view why) {
    return std::invalid_argument(fmt::format("'{}' is not host:port: {}", text, why));
  };
  const auto colon = text.rfind(':');
  if (colon == std::string_view::npos) throw bad("no ':' before the port");
  std::string_view host = text.substr(0, colon);
  const std::string_view port = text.substr(colon + 1);
  if (host.starts_with('[')) {
    if (!host.ends_with(']') || host.size() < 3) throw bad("an IPv6 address needs its closing ']'");
    host = host.substr(1, host.size() - 2);
  } else if (host.find(':') != std::string_view::npos) {
    throw bad("write an IPv6 address in brackets, [::1]:4711");
  }
  if (host.empty()) throw bad("the host is empty");
  if (host.find_first_of(" \t\r\n") != std::string_view::npos) throw bad("the host contains blanks");
  if (port.empty()) throw bad("the port is empty");
  if (port.size() > 5 || !std::all_of(port.begin(), port.end(), [](char c) { return c >= '0' && c <= '9'; })) {
    throw bad("the port is not a number from 1 to 65535");
  }
  const unsigned long number = std::stoul(std::string(port));
  if (number > 65535) throw bad("the port is not a number from 1 to 65535");
  if (number == 0 && !allow_any_port) throw bad("port 0 is only for a listener");
  return Endpoint{std::string(host), static_cast<std::uint16_t>(number)};
}

}  // namespace icars::planet
