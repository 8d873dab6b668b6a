// The send side of a PLANET connection without its socket (docs/protocol.md 5, the paper's
// Frame Divider and I/O scheduler): the messages that have frames left, which frame goes out
// next, and the flow-control credit that DATA_ACKs grant. Connection calls it under its send
// lock and writes the frames it picks; frame_scheduler_test.cc drives it alone.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <list>
#include <optional>
#include <span>
#include <vector>

#include "icars/planet/connection.h"
#include "icars/planet/frame.h"

namespace icars::planet::detail {

// A message being sent, kMaxFramePayload bytes per frame.
struct OutgoingMessage {
  std::uint32_t msg_no = 0;
  std::vector<std::byte> payload;
  std::size_t offset = 0;  // bytes already framed
  std::uint32_t next_frame = 0;
  std::uint32_t credit = kWindowFrames;  // frames that may be sent before the next DATA_ACK
  bool aborted = false;   // refused by the peer: only an empty final frame is still sent
  bool in_order = false;  // starts after the earlier in_order messages are written whole
  SendHandler on_sent;
  // Since when the message has had frames left and no credit (waiting for a DATA_ACK).
  std::optional<std::chrono::steady_clock::time_point> starved_since;

  bool single_frame() const { return payload.size() <= kMaxFramePayload; }
};

// A frame to write: its header, and its payload inside the message's bytes (valid while the
// message is queued, finished or retired).
struct ScheduledFrame {
  FrameHeader header;
  std::span<const std::byte> payload;
};

class FrameScheduler {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;

  void add(OutgoingMessage message) { messages_.push_back(std::move(message)); }
  bool empty() const { return messages_.empty(); }
  std::size_t size() const { return messages_.size(); }

  // Appends to `frames` the frames that go out next, fewer than `max_bytes` frame bytes (the
  // last frame may cross it) and at most `max_frames` frames: one frame from each message with
  // credit in turn, so that no message monopolises the link; an in_order message only after the
  // earlier in_order messages went out whole; a multi-frame message started only while fewer
  // than kMaxInterleavedMessages are in progress, so that the receiver's interleaving limit
  // holds. A message whose final frame is among them moves to `finished`, or to `retired` when
  // the peer had refused it. A message left without credit is stamped with `now`. Returns the
  // frame bytes (headers included) appended.
  std::size_t next_frames(std::size_t max_bytes, std::size_t max_frames, TimePoint now,
                          std::vector<ScheduledFrame>& frames, std::vector<OutgoingMessage>& finished,
                          std::vector<OutgoingMessage>& retired);

  // DATA_ACK(more): the message may send kAckEvery more frames. False when it is not queued
  // (it was written whole already).
  bool grant(std::uint32_t msg_no);

  // DATA_ACK(no_more): the message ends with an empty final frame, so that the receiver can
  // forget it. Returns its handler (to tell of the refusal) and the bytes it will not send, or
  // nullopt when it is not queued or was refused already.
  struct Refusal {
    SendHandler on_sent;
    std::size_t unsent_bytes = 0;
  };
  std::optional<Refusal> refuse(std::uint32_t msg_no);

  // The first message that has waited for credit for `limit` or longer at `now`, or null.
  const OutgoingMessage* starved(TimePoint now, std::chrono::steady_clock::duration limit) const;

  // Removes and returns every queued message (the link closed).
  std::list<OutgoingMessage> take_all() { return std::exchange(messages_, {}); }

 private:
  std::list<OutgoingMessage> messages_;  // messages with frames left, in round-robin order
};

}  // namespace icars::planet::detail
