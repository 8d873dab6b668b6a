// Voice-activity detection on synthetic captures: noise with syllable-shaped bursts, tones and
// clicks, fed in 20 ms periods as a microphone sends them.
#include "icars/audio/vad.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>

#include "test_signals.h"

namespace icars::audio {
namespace {

using namespace testing;

constexpr std::size_t kPeriod = 320;  // 20 ms at 16 kHz

// Background noise at `noise_dbfs` with `speech` added from `at` seconds on.
AudioBlock capture(double seconds, double noise_dbfs, const Signal& speech, double at,
                   std::uint64_t seed = 7) {
  Signal x = white_noise(seconds, noise_dbfs, seed);
  const std::size_t offset = samples_of(at);
  for (std::size_t i = 0; i < speech.samples.size() && offset + i < x.samples.size(); ++i) {
    x.samples[offset + i] += speech.samples[i];
  }
  return to_block(x);
}

std::vector<Utterance> detect(VoiceActivityDetector& vad, const AudioBlock& audio,
                              std::size_t block = kPeriod) {
  std::vector<Utterance> out;
  for (const auto& b : split(audio, block)) {
    for (auto& u : vad.feed(b)) out.push_back(std::move(u));
  }
  return out;
}

double seconds_of(std::uint64_t frame) { return static_cast<double>(frame) / kSpeechRate; }

TEST(Vad, FindsOneUtteranceInNoise) {
  // 2 s of a quiet room (-60 dBFS), 1.6 s of syllables at -30 dBFS, 2 s of room again.
  const Signal speech = speech_like(1.6, -30, 1);
  const AudioBlock audio = capture(5.6, -60, speech, 2.0);
  VoiceActivityDetector vad;
  const auto utterances = detect(vad, audio);
  ASSERT_EQ(utterances.size(), 1u);
  const Utterance& u = utterances[0];
  // From the pre-roll (200 ms) before the onset to the end of the hangover (400 ms).
  EXPECT_NEAR(seconds_of(u.audio.start), 2.0 - 0.2, 0.06);
  EXPECT_NEAR(seconds_of(u.speech_end), 3.6, 0.06);
  EXPECT_NEAR(seconds_of(u.audio.end()), seconds_of(u.speech_end) + 0.4, 0.021);
  EXPECT_EQ(u.audio.format, audio.format);
  // The utterance's audio is the capture's, sample for sample.
  for (std::size_t i = 0; i < u.audio.samples.size(); i += 97) {
    ASSERT_EQ(u.audio.samples[i], audio.samples[u.audio.start + i]);
  }
  EXPECT_NEAR(u.level_dbfs, -30, 2);
  EXPECT_GT(u.peak_dbfs, u.level_dbfs + 6);
  EXPECT_EQ(u.clipped, 0u);
  EXPECT_FALSE(u.truncated);
  EXPECT_FALSE(u.interrupted);
  EXPECT_FALSE(vad.in_speech());
  EXPECT_NEAR(vad.noise_floor_dbfs(), -61, 1.5);
  EXPECT_EQ(vad.position(), audio.frames());
}

TEST(Vad, BlockSizeDoesNotChangeWhatIsFound) {
  const Signal speech = concat({speech_like(0.8, -30, 2), silence(1.0), speech_like(0.6, -35, 3)});
  const AudioBlock audio = capture(5, -55, speech, 1.5);
  std::vector<std::vector<Utterance>> results;
  for (std::size_t block : {kPeriod, std::size_t{113}, std::size_t{1000}, audio.frames()}) {
    VoiceActivityDetector vad;
    results.push_back(detect(vad, audio, block));
  }
  ASSERT_EQ(results[0].size(), 2u);
  for (const auto& r : results) {
    ASSERT_EQ(r.size(), results[0].size());
    for (std::size_t i = 0; i < r.size(); ++i) {
      EXPECT_EQ(r[i].audio.start, results[0][i].audio.start);
      EXPECT_EQ(r[i].speech_end, results[0][i].speech_end);
      EXPECT_EQ(r[i].audio.samples, results[0][i].audio.samples);
    }
  }
}

TEST(Vad, AnHourOfQuietIsNothingAndCheap) {
  // 180,000 periods of a quiet room (-60 dBFS), from a pool of distinct noise periods.
  const AudioBlock pool = to_block(white_noise(64 * 0.02, -60, 11));
  const auto periods = split(pool, kPeriod);
  VoiceActivityDetector vad;
  constexpr std::size_t kHour = 3600 * 50;
  AudioBlock block = periods[0];
  const auto begin = std::chrono::steady_clock::now();
  std::size_t found = 0;
  for (std::size_t i = 0; i < kHour; ++i) {
    block.samples = periods[i % periods.size()].samples;
    block.start = i * kPeriod;
    found += vad.feed(block).size();
  }
  const double took =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count();
  std::printf("[ vad      ] an hour of 20 ms periods in %.2f s (%.0fx real time)\n", took,
              3600 / took);
  EXPECT_EQ(found, 0u);
  EXPECT_FALSE(vad.in_speech());
  EXPECT_EQ(vad.position(), kHour * kPeriod);
  EXPECT_NEAR(vad.noise_floor_dbfs(), -61, 1.5);
  EXPECT_LT(took, 360.0);  // a tenth of real time even in a sanitizer build; typically far less
  // Still listening: a word after the hour is heard.
  AudioBlock word = capture(2, -60, speech_like(0.6, -30, 12), 0.5);
  word.start = vad.position();
  EXPECT_EQ(detect(vad, word).size(), 1u);
}

TEST(Vad, GapsAreSilence) {
  VoiceActivityDetector vad;
  const AudioBlock before = capture(2, -60, speech_like(0.6, -30, 4), 1.2);  // speech to the end
  EXPECT_TRUE(detect(vad, before).empty());
  EXPECT_TRUE(vad.in_speech());
  const double floor = vad.noise_floor_dbfs();
  // The microphone sends nothing for an hour: the silence ends the utterance (zeros fill its
  // hangover), and the noise floor is as it was.
  AudioBlock after;
  after.start = before.end() + 3600ull * kSpeechRate;
  const auto utterances = vad.feed(after);
  ASSERT_EQ(utterances.size(), 1u);
  const Utterance& u = utterances[0];
  EXPECT_NEAR(seconds_of(u.speech_end), 1.8, 0.06);
  EXPECT_NEAR(seconds_of(u.audio.end()), seconds_of(u.speech_end) + 0.4, 0.021);
  const std::size_t gap_from = before.end() - u.audio.start;
  for (std::size_t i = gap_from; i < u.audio.samples.size(); ++i) ASSERT_EQ(u.audio.samples[i], 0);
  EXPECT_DOUBLE_EQ(vad.noise_floor_dbfs(), floor);
  EXPECT_EQ(vad.position(), after.end());

  // A gap shorter than the hangover within an utterance: one utterance across it.
  VoiceActivityDetector bridged;
  const AudioBlock a = capture(1.5, -60, speech_like(0.4, -30, 5), 1.1);
  AudioBlock b = capture(1.5, -60, speech_like(0.4, -30, 6), 0.0);
  b.start = a.end() + samples_of(0.2);
  auto found = detect(bridged, a);
  for (auto& u2 : detect(bridged, b)) found.push_back(std::move(u2));
  ASSERT_EQ(found.size(), 1u);
  EXPECT_NEAR(seconds_of(found[0].speech_end), 1.5 + 0.2 + 0.4, 0.06);
}

TEST(Vad, RefusesOverlapAndFormatChanges) {
  VoiceActivityDetector vad;
  AudioBlock a = capture(0.1, -60, Signal{}, 0);
  a.start = 1000;
  vad.feed(a);
  AudioBlock overlapping = a;
  overlapping.start = a.end() - 1;
  EXPECT_THROW(vad.feed(overlapping), AudioError);
  AudioBlock stereo;
  stereo.format = {kSpeechRate, 2};
  stereo.start = a.end();
  stereo.samples.assign(640, 0);
  EXPECT_THROW(vad.feed(stereo), AudioError);
  EXPECT_EQ(vad.position(), a.end());
  EXPECT_THROW(VoiceActivityDetector(VadOptions{.onset_ms = 0}), AudioError);
}

TEST(Vad, FlushReturnsTheUtteranceTheCaptureCutShort) {
  VoiceActivityDetector vad;
  const AudioBlock audio = capture(2, -60, speech_like(2, -30, 8), 1.0);  // stops mid-syllable
  EXPECT_TRUE(detect(vad, audio).empty());
  ASSERT_TRUE(vad.in_speech());
  const auto u = vad.flush();
  ASSERT_TRUE(u);
  EXPECT_TRUE(u->interrupted);
  EXPECT_FALSE(u->truncated);
  EXPECT_EQ(u->audio.end(), audio.end());
  EXPECT_NEAR(seconds_of(u->audio.start), 0.8, 0.06);
  EXPECT_FALSE(vad.in_speech());
  EXPECT_FALSE(vad.flush());
}

TEST(Vad, DropsBurstsShorterThanAnUtterance) {
  // A 100 ms beep passes the onset (60 ms) but not min_utterance (150 ms); a 40 ms click not
  // even the onset. A 300 ms beep is an utterance.
  const Signal sounds = concat({tone(0.1, 1000, -25), silence(1.0), white_noise(0.04, -20, 9),
                                silence(1.0), tone(0.3, 1000, -25)});
  VoiceActivityDetector vad;
  const auto utterances = detect(vad, capture(4.5, -60, sounds, 1.0));
  ASSERT_EQ(utterances.size(), 1u);
  EXPECT_NEAR(seconds_of(utterances[0].speech_end), 1.0 + 2.14 + 0.3, 0.041);
}

TEST(Vad, CutsAnOverlongUtteranceAndGoesOn) {
  // 25 s of talk without a pause longer than a syllable's dip.
  const AudioBlock audio = capture(28, -60, speech_like(25, -30, 10), 1.0);
  VoiceActivityDetector vad;
  const auto utterances = detect(vad, audio);
  ASSERT_EQ(utterances.size(), 3u);
  const auto max_frames = static_cast<std::size_t>(10 * kSpeechRate);
  for (std::size_t i : {0u, 1u}) {
    EXPECT_TRUE(utterances[i].truncated);
    EXPECT_LE(utterances[i].audio.frames(), max_frames);
    EXPECT_GE(utterances[i].audio.frames(), max_frames - kPeriod);
    EXPECT_EQ(utterances[i].speech_end, utterances[i].audio.end());
  }
  // Nothing lost and nothing twice: each piece starts where the previous was cut.
  EXPECT_EQ(utterances[1].audio.start, utterances[0].audio.end());
  EXPECT_EQ(utterances[2].audio.start, utterances[1].audio.end());
  EXPECT_FALSE(utterances[2].truncated);
  EXPECT_NEAR(seconds_of(utterances[2].speech_end), 26.0, 0.06);
}

TEST(Vad, CountsClippedSamples) {
  Signal loud = speech_like(0.8, -2, 13);  // peaks far over full scale
  VoiceActivityDetector vad;
  const auto utterances = detect(vad, capture(3, -60, loud, 1.0));
  ASSERT_EQ(utterances.size(), 1u);
  EXPECT_GT(utterances[0].clipped, 100u);
  EXPECT_NEAR(utterances[0].peak_dbfs, 0.0, 0.01);
}

TEST(Vad, LearnsANoiseThatComesToStay) {
  // The room at -60 dBFS, then a fan at -40 dBFS for 30 s: at most the fan's start is taken for
  // speech, then the floor has risen to it.
  const Signal fan = white_noise(30, -40.04, 14);  // -40 dBFS with the room's noise added
  VoiceActivityDetector vad;
  const auto utterances = detect(vad, capture(32, -60, fan, 2.0));
  EXPECT_LE(utterances.size(), 1u);
  for (const auto& u : utterances) EXPECT_LT(u.audio.seconds(), 9.0);
  EXPECT_FALSE(vad.in_speech());
  EXPECT_NEAR(vad.noise_floor_dbfs(), -41, 1.5);
  // ... and speech over the fan is still heard.
  AudioBlock more = capture(3, -40, speech_like(1, -20, 15), 1.0);
  more.start = vad.position();
  EXPECT_EQ(detect(vad, more).size(), 1u);
}

TEST(Vad, KeepsEveryChannelAndListensToTheirMean) {
  // Stereo: the talker is louder on the right (second) channel.
  const AudioBlock left = capture(3, -60, speech_like(1, -40, 16), 1.0, 17);
  const AudioBlock right = capture(3, -60, speech_like(1, -28, 16), 1.0, 18);
  AudioBlock stereo;
  stereo.format = {kSpeechRate, 2};
  for (std::size_t i = 0; i < left.samples.size(); ++i) {
    stereo.samples.push_back(left.samples[i]);
    stereo.samples.push_back(right.samples[i]);
  }
  VoiceActivityDetector vad;
  const auto utterances = detect(vad, stereo);
  ASSERT_EQ(utterances.size(), 1u);
  const Utterance& u = utterances[0];
  EXPECT_EQ(u.audio.format.channels, 2);
  EXPECT_EQ(u.audio.samples[1], stereo.samples[u.audio.start * 2 + 1]);
  EXPECT_NEAR(u.level_dbfs, -40, 2);  // the first channel's level
}

}  // namespace
}  // namespace icars::audio
