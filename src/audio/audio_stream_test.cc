// Audio on a stream: the frame's byte layout, reassembly from pieces of any size, and the
// refusal of malformed frames with a message naming the field.
#include "icars/audio/audio_stream.h"

#include <gtest/gtest.h>

#include <random>
#include <string>
#include <vector>

namespace icars::audio {
namespace {

std::vector<std::byte> bytes(std::initializer_list<int> v) {
  std::vector<std::byte> out;
  for (int b : v) out.push_back(static_cast<std::byte>(b));
  return out;
}

AudioBlock noise_block(int rate, int channels, std::size_t frames, std::uint64_t start,
                       std::uint64_t seed) {
  std::mt19937 rng(static_cast<std::uint32_t>(seed));
  std::uniform_int_distribution<int> sample(-32768, 32767);
  AudioBlock block;
  block.format = {rate, channels};
  block.start = start;
  block.samples.resize(frames * static_cast<std::size_t>(channels));
  for (auto& s : block.samples) s = static_cast<std::int16_t>(sample(rng));
  return block;
}

// The frames joined back into one block (they must be contiguous).
AudioBlock join(const std::vector<AudioBlock>& frames) {
  AudioBlock out;
  out.format = frames.at(0).format;
  out.start = frames[0].start;
  for (const auto& f : frames) {
    EXPECT_EQ(f.start, out.end());
    out.samples.insert(out.samples.end(), f.samples.begin(), f.samples.end());
  }
  return out;
}

std::string error_of(AudioStreamDecoder& decoder, const std::vector<std::byte>& data) {
  try {
    decoder.feed(data);
  } catch (const AudioError& e) {
    return e.what();
  }
  return "";
}

TEST(AudioStream, FrameBytesAreLittleEndianAsDocumented) {
  AudioBlock block;
  block.format = {16000, 2};
  block.start = 0x0102030405060708;
  block.samples = {1, -2, 0x1234, -32768};
  std::vector<std::byte> out;
  encode_frames(block, out);
  const auto expected =
      bytes({'I',  'C',  'A',  'U',  1,    2,    0,    0,       // magic, version, channels
             0x80, 0x3e, 0,    0,                               // 16000
             8,    7,    6,    5,    4,    3,    2,    1,       // start frame
             2,    0,    0,    0,                               // frame count
             1,    0,    0xfe, 0xff, 0x34, 0x12, 0x00, 0x80});  // samples
  EXPECT_EQ(out, expected);
  ASSERT_EQ(kAudioFrameHeader, 24u);
}

TEST(AudioStream, SplitsIntoFramesOfFrameMsOnOneTimeline) {
  const AudioBlock audio = noise_block(16000, 1, 16000 + 100, 5000, 1);  // 1 s and 100 frames
  std::vector<std::byte> out;
  encode_frames(audio, out);
  AudioStreamDecoder decoder;
  const auto frames = decoder.feed(out);
  ASSERT_EQ(frames.size(), 51u);
  for (std::size_t i = 0; i + 1 < frames.size(); ++i) {
    EXPECT_EQ(frames[i].frames(), 320u);  // 20 ms
    EXPECT_EQ(frames[i].start, 5000 + 320 * i);
  }
  EXPECT_EQ(frames.back().frames(), 100u);
  EXPECT_EQ(decoder.pending(), 0u);
  const AudioBlock back = join(frames);
  EXPECT_EQ(back.samples, audio.samples);
  EXPECT_EQ(back.format, audio.format);

  std::vector<std::byte> longer;
  encode_frames(audio, longer, 250);
  EXPECT_EQ(AudioStreamDecoder().feed(longer).size(), 5u);  // 4 x 250 ms and the rest

  std::vector<std::byte> none;
  encode_frames(AudioBlock{}, none);
  EXPECT_TRUE(none.empty());
}

TEST(AudioStream, ReassemblesFromOneByteAtATime) {
  const AudioBlock audio = noise_block(48000, 2, 48000 / 5, 0, 2);  // 200 ms of stereo
  std::vector<std::byte> out;
  encode_frames(audio, out);
  AudioStreamDecoder decoder;
  std::vector<AudioBlock> frames;
  const std::size_t frame_bytes = kAudioFrameHeader + 960 * 2 * 2;
  for (std::byte b : out) {
    for (auto& f : decoder.feed(std::span(&b, 1))) frames.push_back(std::move(f));
    EXPECT_LT(decoder.pending(), frame_bytes);
  }
  ASSERT_EQ(frames.size(), 10u);
  EXPECT_EQ(join(frames).samples, audio.samples);
  EXPECT_EQ(decoder.pending(), 0u);
}

TEST(AudioStream, ReassemblesFromRandomPieces) {
  for (std::uint64_t seed = 1; seed <= 20; ++seed) {
    const AudioBlock audio = noise_block(16000, 3, 16000, 42, seed);
    std::vector<std::byte> out;
    encode_frames(audio, out, 10 + static_cast<int>(seed));
    std::mt19937 rng(static_cast<std::uint32_t>(seed));
    std::uniform_int_distribution<std::size_t> piece(1, 3000);
    AudioStreamDecoder decoder;
    std::vector<AudioBlock> frames;
    for (std::size_t at = 0; at < out.size();) {
      const std::size_t n = std::min(piece(rng), out.size() - at);
      for (auto& f : decoder.feed(std::span(out).subspan(at, n))) frames.push_back(std::move(f));
      at += n;
    }
    const AudioBlock back = join(frames);
    EXPECT_EQ(back.start, 42u);
    EXPECT_EQ(back.samples, audio.samples) << "seed " << seed;
    EXPECT_EQ(decoder.pending(), 0u);
  }
}

TEST(AudioStream, AGapInTheTimelineIsFine) {
  std::vector<std::byte> out;
  encode_frames(noise_block(16000, 1, 320, 0, 3), out);
  encode_frames(noise_block(16000, 1, 320, 16000, 4), out);  // a second later
  const auto frames = AudioStreamDecoder().feed(out);
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(frames[1].start, 16000u);
}

struct Malformed {
  const char* what;
  std::size_t offset;      // of the byte(s) to change in the encoded frame
  std::vector<int> value;  // little-endian bytes written there
  const char* message;     // what the error must say
};

TEST(AudioStream, RefusesMalformedFramesNamingTheField) {
  const std::vector<Malformed> cases = {
      {"magic", 0, {'R', 'I', 'F', 'F'}, "bad magic \"RIFF\""},
      {"version", 4, {2}, "unknown version 2"},
      {"no channels", 5, {0}, "channels 0"},
      {"too many channels", 5, {17}, "channels 17"},
      {"rate too low", 8, {0x3f, 0x1f, 0, 0}, "sample_rate 7999"},
      {"rate too high", 8, {0x01, 0xee, 0x02, 0}, "sample_rate 192001"},
      {"frame too long", 20, {0x81, 0x3e, 0, 0}, "frame count 16001"},
  };
  for (const auto& c : cases) {
    std::vector<std::byte> out;
    encode_frames(noise_block(16000, 1, 320, 0, 5), out);
    for (std::size_t i = 0; i < c.value.size(); ++i)
      out[c.offset + i] = static_cast<std::byte>(c.value[i]);
    AudioStreamDecoder decoder;
    const std::string error = error_of(decoder, out);
    EXPECT_NE(error.find(c.message), std::string::npos) << c.what << ": " << error;
    EXPECT_EQ(decoder.pending(), 0u) << c.what;
  }
}

TEST(AudioStream, RefusesAFrameStartingBeforeThePreviousEnd) {
  std::vector<std::byte> first, overlapping;
  encode_frames(noise_block(16000, 1, 320, 1000, 6), first);
  encode_frames(noise_block(16000, 1, 320, 1200, 7), overlapping);
  AudioStreamDecoder decoder;
  ASSERT_EQ(decoder.feed(first).size(), 1u);
  const std::string error = error_of(decoder, overlapping);
  EXPECT_NE(error.find("start 1200 before the previous frame's end 1320"), std::string::npos)
      << error;
  // The decoder starts afresh: the caller may go on, and the same frame is now accepted.
  EXPECT_EQ(decoder.pending(), 0u);
  EXPECT_EQ(decoder.feed(overlapping).size(), 1u);
}

TEST(AudioStream, RefusesBadMagicAsSoonAsItArrives) {
  AudioStreamDecoder decoder;
  EXPECT_TRUE(decoder.feed(bytes({'I', 'C'})).empty());
  const std::string error = error_of(decoder, bytes({'X'}));
  EXPECT_NE(error.find("bad magic \"ICX\""), std::string::npos) << error;
}

TEST(AudioStream, EncoderRefusesWhatAReaderWouldRefuse) {
  std::vector<std::byte> out;
  EXPECT_THROW(encode_frames(noise_block(4000, 1, 10, 0, 1), out), AudioError);
  EXPECT_THROW(encode_frames(noise_block(16000, 17, 10, 0, 1), out), AudioError);
  EXPECT_THROW(encode_frames(noise_block(16000, 1, 10, 0, 1), out, 1001), AudioError);
  EXPECT_TRUE(out.empty());
}

}  // namespace
}  // namespace icars::audio
