// PCM blocks and levels: saturation that counts what it clipped, dBFS levels of known signals,
// channels picked out of and mixed down from interleaved audio.
#include "icars/audio/pcm.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>

namespace icars::audio {
namespace {

TEST(Pcm, SaturatesAndCountsClippedSamples) {
  std::size_t clipped = 0;
  EXPECT_EQ(to_pcm16(0.0f, &clipped), 0);
  EXPECT_EQ(to_pcm16(1.0f, &clipped), 32767);
  EXPECT_EQ(to_pcm16(-1.0f, &clipped), -32767);
  EXPECT_EQ(to_pcm16(0.5f, &clipped), 16384);  // 16383.5 rounded to even
  EXPECT_EQ(clipped, 0u);
  EXPECT_EQ(to_pcm16(1.5f, &clipped), 32767);
  EXPECT_EQ(to_pcm16(-7.0f, &clipped), -32768);
  EXPECT_EQ(to_pcm16(std::numeric_limits<float>::infinity(), &clipped), 32767);
  EXPECT_EQ(clipped, 3u);
  EXPECT_EQ(to_pcm16(std::numeric_limits<float>::quiet_NaN(), &clipped), 0);
  EXPECT_EQ(clipped, 3u);
  EXPECT_EQ(to_pcm16(2.0f), 32767);  // counting is optional
}

TEST(Pcm, LevelsInDbfs) {
  EXPECT_EQ(rms_dbfs({}), -120.0);
  const std::vector<std::int16_t> zeros(1000, 0);
  EXPECT_EQ(rms_dbfs(zeros), -120.0);

  std::vector<std::int16_t> square(1000);
  for (std::size_t i = 0; i < square.size(); ++i) square[i] = i % 2 == 0 ? -32768 : 32767;
  EXPECT_NEAR(rms_dbfs(square), 0.0, 0.01);

  Signal sine{kSpeechRate, std::vector<float>(16000)};
  for (std::size_t i = 0; i < sine.samples.size(); ++i) {
    sine.samples[i] = static_cast<float>(
        0.1 * std::sin(2 * std::numbers::pi * 440.0 * static_cast<double>(i) / kSpeechRate));
  }
  // A sine's RMS is its peak / sqrt(2): -20 dB - 3.01 dB.
  EXPECT_NEAR(rms_dbfs(to_block(sine).samples), -23.01, 0.05);
}

TEST(Pcm, ChannelsOfInterleavedAudio) {
  AudioBlock block;
  block.format = {48000, 3};
  block.start = 480;
  block.samples = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12};
  EXPECT_EQ(block.frames(), 4u);
  EXPECT_EQ(block.end(), 484u);
  EXPECT_DOUBLE_EQ(block.seconds(), 4.0 / 48000);
  EXPECT_EQ(block.channel(0), (std::vector<std::int16_t>{1, 4, 7, 10}));
  EXPECT_EQ(block.channel(2), (std::vector<std::int16_t>{3, 6, 9, 12}));
  EXPECT_THROW(block.channel(3), std::out_of_range);
  EXPECT_THROW(block.channel(-1), std::out_of_range);

  block.format.channels = 0;
  EXPECT_EQ(block.frames(), 0u);
}

TEST(Pcm, MixDownAveragesTheChannels) {
  AudioBlock stereo;
  stereo.format = {22050, 2};
  stereo.samples = {32767, -32767, 16384, 0, -32768, -32768};
  const Signal mono = mix_down(stereo);
  EXPECT_EQ(mono.sample_rate, 22050);
  ASSERT_EQ(mono.samples.size(), 3u);
  EXPECT_FLOAT_EQ(mono.samples[0], 0.0f);
  EXPECT_NEAR(mono.samples[1], 0.25f, 1e-4);
  EXPECT_NEAR(mono.samples[2], -1.0f, 1e-4);

  // to_block and mix_down are each other's inverse on one channel.
  const Signal tone{8000, {0.0f, 0.25f, -0.5f, 1.0f, -1.0f}};
  const AudioBlock block = to_block(tone);
  EXPECT_EQ(block.format, (AudioFormat{8000, 1}));
  const Signal back = mix_down(block);
  ASSERT_EQ(back.samples.size(), tone.samples.size());
  for (std::size_t i = 0; i < tone.samples.size(); ++i) {
    EXPECT_NEAR(back.samples[i], tone.samples[i], 0.5 / 32767) << i;
  }

  AudioBlock none;
  none.format = {kSpeechRate, 0};
  EXPECT_THROW(mix_down(none), AudioError);
}

TEST(Pcm, ToBlockCountsClipping) {
  std::size_t clipped = 0;
  const AudioBlock block = to_block(Signal{kSpeechRate, {0.5f, 1.2f, -3.0f, 0.0f}}, &clipped);
  EXPECT_EQ(clipped, 2u);
  EXPECT_EQ(block.samples, (std::vector<std::int16_t>{16384, 32767, -32768, 0}));
}

}  // namespace
}  // namespace icars::audio
