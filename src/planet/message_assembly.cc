#include "message_assembly.h"

#include <fmt/format.h>

#include <algorithm>

#include "buffer_pool.h"

namespace icars::planet::detail {

std::optional<std::string> IncomingMessage::misfit(const FrameHeader& h) const {
  if (h.frame_no != next_frame) {
    return fmt::format("frame #{} of message #{} out of order (expected #{})", h.frame_no, h.msg_no, next_frame);
  }
  if (h.frame_no >= granted && !refused) {
    return fmt::format("frame #{} of message #{} exceeds the flow-control window (granted {} frames)", h.frame_no,
                       h.msg_no, granted);
  }
  return std::nullopt;
}

void IncomingMessage::append(std::span<const std::byte> payload, std::vector<std::byte>& spare) {
  while (!payload.empty()) {
    if (blocks.empty() || blocks.back().size() == kBlockBytes) {
      if (blocks.empty() && spare.capacity() > 0) {
        blocks.push_back(std::move(spare));
        spare = {};
        blocks.back().clear();
      } else {
        blocks.push_back(take_buffer(kBlockBytes));
      }
    }
    std::vector<std::byte>& block = blocks.back();
    const std::size_t n = std::min(payload.size(), kBlockBytes - block.size());
    block.insert(block.end(), payload.begin(), payload.begin() + static_cast<std::ptrdiff_t>(n));
    payload = payload.subspan(n);
    size += n;
  }
}

std::size_t IncomingMessage::holding() const {
  return refused ? 0 : size + std::size_t{granted - next_frame} * kMaxFramePayload;
}

std::uint32_t IncomingMessage::acks_to_owe() const {
  const std::uint32_t wanted = next_frame + kGrantAheadFrames;
  const std::uint32_t promised = granted + owed_acks * kAckEvery;
  return wanted >= promised + kAckEvery ? (wanted - promised) / kAckEvery : 0;
}

void IncomingMessage::grant_one(TimePoint now) {
  --owed_acks;
  granted += kAckEvery;
  last_progress = now;
}

bool IncomingMessage::stalled(TimePoint now, std::chrono::steady_clock::duration limit) const {
  return !refused && granted > next_frame && now - last_progress >= limit;
}

}  // namespace icars::planet::detail
