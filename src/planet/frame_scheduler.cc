#include "frame_scheduler.h"

#include <algorithm>
#include <utility>

namespace icars::planet::detail {

std::size_t FrameScheduler::next_frames(std::size_t max_bytes, std::size_t max_frames, TimePoint now,
                                        std::vector<ScheduledFrame>& frames, std::vector<OutgoingMessage>& finished,
                                        std::vector<OutgoingMessage>& retired) {
  std::size_t bytes = 0;
  std::size_t count = 0;
  std::size_t in_progress = 0;
  for (const auto& m : messages_) in_progress += m.next_frame > 0 ? 1 : 0;
  bool progress = true;
  while (progress && bytes < max_bytes && count < max_frames) {
    progress = false;
    bool in_order_pending = false;  // an earlier in_order message has frames left
    for (auto it = messages_.begin(); it != messages_.end() && bytes < max_bytes && count < max_frames;) {
      OutgoingMessage& m = *it;
      const bool single_frame = m.single_frame();
      if (m.in_order) {
        if (in_order_pending) {
          ++it;
          continue;
        }
        in_order_pending = true;  // until its final frame goes, below
      }
      if ((m.credit == 0 && !m.aborted) ||
          (m.next_frame == 0 && !single_frame && in_progress >= kMaxInterleavedMessages)) {
        ++it;
        continue;
      }
      if (m.next_frame == 0 && !single_frame) ++in_progress;
      const std::size_t n = m.aborted ? 0 : std::min(kMaxFramePayload, m.payload.size() - m.offset);
      FrameHeader h;
      h.length = static_cast<std::uint32_t>(kFrameHeaderSize + n);
      h.msg_no = m.msg_no;
      h.frame_no = m.next_frame++;
      h.final = m.aborted || m.offset + n == m.payload.size();
      h.code = FrameCode::data;
      frames.push_back({h, std::span<const std::byte>(m.payload).subspan(m.offset, n)});
      m.offset += n;
      --m.credit;
      if (m.credit == 0 && !m.starved_since) m.starved_since = now;
      bytes += h.length;
      ++count;
      progress = true;
      if (h.final) {
        if (m.in_order) in_order_pending = false;
        if (m.next_frame > 1 && !single_frame) --in_progress;
        (m.aborted ? retired : finished).push_back(std::move(m));
        it = messages_.erase(it);
      } else {
        ++it;
      }
    }
  }
  return bytes;
}

bool FrameScheduler::grant(std::uint32_t msg_no) {
  auto it = std::find_if(messages_.begin(), messages_.end(), [&](const OutgoingMessage& m) { return m.msg_no == msg_no; });
  if (it == messages_.end()) return false;
  it->credit += kAckEvery;
  it->starved_since.reset();
  return true;
}

std::optional<FrameScheduler::Refusal> FrameScheduler::refuse(std::uint32_t msg_no) {
  auto it = std::find_if(messages_.begin(), messages_.end(), [&](const OutgoingMessage& m) { return m.msg_no == msg_no; });
  if (it == messages_.end() || it->aborted) return std::nullopt;
  Refusal refusal{std::move(it->on_sent), it->payload.size() - it->offset};
  it->on_sent = {};
  it->aborted = true;
  it->starved_since.reset();
  return refusal;
}

const OutgoingMessage* FrameScheduler::starved(TimePoint now, std::chrono::steady_clock::duration limit) const {
  for (const auto& m : messages_) {
    if (m.starved_since && now - *m.starved_since >= limit) return &m;
  }
  return nullptr;
}

}  // namespace icars::planet::detail
