#include "icars/coros/messages.h"

#include <fmt/format.h>

#include <array>

namespace icars::coros {

namespace {
constexpr std::byte kMagic0{'C'};
constexpr std::byte kMagic1{'R'};
constexpr std::size_t kMaxSender = 255;
}  // namespace

std::string_view to_string(MessageCode code) {
  switch (code) {
    case MessageCode::hello:
      return "HELLO";
    case MessageCode::auction:
      return "AUCTION";
    case MessageCode::bid:
      return "BID";
    case MessageCode::award:
      return "AWARD";
    case MessageCode::award_ack:
      return "AWARD_ACK";
    case MessageCode::revoke:
      return "REVOKE";
    case MessageCode::task_status:
      return "TASK_STATUS";
    case MessageCode::result:
      return "RESULT";
    case MessageCode::result_ack:
      return "RESULT_ACK";
    case MessageCode::decline:
      return "DECLINE";
    case MessageCode::errand_auction:
      return "ERRAND_AUCTION";
    case MessageCode::errand_award:
      return "ERRAND_AWARD";
  }
  return "message";
}

std::vector<std::byte> encode_header(MessageCode code, std::string_view sender) {
  if (sender.empty() || sender.size() > kMaxSender) {
    throw CorosError(
        fmt::format("agent id must be 1 to {} bytes, got {}", kMaxSender, sender.size()));
  }
  std::vector<std::byte> out;
  out.reserve(64);
  planet::Writer w(out);
  w.raw(std::array{kMagic0, kMagic1});
  w.u8(kProtocolVersion);
  w.u16(static_cast<std::uint16_t>(code));
  w.str(sender);
  return out;
}

Datagram decode_datagram(std::span<const std::byte> bytes) {
  if (bytes.size() > kMaxDatagram) {
    throw CorosError(fmt::format("datagram of {} bytes exceeds {}", bytes.size(), kMaxDatagram));
  }
  if (bytes.size() < 2 || bytes[0] != kMagic0 || bytes[1] != kMagic1) {
    throw CorosError("not a COROS datagram (bad magic)");
  }
  try {
    planet::Reader r(bytes.subspan(2));
    const std::uint8_t version = r.u8();
    if (version != kProtocolVersion && version != kAuthenticatedVersion) {
      throw CorosError(fmt::format("unsupported COROS version {} (this agent speaks {} and {})",
                                   version, kProtocolVersion, kAuthenticatedVersion));
    }
    Datagram d;
    d.code = static_cast<MessageCode>(r.u16());
    d.sender = r.str();
    if (d.sender.empty() || d.sender.size() > kMaxSender) {
      throw CorosError(
          fmt::format("sender id of {} bytes (must be 1 to {})", d.sender.size(), kMaxSender));
    }
    const std::size_t trailer = version == kAuthenticatedVersion ? kAuthTrailerSize : 0;
    if (r.remaining() <= trailer) {
      throw CorosError(trailer == 0 ? std::string("datagram has no message body")
                                    : fmt::format("signed datagram of {} bytes after the header "
                                                  "has no room for a body and its {}-byte trailer",
                                                  r.remaining(), trailer));
    }
    const auto body = r.raw(r.remaining() - trailer);
    d.body.assign(body.begin(), body.end());
    if (trailer != 0) {
      AuthenticationTrailer t;
      t.generation = r.u64();
      t.counter = r.u64();
      d.authentication = t;  // the tag, the last kAuthTagSize bytes, is left to the verifier
    }
    return d;
  } catch (const planet::Error& e) {
    throw CorosError(std::string("truncated COROS header: ") + e.what());
  }
}

}  // namespace icars::coros
