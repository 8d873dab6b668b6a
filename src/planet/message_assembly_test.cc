// Message assembly without a socket: an incoming message checked frame by frame, joined in
// blocks, and the credit its receiver owes (docs/protocol.md 5).
#include "message_assembly.h"

#include <gtest/gtest.h>

#include <vector>

namespace icars::planet::detail {
namespace {

using Clock = std::chrono::steady_clock;

FrameHeader frame(std::uint32_t msg_no, std::uint32_t frame_no) {
  FrameHeader h;
  h.msg_no = msg_no;
  h.frame_no = frame_no;
  h.code = FrameCode::data;
  return h;
}

TEST(MessageAssembly, FramesMustComeInOrderAndWithinTheCreditGranted) {
  IncomingMessage in;
  in.msg_no = 7;
  EXPECT_FALSE(in.misfit(frame(7, 0)).has_value());
  EXPECT_EQ(in.misfit(frame(7, 1)).value_or(""), "frame #1 of message #7 out of order (expected #0)");
  in.next_frame = kWindowFrames;  // the whole window arrived
  EXPECT_EQ(in.misfit(frame(7, kWindowFrames)).value_or(""),
            "frame #8 of message #7 exceeds the flow-control window (granted 8 frames)");
  // Frames of a refused message that were in flight are not held to the window.
  in.refused = true;
  EXPECT_FALSE(in.misfit(frame(7, kWindowFrames)).has_value());
}

TEST(MessageAssembly, ALargeMessageIsJoinedInBlocksWithoutMovingWhatArrived) {
  IncomingMessage in;
  std::vector<std::byte> spare;
  std::vector<std::byte> payload(kMaxFramePayload, std::byte{1});
  const std::size_t frames = kBlockBytes / kMaxFramePayload + 2;
  const std::byte* first_block = nullptr;
  for (std::size_t i = 0; i < frames; ++i) {
    in.append(payload, spare);
    if (i == 0) first_block = in.blocks.front().data();
  }
  EXPECT_EQ(in.size, frames * kMaxFramePayload);
  ASSERT_EQ(in.blocks.size(), 2u);
  EXPECT_EQ(in.blocks.front().size(), kBlockBytes);
  EXPECT_EQ(in.blocks.back().size(), 2 * kMaxFramePayload);
  EXPECT_EQ(in.blocks.front().data(), first_block);  // never reallocated
}

TEST(MessageAssembly, TheSpareBlockOfAnEarlierMessageIsReused) {
  std::vector<std::byte> spare;
  spare.reserve(4096);
  spare.push_back(std::byte{9});
  const std::byte* memory = spare.data();
  IncomingMessage in;
  const std::vector<std::byte> payload(100, std::byte{2});
  in.append(payload, spare);
  ASSERT_EQ(in.blocks.size(), 1u);
  EXPECT_EQ(in.blocks[0].data(), memory);
  EXPECT_EQ(in.blocks[0].size(), 100u);  // the earlier message's byte is gone
  EXPECT_EQ(in.blocks[0][0], std::byte{2});
  EXPECT_EQ(spare.capacity(), 0u);
}

TEST(MessageAssembly, TheReceiverKeepsItsSenderAFixedDistanceAheadInWholeAcks) {
  IncomingMessage in;
  // After the first frame: granted 8, wanted 1 + 64: owe (65 - 8) / 4 = 14 acks.
  in.next_frame = 1;
  EXPECT_EQ(in.acks_to_owe(), (1 + kGrantAheadFrames - kWindowFrames) / kAckEvery);
  in.owed_acks = in.acks_to_owe();
  EXPECT_EQ(in.acks_to_owe(), 0u);  // owed already
  // Sending them grants the frames and counts as progress.
  const Clock::time_point t{std::chrono::seconds(3)};
  const auto owed = in.owed_acks;
  while (in.owed_acks > 0) in.grant_one(t);
  EXPECT_EQ(in.granted, kWindowFrames + owed * kAckEvery);
  EXPECT_EQ(in.last_progress, t);
  // The sender is one frame short of kGrantAheadFrames ahead; less than an ack's worth short
  // owes nothing, a whole ack's worth owes one.
  EXPECT_EQ(in.granted, in.next_frame + kGrantAheadFrames - 1);
  in.next_frame += kAckEvery - 2;
  EXPECT_EQ(in.acks_to_owe(), 0u);
  in.next_frame += 1;
  EXPECT_EQ(in.acks_to_owe(), 1u);
}

TEST(MessageAssembly, WhatAMessageHoldsAndWhenItHasStalled) {
  IncomingMessage in;
  in.next_frame = 2;
  in.size = 2 * kMaxFramePayload;
  EXPECT_EQ(in.holding(), 2 * kMaxFramePayload + (kWindowFrames - 2) * kMaxFramePayload);
  const Clock::time_point t0{std::chrono::seconds(10)};
  in.last_progress = t0;
  EXPECT_FALSE(in.stalled(t0 + std::chrono::seconds(1), std::chrono::seconds(2)));
  EXPECT_TRUE(in.stalled(t0 + std::chrono::seconds(2), std::chrono::seconds(2)));
  in.next_frame = in.granted;  // nothing granted that has not arrived: waiting on us, not them
  EXPECT_FALSE(in.stalled(t0 + std::chrono::hours(1), std::chrono::seconds(2)));
  in.refused = true;
  EXPECT_EQ(in.holding(), 0u);
}

}  // namespace
}  // namespace icars::planet::detail
