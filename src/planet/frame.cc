#include "icars/planet/frame.h"

#include <fmt/format.h>

#include "icars/planet/detail/byte_order.h"

namespace icars::planet {
using namespace detail;

std::string_view to_string(FrameCode code) noexcept {
  switch (code) {
    case FrameCode::connect:
      return "CONNECT";
    case FrameCode::connect_ack:
      return "CONNECT_ACK";
    case FrameCode::heartbeat:
      return "HEARTBEAT";
    case FrameCode::heartbeat_ack:
      return "HEARTBEAT_ACK";
    case FrameCode::data:
      return "DATA";
    case FrameCode::data_ack:
      return "DATA_ACK";
  }
  return "UNKNOWN";
}

FrameHeaderBytes encode_header(const FrameHeader& header) noexcept {
  FrameHeaderBytes out{};
  store_be32(out.data(), kFrameMagic);
  store_be32(out.data() + 4, header.length);
  store_be32(out.data() + 8, header.msg_no);
  store_be32(out.data() + 12, header.frame_no);
  out[16] = std::byte{header.final ? std::uint8_t{1} : std::uint8_t{0}};
  out[17] = std::byte{header.version_major};
  out[18] = std::byte{header.version_minor};
  out[19] = std::byte{static_cast<std::uint8_t>(header.code)};
  return out;
}

HeaderParse parse_header(std::span<const std::byte> bytes) {
  HeaderParse result;
  if (bytes.size() >= 4) {
    const std::uint32_t magic = load_be32(bytes.data());
    if (magic != kFrameMagic) {
      result.error = fmt::format("bad magic 0x{:08X} (expected 0x{:08X} \"PLNT\")", magic, kFrameMagic);
      return result;
    }
  }
  if (bytes.size() < kFrameHeaderSize) return result;

  FrameHeader h;
  h.length = load_be32(bytes.data() + 4);
  h.msg_no = load_be32(bytes.data() + 8);
  h.frame_no = load_be32(bytes.data() + 12);
  const auto final_byte = std::to_integer<std::uint8_t>(bytes[16]);
  h.version_major = std::to_integer<std::uint8_t>(bytes[17]);
  h.version_minor = std::to_integer<std::uint8_t>(bytes[18]);
  const auto code = std::to_integer<std::uint8_t>(bytes[19]);

  if (final_byte > 1) {
    result.error = fmt::format("bad final flag {} (expected 0 or 1)", final_byte);
    return result;
  }
  h.final = final_byte == 1;
  if (h.version_major != kProtocolMajor) {
    result.error = fmt::format("unsupported protocol version {}.{} (this peer speaks {}.x)",
                               h.version_major, h.version_minor, kProtocolMajor);
    result.version_mismatch = true;
    return result;
  }
  if (code < static_cast<std::uint8_t>(FrameCode::connect) ||
      code > static_cast<std::uint8_t>(FrameCode::data_ack)) {
    result.error = fmt::format("unknown frame code {}", code);
    return result;
  }
  h.code = static_cast<FrameCode>(code);
  if (h.length < kFrameHeaderSize) {
    result.error = fmt::format("frame length {} is shorter than the {}-byte header", h.length,
                               kFrameHeaderSize);
    return result;
  }
  const std::size_t limit = h.code == FrameCode::data ? kMaxFramePayload : kMaxControlPayload;
  if (h.payload_size() > limit) {
    result.error = fmt::format("{} frame length {} exceeds the limit of {} bytes", to_string(h.code),
                               h.length, limit + kFrameHeaderSize);
    return result;
  }
  if (h.code != FrameCode::data && (!h.final || h.frame_no != 0)) {
    result.error = fmt::format("{} frame must be a single final frame", to_string(h.code));
    return result;
  }
  result.header = h;
  return result;
}

}  // namespace icars::planet
