// PLANET remote method invocation layer: the five RMI message codes and their fixed headers.
//
// An RMI message is the payload of one transport message (one or more DATA frames). It starts
// with a one-byte code. CALL and NOTIFY carry the servant path, method name and tagged
// arguments; REPLY carries the tagged result; ERROR carries an error kind and an exception;
// STREAM carries one operation on a stream channel. docs/protocol.md is normative.
#pragma once

#include <cstdint>
#include <string_view>

namespace icars::planet {

enum class RmiCode : std::uint8_t {
  call = 1,    // u32 request_id, string path, string method, u8 argc, argc tagged values
  reply = 2,   // u32 request_id, one tagged value (void: the single byte 0x00)
  error = 3,   // u32 request_id, u8 ErrorKind, exception body (type_id, message, properties)
  notify = 4,  // as CALL; request_id is 0 and no reply is sent
  stream = 5,  // u32 stream_id, u8 StreamOp, operation body
};

// STREAM operations. DATA, END and ABORT go from the writer to the reader; PULL and CANCEL from
// the reader to the writer, so the direction tells which end a stream id names.
enum class StreamOp : std::uint8_t {
  data = 1,    // u32 length + bytes: the next chunk, within the credit granted
  pull = 2,    // u32 bytes: credit, the reader accepts this many more bytes
  end = 3,     // no body: the writer has no more data
  cancel = 4,  // string reason: the reader abandons the stream
  abort = 5,   // string reason: the writer abandons the stream
};

inline constexpr std::size_t kRequestIdOffset = 1;  // where CALL's request_id sits

std::string_view to_string(RmiCode code) noexcept;

}  // namespace icars::planet
