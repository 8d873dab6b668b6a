// The frame header: byte-exact encoding and rejection of malformed headers.
#include "icars/planet/frame.h"

#include <gtest/gtest.h>

#include <vector>

namespace icars::planet {
namespace {

std::vector<std::byte> bytes(std::initializer_list<int> v) {
  std::vector<std::byte> out;
  for (int b : v) out.push_back(std::byte(b));
  return out;
}

TEST(Frame, HeaderEncodingIsByteExact) {
  FrameHeader h;
  h.length = 0x00000015;
  h.msg_no = 0x01020304;
  h.frame_no = 7;
  h.final = false;
  h.code = FrameCode::data;
  const auto out = encode_header(h);
  const auto expected = bytes({0x50, 0x4C, 0x4E, 0x54, 0, 0, 0, 0x15, 1, 2, 3, 4, 0, 0, 0, 7, 0,
                               kProtocolMajor, kProtocolMinor, 5});
  EXPECT_EQ(std::vector<std::byte>(out.begin(), out.end()), expected);
}

TEST(Frame, ParseRoundTrip) {
  FrameHeader h;
  h.length = kFrameHeaderSize + 100;
  h.msg_no = 99;
  h.frame_no = 3;
  h.final = true;
  const auto out = encode_header(h);
  const auto parsed = parse_header(out);
  ASSERT_TRUE(parsed.header) << parsed.error;
  EXPECT_EQ(parsed.header->length, h.length);
  EXPECT_EQ(parsed.header->msg_no, 99u);
  EXPECT_EQ(parsed.header->frame_no, 3u);
  EXPECT_TRUE(parsed.header->final);
  EXPECT_EQ(parsed.header->code, FrameCode::data);
}

TEST(Frame, NeedsMoreBytesWithoutError) {
  const auto out = encode_header(FrameHeader{});
  const auto parsed = parse_header(std::span(out).first(10));
  EXPECT_FALSE(parsed.header);
  EXPECT_TRUE(parsed.error.empty());
}

TEST(Frame, RejectsBadMagicAsSoonAsFourBytesArrive) {
  const auto b = bytes({'G', 'E', 'T', ' '});
  const auto parsed = parse_header(b);
  EXPECT_FALSE(parsed.header);
  EXPECT_NE(parsed.error.find("bad magic"), std::string::npos) << parsed.error;
}

TEST(Frame, RejectsAbsurdLength) {
  FrameHeader h;
  h.length = 0x7FFFFFFF;
  const auto parsed = parse_header(encode_header(h));
  EXPECT_NE(parsed.error.find("exceeds the limit"), std::string::npos) << parsed.error;
}

TEST(Frame, RejectsLengthShorterThanHeader) {
  FrameHeader h;
  h.length = 3;
  EXPECT_NE(parse_header(encode_header(h)).error.find("shorter than"), std::string::npos);
}

TEST(Frame, RejectsUnknownCodeBadFinalAndOtherVersion) {
  auto raw = encode_header(FrameHeader{});
  raw[19] = std::byte{42};
  EXPECT_NE(parse_header(raw).error.find("unknown frame code 42"), std::string::npos);
  raw = encode_header(FrameHeader{});
  raw[16] = std::byte{2};
  EXPECT_NE(parse_header(raw).error.find("bad final flag"), std::string::npos);
  raw = encode_header(FrameHeader{});
  raw[17] = std::byte{9};
  const auto parsed = parse_header(raw);
  EXPECT_TRUE(parsed.version_mismatch);
  EXPECT_NE(parsed.error.find("unsupported protocol version 9.0"), std::string::npos);
}

TEST(Frame, ControlFramesMustBeSingleAndSmall) {
  FrameHeader h;
  h.code = FrameCode::heartbeat;
  h.final = false;
  EXPECT_NE(parse_header(encode_header(h)).error.find("single final frame"), std::string::npos);
  h.final = true;
  h.length = static_cast<std::uint32_t>(kFrameHeaderSize + kMaxControlPayload + 1);
  EXPECT_NE(parse_header(encode_header(h)).error.find("exceeds the limit"), std::string::npos);
}

}  // namespace
}  // namespace icars::planet
