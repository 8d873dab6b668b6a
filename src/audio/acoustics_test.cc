// A room's acoustics: calibrated levels, delays from distances, reverberation against the
// critical distance, background noise, clipping, and determinism.
#include "icars/audio/acoustics.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <tuple>
#include <vector>

#include "icars/audio/direction.h"
#include "test_signals.h"

namespace icars::audio {
namespace {

using namespace testing;

RoomSound anechoic_and_quiet() {
  RoomSound room;
  room.rt60 = 0;
  room.noise_db = -1;  // none
  return room;
}

// The level of one channel as acoustics.h defines it: RMS over the 20 ms frames within 40 dB
// of the loudest, in dBFS.
double voiced_level_dbfs(const std::vector<std::int16_t>& x) {
  constexpr std::size_t kFrame = 320;
  std::vector<double> energy;
  for (std::size_t at = 0; at + kFrame <= x.size(); at += kFrame) {
    double sum = 0;
    for (std::size_t i = at; i < at + kFrame; ++i) sum += static_cast<double>(x[i]) * x[i];
    energy.push_back(sum / kFrame);
  }
  const double floor = *std::max_element(energy.begin(), energy.end()) * 1e-4;
  double sum = 0;
  int count = 0;
  for (double e : energy) {
    if (e >= floor) {
      sum += e;
      ++count;
    }
  }
  return 10.0 * std::log10(sum / count / (32767.0 * 32767.0));
}

double energy(const std::vector<std::int16_t>& x) {
  double sum = 0;
  for (auto v : x) sum += static_cast<double>(v) * v;
  return sum;
}

TEST(Acoustics, TheVoiceArrivesAtTheLevelAsked) {
  // Syllables with pauses, at an arbitrary level: scaled so that the voiced part is 60 and 72 dB
  // SPL at the two microphones (-40 and -28 dBFS).
  const Signal voice = concat({speech_like(1.0, -13, 1), silence(0.5), speech_like(0.7, -25, 2)});
  const AudioBlock audio =
      render(voice, {{1.0, 60.0}, {1.3, 72.0}}, anechoic_and_quiet(), 0.2, 0.6);
  ASSERT_EQ(audio.format.channels, 2);
  EXPECT_EQ(audio.format.sample_rate, kSpeechRate);
  EXPECT_EQ(audio.frames(), samples_of(0.2) + voice.samples.size() + samples_of(0.6));
  EXPECT_NEAR(voiced_level_dbfs(audio.channel(0)), 60.0 - kFullScaleSpl, 1.0);
  EXPECT_NEAR(voiced_level_dbfs(audio.channel(1)), 72.0 - kFullScaleSpl, 1.0);
  // Nothing before the sound has travelled from the source (1 m: 2.9 ms after the lead).
  const auto first = audio.channel(0);
  const auto onset =
      std::find_if(first.begin(), first.end(), [](std::int16_t v) { return std::abs(v) > 3; });
  EXPECT_NEAR(static_cast<double>(onset - first.begin()) / kSpeechRate, 0.2 + 1.0 / kSpeedOfSound,
              0.0015);
}

TEST(Acoustics, DelaysBetweenMicrophonesFollowTheDistances) {
  const Signal voice = noise_bursts(4, 0.2, 0.1, -20, 3);
  const std::vector<Path> paths = {{1.0, 60}, {1.05, 60}, {1.2, 60}, {0.93, 60}};
  RoomSound room;
  room.rt60 = 0;
  room.noise_db = 30;
  const AudioBlock audio = render(voice, paths, room);
  const auto reference = as_float(audio.channel(0));
  for (std::size_t c = 1; c < paths.size(); ++c) {
    const double expected = (paths[c].distance - paths[0].distance) / kSpeedOfSound;
    const double found =
        gcc_phat_delay(reference, as_float(audio.channel(static_cast<int>(c))), kSpeechRate, 0.002);
    EXPECT_NEAR(found * kSpeechRate, expected * kSpeechRate, 0.1) << "channel " << c;
  }
}

TEST(Acoustics, BackgroundNoiseIsAtItsLevelAndIndependentPerMicrophone) {
  RoomSound room;
  room.noise_db = 40;  // -60 dBFS
  const AudioBlock noise = room_noise(2.0, 2, room);
  EXPECT_EQ(noise.frames(), samples_of(2.0));
  const auto left = noise.channel(0), right = noise.channel(1);
  EXPECT_NEAR(rms_dbfs(left), 40 - kFullScaleSpl, 0.5);
  EXPECT_NEAR(rms_dbfs(right), 40 - kFullScaleSpl, 0.5);
  double cross = 0;
  for (std::size_t i = 0; i < left.size(); ++i) cross += static_cast<double>(left[i]) * right[i];
  EXPECT_LT(std::abs(cross) / std::sqrt(energy(left) * energy(right)), 0.2);  // shared: 1

  // The same noise in a rendering: its lead (before the voice arrives) is at the room's level.
  const AudioBlock audio = render(speech_like(0.5, -20, 4), {{1.0, 60}}, room, 1.0, 0.2);
  const auto lead = audio.channel(0);
  EXPECT_NEAR(rms_dbfs(std::span(lead).first(samples_of(0.99))), 40 - kFullScaleSpl, 0.7);
}

TEST(Acoustics, ReverberationIsAsStrongAsTheDirectSoundAtTheCriticalDistance) {
  const Signal voice = noise_bursts(3, 0.3, 0.2, -20, 5);
  for (const auto& [distance, critical, ratio] : std::vector<std::tuple<double, double, double>>{
           {2.0, 2.0, 1.0}, {2.0, 1.0, 4.0}, {0.5, 1.0, 0.25}}) {
    RoomSound room = anechoic_and_quiet();
    const double direct = energy(render(voice, {{distance, 60}}, room, 0.1, 1.0).samples);
    room.rt60 = 0.4;
    room.critical_distance = critical;
    const double total = energy(render(voice, {{distance, 60}}, room, 0.1, 1.0).samples);
    EXPECT_NEAR(10 * std::log10(total / direct), 10 * std::log10(1 + ratio), 0.5)
        << distance << " m with critical distance " << critical;
  }
}

TEST(Acoustics, ReverberationDecaysByRt60) {
  // After a click the level falls 60 dB in RT60: 30 dB in half of it.
  RoomSound room = anechoic_and_quiet();
  room.rt60 = 0.5;
  room.critical_distance = 0.5;
  Signal click = silence(0.02);
  click.samples[0] = 1.0f;
  const AudioBlock audio = render(click, {{3.0, 70}}, room, 0.0, 0.8);
  const auto x = audio.channel(0);
  auto level_at = [&](double t) {
    return rms_dbfs(std::span(x).subspan(samples_of(t), samples_of(0.05)));
  };
  EXPECT_NEAR(level_at(0.05) - level_at(0.30), 30.0, 4.0);
}

TEST(Acoustics, ClippingSaturatesAndIsCounted) {
  const Signal voice = speech_like(0.5, -20, 6);
  std::size_t clipped = 0;
  const AudioBlock loud = render(voice, {{1.0, 110}}, anechoic_and_quiet(), 0.1, 0.1, &clipped);
  EXPECT_GT(clipped, 1000u);
  const auto [lo, hi] = std::minmax_element(loud.samples.begin(), loud.samples.end());
  EXPECT_EQ(*hi, 32767);
  EXPECT_EQ(*lo, -32768);
  const auto at_full_scale = static_cast<std::size_t>(
      std::count_if(loud.samples.begin(), loud.samples.end(),
                    [](std::int16_t v) { return v == 32767 || v == -32768; }));
  EXPECT_LE(clipped, at_full_scale);  // a sample may land on full scale without clipping
  EXPECT_GT(clipped, at_full_scale * 99 / 100);
  std::size_t none = 5;
  render(voice, {{1.0, 60}}, anechoic_and_quiet(), 0.1, 0.1, &none);
  EXPECT_EQ(none, 0u);
}

TEST(Acoustics, TheSameSeedRendersTheSame) {
  const Signal voice = speech_like(0.5, -20, 7);
  RoomSound room;
  room.seed = 42;
  const std::vector<Path> paths = {{1.0, 60}, {1.1, 60}};
  const AudioBlock a = render(voice, paths, room);
  const AudioBlock b = render(voice, paths, room);
  EXPECT_EQ(a.samples, b.samples);
  room.seed = 43;
  EXPECT_NE(render(voice, paths, room).samples, a.samples);
  EXPECT_EQ(room_noise(0.5, 2, room).samples, room_noise(0.5, 2, room).samples);
}

// Noise bursts in a room at 2 m (the reverberant field four times the direct sound). With the
// defaults, the tails between the bursts lose at least 3 dB and the bursts keep their level
// within 1.5 dB; smoothed and oversubtracted, the tails lose at least 8 dB (measured 9.6 to 11)
// and the bursts stay within 3 dB.
TEST(Acoustics, SuppressingLateReverberationQuietensTheTailsAndKeepsTheSound) {
  const Signal bursts = noise_bursts(3, 0.3, 0.5, -20, 9);  // 0.3 s on, 0.5 s off
  RoomSound room = anechoic_and_quiet();
  room.rt60 = 0.4;
  const Signal heard = mix_down(render(bursts, {{2.0, 60}}, room, 0.0, 0.5));
  const auto level = [](const Signal& x, double from, double seconds) {
    double sum = 0;
    const auto begin = samples_of(from), n = samples_of(seconds);
    for (std::size_t i = begin; i < begin + n && i < x.samples.size(); ++i) sum += static_cast<double>(x.samples[i]) * x.samples[i];
    return 10 * std::log10(sum / static_cast<double>(n) + 1e-20);
  };
  for (const auto& [options, tail_db, burst_db] : std::vector<std::tuple<Dereverberation, double, double>>{
           {Dereverberation{.rt60 = 0.4}, 3.0, 1.5},
           {Dereverberation{.rt60 = 0.4, .smoothing_bins = 3, .oversubtraction = 1.5}, 8.0, 3.0}}) {
    const Signal cleaned = suppress_late_reverberation(heard, options);
    ASSERT_EQ(cleaned.samples.size(), heard.samples.size());
    ASSERT_EQ(cleaned.sample_rate, heard.sample_rate);
    // The direct sound arrives 2 m / 343 m/s = 6 ms late; tails from 0.15 s after each burst.
    for (const double burst : {0.0, 0.8, 1.6}) {
      EXPECT_NEAR(level(cleaned, burst + 0.05, 0.2), level(heard, burst + 0.05, 0.2), burst_db)
          << "burst at " << burst << " s, smoothing " << options.smoothing_bins;
      EXPECT_LT(level(cleaned, burst + 0.45, 0.3), level(heard, burst + 0.45, 0.3) - tail_db)
          << "tail after " << burst << " s, smoothing " << options.smoothing_bins;
    }
  }
  // Nothing in, nothing out; a room it cannot be told is an error.
  EXPECT_TRUE(suppress_late_reverberation(Signal{kSpeechRate, {}}).samples.empty());
  EXPECT_THROW(suppress_late_reverberation(heard, {.rt60 = 0}), AudioError);
  EXPECT_THROW(suppress_late_reverberation(heard, {.rt60 = 0.4, .early = 2.0}), AudioError);
  EXPECT_THROW(suppress_late_reverberation(Signal{4000, heard.samples}), AudioError);
}

TEST(Acoustics, RefusesWhatItCannotRender) {
  const Signal voice = speech_like(0.2, -20, 8);
  EXPECT_THROW(render(voice, {}, RoomSound{}), AudioError);
  EXPECT_THROW(render(Signal{4000, voice.samples}, {{1.0, 60}}, RoomSound{}), AudioError);
  RoomSound room;
  room.critical_distance = 0;
  EXPECT_THROW(render(voice, {{1.0, 60}}, room), AudioError);
  EXPECT_THROW(room_noise(1.0, 0, RoomSound{}), AudioError);
}

}  // namespace
}  // namespace icars::audio
