// Endpoints as users write them: every program that takes host:port reads it here.
#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

#include "icars/planet/endpoint.h"

namespace icars::planet {
namespace {

std::string refusal(const std::string& text, bool allow_any_port = false) {
  try {
    parse_endpoint(text, allow_any_port);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "(accepted)";
}

TEST(Endpoint, ReadsHostsAddressesAndBracketedIpv6) {
  EXPECT_EQ(parse_endpoint("127.0.0.1:4711").host, "127.0.0.1");
  EXPECT_EQ(parse_endpoint("127.0.0.1:4711").port, 4711);
  EXPECT_EQ(parse_endpoint("home.local:1").host, "home.local");
  EXPECT_EQ(parse_endpoint("[::1]:65535").host, "::1");
  EXPECT_EQ(parse_endpoint("[::1]:65535").port, 65535);
  EXPECT_EQ(parse_endpoint("0.0.0.0:0", true).port, 0);
  EXPECT_EQ(parse_endpoint("[::1]:80").to_string(), "[::1]:80");
  EXPECT_EQ(parse_endpoint("localhost:80").to_string(), "localhost:80");
}

TEST(Endpoint, EveryMistakeIsNamed) {
  EXPECT_EQ(refusal("localhost"), "'localhost' is not host:port: no ':' before the port");
  EXPECT_EQ(refusal(":4711"), "':4711' is not host:port: the host is empty");
  EXPECT_EQ(refusal("[]:4711"), "'[]:4711' is not host:port: an IPv6 address needs its closing ']'");
  EXPECT_EQ(refusal("::1:4711"), "'::1:4711' is not host:port: write an IPv6 address in brackets, [::1]:4711");
  EXPECT_EQ(refusal("host:"), "'host:' is not host:port: the port is empty");
  EXPECT_EQ(refusal("host:http"), "'host:http' is not host:port: the port is not a number from 1 to 65535");
  EXPECT_EQ(refusal("host:-1"), "'host:-1' is not host:port: the port is not a number from 1 to 65535");
  EXPECT_EQ(refusal("host:65536"), "'host:65536' is not host:port: the port is not a number from 1 to 65535");
  EXPECT_EQ(refusal("host:99999999999999999999"),
            "'host:99999999999999999999' is not host:port: the port is not a number from 1 to 65535");
  EXPECT_EQ(refusal("host:12x"), "'host:12x' is not host:port: the port is not a number from 1 to 65535");
  EXPECT_EQ(refusal("host:0"), "'host:0' is not host:port: port 0 is only for a listener");
  EXPECT_EQ(refusal("my host:80"), "'my host:80' is not host:port: the host contains blanks");
}

}  // namespace
}  // namespace icars::planet
