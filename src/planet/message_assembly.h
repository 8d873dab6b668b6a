// The receive side of a PLANET connection without its socket (docs/protocol.md 5, the paper's
// message assembly): an incoming multi-frame message checked frame by frame against the order
// and the flow-control window, joined without copying what arrived before, and the credit the
// receiver owes its sender. Connection adds the budgets shared by all connections and the
// sending of acks; message_assembly_test.cc drives it alone.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "icars/planet/connection.h"
#include "icars/planet/frame.h"

namespace icars::planet::detail {

// How far ahead of the frames received a receiver grants credit to each incoming message (1 MiB).
inline constexpr std::uint32_t kGrantAheadFrames = 64;
// Incoming multi-frame messages are assembled in blocks of this size.
inline constexpr std::size_t kBlockBytes = 1u << 20;

struct IncomingMessage {
  using TimePoint = std::chrono::steady_clock::time_point;

  std::uint32_t msg_no = 0;
  std::uint32_t next_frame = 0;
  std::uint32_t granted = kWindowFrames;  // frames the sender may send so far
  std::uint32_t owed_acks = 0;            // acks held back by the receive budget
  bool refused = false;
  std::size_t reserved = 0;  // its share of the total receive budget
  TimePoint last_progress;   // last frame, or last credit granted
  // The message so far, in blocks of kBlockBytes: growing a large message never copies what
  // arrived before (no reallocation on the io thread).
  std::vector<std::vector<std::byte>> blocks;
  std::size_t size = 0;

  // Why `h` cannot be this message's next frame (out of order, or beyond the credit granted),
  // as a protocol error; nullopt when it fits. Frames of a refused message that were in flight
  // when the refusal was sent are not held to the window.
  std::optional<std::string> misfit(const FrameHeader& h) const;

  // Adds a frame's payload. The first block may be `spare`, the first block of an earlier
  // message (memory already paged in), which it then takes.
  void append(std::span<const std::byte> payload, std::vector<std::byte>& spare);

  // What the message may still make the receiver hold: what arrived plus the credit not yet used.
  std::size_t holding() const;

  // After a frame arrived: the DATA_ACK(more)s to owe the sender so that its credit reaches
  // kGrantAheadFrames beyond what arrived (a receiver may grant more at any time, protocol 5.3),
  // in whole acks of kAckEvery frames; 0 when enough is granted or owed already.
  std::uint32_t acks_to_owe() const;

  // One owed ack sent: kAckEvery more frames granted at `now`.
  void grant_one(TimePoint now);

  // Whether the sender has had credit and sent nothing for `limit` or longer at `now`.
  bool stalled(TimePoint now, std::chrono::steady_clock::duration limit) const;
};

}  // namespace icars::planet::detail
