// Fuzz target: the PLANET frame header parser, driven like a receiver drives it.
//
// The input is a byte stream as it would arrive on a connection. Like Connection::on_read, the
// target parses a header at the current position, stops at the first error (the connection
// would close) or when the stream ends mid-frame, and otherwise skips the frame and goes on.
// At every frame it also feeds the parser each shorter prefix, as partial reads deliver them.
// It checks what the receiver relies on: a prefix shorter than a header never yields one, a
// parsed header re-encodes to the same 20 bytes and respects the length limits, and an error
// always comes without a header and with a message. The reassembly of multi-frame messages
// lives inside Connection, which needs a socket, and is not reached from here.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <span>

#include "fuzz_util.h"
#include "icars/planet/frame.h"

namespace {

using namespace icars::planet;

void check(bool ok, const char* what) { icars_fuzz::check(ok, "frame_decoder_fuzz", what); }

void check_result(const HeaderParse& parsed, std::span<const std::byte> bytes) {
  if (!parsed.error.empty()) {
    check(!parsed.header, "a header came with an error");
    return;
  }
  check(!parsed.version_mismatch, "version_mismatch set without an error");
  if (!parsed.header) {
    check(bytes.size() < kFrameHeaderSize, "no header and no error for a complete header");
    return;
  }
  check(bytes.size() >= kFrameHeaderSize, "a header from fewer than 20 bytes");
  const FrameHeader& h = *parsed.header;
  const FrameHeaderBytes encoded = encode_header(h);
  check(std::memcmp(encoded.data(), bytes.data(), kFrameHeaderSize) == 0,
        "the parsed header does not re-encode to the bytes it came from");
  check(h.length >= kFrameHeaderSize, "frame length below the header size");
  const std::size_t limit = h.code == FrameCode::data ? kMaxFramePayload : kMaxControlPayload;
  check(h.payload_size() <= limit, "payload above the frame limit");
  check(h.code == FrameCode::data || (h.final && h.frame_no == 0),
        "a control frame that is not a single final frame");
  check(h.version_major == kProtocolMajor, "a header of another major version");
  check(to_string(h.code) != "UNKNOWN", "a header with an unknown code");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::span<const std::byte> stream(reinterpret_cast<const std::byte*>(data), size);
  std::size_t at = 0;
  while (at < stream.size()) {
    const std::span<const std::byte> avail = stream.subspan(at);
    // The same frame as a receiver may see it after shorter reads.
    const std::size_t prefixes = avail.size() < kFrameHeaderSize ? avail.size() : kFrameHeaderSize;
    for (std::size_t n = 0; n < prefixes; ++n) {
      const HeaderParse partial = parse_header(avail.first(n));
      check(!partial.header, "a header from a partial read");
      check(partial.error.empty() || n >= 4, "an error before the magic is complete");
      check_result(partial, avail.first(n));
    }
    const HeaderParse parsed = parse_header(avail);
    check_result(parsed, avail);
    if (!parsed.error.empty() || !parsed.header) break;  // closed, or waiting for more bytes
    if (avail.size() < parsed.header->length) break;     // the payload has not arrived yet
    at += parsed.header->length;
  }
  return 0;
}
