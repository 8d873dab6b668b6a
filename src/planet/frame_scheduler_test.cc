// The I/O scheduler without a socket: which frames of which messages go out in which order,
// within the flow-control credit and the interleaving limit (docs/protocol.md 5).
#include "frame_scheduler.h"

#include <gtest/gtest.h>

#include <set>
#include <string>
#include <vector>

namespace icars::planet::detail {
namespace {

using Clock = std::chrono::steady_clock;
constexpr std::size_t kAll = 1u << 30;  // no batch limit

OutgoingMessage message(std::uint32_t msg_no, std::size_t bytes, bool in_order = false) {
  OutgoingMessage m;
  m.msg_no = msg_no;
  m.payload.assign(bytes, std::byte{static_cast<unsigned char>(msg_no)});
  m.in_order = in_order;
  return m;
}

// "msg_no.frame_no" of each frame, with "!" after a final one.
std::vector<std::string> order(const std::vector<ScheduledFrame>& frames) {
  std::vector<std::string> out;
  for (const auto& f : frames) {
    out.push_back(std::to_string(f.header.msg_no) + "." + std::to_string(f.header.frame_no) +
                  (f.header.final ? "!" : ""));
  }
  return out;
}

struct Batch {
  std::vector<ScheduledFrame> frames;
  std::vector<OutgoingMessage> finished, retired;
  std::size_t bytes = 0;
};

Batch next(FrameScheduler& s, std::size_t max_bytes = kAll, std::size_t max_frames = kAll,
           Clock::time_point now = Clock::time_point{}) {
  Batch b;
  b.bytes = s.next_frames(max_bytes, max_frames, now, b.frames, b.finished, b.retired);
  return b;
}

TEST(FrameScheduler, SmallMessagesGoOutWholeInTheOrderQueued) {
  FrameScheduler s;
  s.add(message(1, 10));
  s.add(message(2, 0));
  s.add(message(3, kMaxFramePayload));
  const auto b = next(s);
  EXPECT_EQ(order(b.frames), (std::vector<std::string>{"1.0!", "2.0!", "3.0!"}));
  EXPECT_EQ(b.bytes, 3 * kFrameHeaderSize + 10 + kMaxFramePayload);
  ASSERT_EQ(b.finished.size(), 3u);
  EXPECT_TRUE(s.empty());
  // The payload spans point into the finished messages' bytes.
  EXPECT_EQ(b.frames[0].payload.data(), b.finished[0].payload.data());
  EXPECT_EQ(b.frames[0].header.length, kFrameHeaderSize + 10);
}

TEST(FrameScheduler, LargeMessagesTakeTurnsFrameByFrame) {
  FrameScheduler s;
  s.add(message(1, 3 * kMaxFramePayload));
  s.add(message(2, 2 * kMaxFramePayload + 1));
  s.add(message(3, 5));
  const auto b = next(s);
  EXPECT_EQ(order(b.frames),
            (std::vector<std::string>{"1.0", "2.0", "3.0!", "1.1", "2.1", "1.2!", "2.2!"}));
  EXPECT_EQ(b.frames.back().payload.size(), 1u);
  ASSERT_EQ(b.finished.size(), 3u);
  EXPECT_EQ(b.finished[0].msg_no, 3u);  // in the order they completed
}

TEST(FrameScheduler, AMessageStopsAtItsCreditUntilADataAckGrantsMore) {
  FrameScheduler s;
  s.add(message(1, 20 * kMaxFramePayload));
  const Clock::time_point t0{std::chrono::seconds(5)};
  auto b = next(s, kAll, kAll, t0);
  EXPECT_EQ(b.frames.size(), kWindowFrames);
  EXPECT_TRUE(b.finished.empty());
  // Out of credit since t0: starved once the limit passed, not before.
  EXPECT_EQ(s.starved(t0 + std::chrono::seconds(1), std::chrono::seconds(2)), nullptr);
  const auto* starved = s.starved(t0 + std::chrono::seconds(2), std::chrono::seconds(2));
  ASSERT_NE(starved, nullptr);
  EXPECT_EQ(starved->msg_no, 1u);
  EXPECT_TRUE(next(s).frames.empty());

  EXPECT_TRUE(s.grant(1));
  EXPECT_EQ(s.starved(t0 + std::chrono::hours(1), std::chrono::seconds(2)), nullptr);
  b = next(s);
  EXPECT_EQ(order(b.frames), (std::vector<std::string>{"1.8", "1.9", "1.10", "1.11"}));
  EXPECT_FALSE(s.grant(7));  // unknown: written whole already
}

TEST(FrameScheduler, ARefusedMessageEndsWithOneEmptyFinalFrameAndIsRetired) {
  FrameScheduler s;
  bool told = false;
  auto m = message(1, 20 * kMaxFramePayload);
  m.on_sent = [&](const std::exception_ptr&) { told = true; };
  s.add(std::move(m));
  next(s);  // the whole window
  const auto refusal = s.refuse(1);
  ASSERT_TRUE(refusal.has_value());
  EXPECT_EQ(refusal->unsent_bytes, 12 * kMaxFramePayload);
  ASSERT_TRUE(refusal->on_sent);
  refusal->on_sent(nullptr);
  EXPECT_TRUE(told);
  EXPECT_FALSE(s.refuse(1).has_value());  // once
  const auto b = next(s);  // sent without credit
  EXPECT_EQ(order(b.frames), (std::vector<std::string>{"1.8!"}));
  EXPECT_TRUE(b.frames[0].payload.empty());
  EXPECT_TRUE(b.finished.empty());
  ASSERT_EQ(b.retired.size(), 1u);
  EXPECT_TRUE(s.empty());
}

TEST(FrameScheduler, InOrderMessagesWaitForTheEarlierOnesToGoOutWhole) {
  FrameScheduler s;
  s.add(message(1, 2 * kMaxFramePayload, true));
  s.add(message(2, 10, true));  // small, but after message 1
  s.add(message(3, 10));        // not ordered: goes at once
  const auto b = next(s);
  EXPECT_EQ(order(b.frames), (std::vector<std::string>{"1.0", "3.0!", "1.1!", "2.0!"}));
}

TEST(FrameScheduler, NoMoreThanTheInterleavingLimitOfLargeMessagesIsStartedAtOnce) {
  FrameScheduler s;
  for (std::uint32_t i = 1; i <= kMaxInterleavedMessages + 2; ++i) s.add(message(i, 20 * kMaxFramePayload));
  s.add(message(100, 10));  // a single-frame message is never held back
  const auto b = next(s);
  std::set<std::uint32_t> started;
  for (const auto& f : b.frames) started.insert(f.header.msg_no);
  EXPECT_EQ(started.size(), kMaxInterleavedMessages + 1);
  EXPECT_TRUE(started.contains(100));
  EXPECT_FALSE(started.contains(kMaxInterleavedMessages + 1));
  // One finishes (credit for all of message 1): the next one starts.
  for (int i = 0; i < 3; ++i) s.grant(1);
  const auto more = next(s);
  ASSERT_FALSE(more.finished.empty());
  EXPECT_EQ(more.finished[0].msg_no, 1u);
  bool seventeenth = false;
  for (const auto& f : more.frames) seventeenth = seventeenth || f.header.msg_no == kMaxInterleavedMessages + 1;
  EXPECT_TRUE(seventeenth);
}

TEST(FrameScheduler, ABatchStopsAtItsLimitsAndEachBatchStartsWithTheOldestMessage) {
  FrameScheduler s;
  s.add(message(1, 4 * kMaxFramePayload));
  s.add(message(2, 4 * kMaxFramePayload));
  auto b = next(s, kAll, 3);
  EXPECT_EQ(order(b.frames), (std::vector<std::string>{"1.0", "2.0", "1.1"}));
  b = next(s, 1);  // one byte: one frame crosses it
  EXPECT_EQ(order(b.frames), (std::vector<std::string>{"1.2"}));
  b = next(s);
  EXPECT_EQ(order(b.frames), (std::vector<std::string>{"1.3!", "2.1", "2.2", "2.3!"}));
  s.add(message(3, 10));
  b = next(s, 0);
  EXPECT_TRUE(b.frames.empty());
}

TEST(FrameScheduler, TakeAllEmptiesTheQueue) {
  FrameScheduler s;
  s.add(message(1, 10));
  s.add(message(2, 3 * kMaxFramePayload));
  next(s, kAll, 1);
  const auto all = s.take_all();
  EXPECT_EQ(all.size(), 1u);
  EXPECT_TRUE(s.empty());
  EXPECT_TRUE(next(s).frames.empty());
}

}  // namespace
}  // namespace icars::planet::detail
