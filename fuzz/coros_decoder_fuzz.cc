// Fuzz target: COROS datagram decoding, as an agent's receive loop does it.
//
// The input is one UDP payload. decode_datagram() checks magic, version and header; the body
// is then read as every message type: as the type its code names (what an agent does), and as
// each other type (a body of the wrong type must be rejected, never misread). The expected
// failure is CorosError. A datagram that decodes as the message its code names must re-encode
// to exactly the input bytes (version 2: less its authentication trailer, which is read here but
// checked by DatagramVerifier, not fuzzed here).
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <span>
#include <vector>

#include "fuzz_util.h"
#include "icars/coros/messages.h"

namespace {

using namespace icars::coros;

template <Message M>
void read_as(const Datagram& d, std::span<const std::byte> input) {
  try {
    const M message = d.body_as<M>();
    if (d.code != M::kCode) return;
    const std::vector<std::byte> again = encode_datagram(d.sender, message);
    // A signed datagram (version 2) re-encodes unsigned: version 1, without the trailer.
    std::vector<std::byte> expected(input.begin(), input.end());
    if (d.authentication) {
      expected.resize(expected.size() - kAuthTrailerSize);
      expected[2] = std::byte{kProtocolVersion};
    }
    if (again != expected) {
      std::fprintf(stderr, "coros_decoder_fuzz: %s re-encodes differently\n",
                   std::string(to_string(M::kCode)).c_str());
      std::abort();
    }
  } catch (const CorosError& e) {
    if (d.code == M::kCode) icars_fuzz::note_rejected("coros_decoder_fuzz", e.what());
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::span<const std::byte> input(reinterpret_cast<const std::byte*>(data), size);
  try {
    const Datagram d = decode_datagram(input);
    (void)to_string(d.code);
    read_as<HelloMessage>(d, input);
    read_as<AuctionMessage>(d, input);
    read_as<BidMessage>(d, input);
    read_as<DeclineMessage>(d, input);
    read_as<AwardMessage>(d, input);
    read_as<AwardAckMessage>(d, input);
    read_as<RevokeMessage>(d, input);
    read_as<TaskStatusMessage>(d, input);
    read_as<ResultMessage>(d, input);
    read_as<ResultAckMessage>(d, input);
  } catch (const CorosError& e) {
    icars_fuzz::note_rejected("coros_decoder_fuzz", e.what());
    // Rejected with a message naming what was wrong: what decode_datagram promises.
  }
  return 0;
}
