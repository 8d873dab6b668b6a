// Audio on a PLANET stream (a Microphone's capture): a sequence of frames, each a small header
// and interleaved 16-bit little-endian PCM, as a sound card delivers periods. The header says
// the format and where the frame starts on the capture's timeline, so a microphone may leave
// out what it did not hear (the reader takes a gap for silence) and a reader can time what it
// hears. A reader gets the bytes in pieces of any size: AudioStreamDecoder reassembles frames
// and refuses a malformed one with an AudioError naming what was wrong (bad magic, a version it
// does not know, a rate or channel count out of range, a frame longer than kMaxFrameMs, a start
// before the previous frame's end).
//
//   frame: "ICAU" | u8 version (1) | u8 channels | u16 reserved | u32 sample_rate
//          | u64 start frame | u32 frame count | frame count * channels * i16 samples
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "icars/audio/pcm.h"

namespace icars::audio {

inline constexpr int kFrameMs = 20;       // what a microphone sends per frame
inline constexpr int kMaxFrameMs = 1000;  // longest frame a reader accepts
inline constexpr int kMaxChannels = 16;
inline constexpr std::size_t kAudioFrameHeader = 24;

// `audio` as frames of at most `frame_ms` each, appended to `out` (nothing for empty audio).
// AudioError for a format a reader would refuse or frame_ms outside 1..kMaxFrameMs.
void encode_frames(const AudioBlock& audio, std::vector<std::byte>& out, int frame_ms = kFrameMs);

class AudioStreamDecoder {
 public:
  // Appends received bytes; returns the whole frames they completed, in order. A malformed
  // frame is an AudioError naming the field and its value; the decoder is then as new (what it
  // held, and the frames completed earlier in the same call, are dropped), and the caller
  // decides whether to go on feeding it.
  std::vector<AudioBlock> feed(std::span<const std::byte> bytes);
  // Bytes of an incomplete frame held (at most one frame).
  std::size_t pending() const { return buffer_.size(); }

 private:
  std::vector<std::byte> buffer_;
  std::uint64_t next_start_ = 0;
  bool started_ = false;
};

}  // namespace icars::audio
