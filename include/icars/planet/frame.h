// PLANET message transfer layer: the frame header and the six transport messages.
//
// Every byte on a PLANET connection belongs to a frame: a fixed 20-byte header followed by at
// most 16 KiB of payload. Messages larger than one frame are divided into frames that share a
// msg# and carry increasing frame# values; the last one has final = 1. All integers are
// big-endian. docs/protocol.md is the normative description; this header mirrors it.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

namespace icars::planet {

inline constexpr std::uint32_t kFrameMagic = 0x504C4E54;  // "PLNT"
inline constexpr std::size_t kFrameHeaderSize = 20;
inline constexpr std::size_t kMaxFramePayload = 16 * 1024;  // the paper's 16 K frames
inline constexpr std::uint8_t kProtocolMajor = 1;
inline constexpr std::uint8_t kProtocolMinor = 0;
inline constexpr std::size_t kMaxControlPayload = 1024;  // CONNECT, CONNECT_ACK, DATA_ACK

enum class FrameCode : std::uint8_t {
  connect = 1,
  connect_ack = 2,
  heartbeat = 3,
  heartbeat_ack = 4,
  data = 5,
  data_ack = 6,
};

std::string_view to_string(FrameCode code) noexcept;

// DATA_ACK control codes (paper Fig. 7).
enum class AckCode : std::uint8_t {
  more = 0x00,     // "request for more frames": grants the sender another half window
  no_more = 0xFF,  // "request for no more frames": the receiver refuses the rest of the message
};

inline constexpr std::uint8_t kConnectAccept = 0x00;
inline constexpr std::uint8_t kConnectDeny = 0xFF;

struct FrameHeader {
  std::uint32_t length = kFrameHeaderSize;  // whole frame, header included
  std::uint32_t msg_no = 0;
  std::uint32_t frame_no = 0;
  bool final = true;
  std::uint8_t version_major = kProtocolMajor;
  std::uint8_t version_minor = kProtocolMinor;
  FrameCode code = FrameCode::data;

  std::size_t payload_size() const { return length - kFrameHeaderSize; }
};

using FrameHeaderBytes = std::array<std::byte, kFrameHeaderSize>;

FrameHeaderBytes encode_header(const FrameHeader& header) noexcept;

// Result of looking at the first bytes of a frame. `error` is set (and names the field) when
// the bytes cannot be the start of a valid frame; the connection must then be closed.
struct HeaderParse {
  std::optional<FrameHeader> header;  // empty with no error: need more bytes
  std::string error;
  bool version_mismatch = false;  // the error is only an unsupported major version
};

HeaderParse parse_header(std::span<const std::byte> bytes);

}  // namespace icars::planet
