// Sample-rate conversion: a tone keeps its pitch, level and length across the rates the voice
// path meets (espeak-ng's 22,050 Hz, sound cards' 44,100 and 48,000 Hz, telephone 8,000 Hz),
// every channel is converted, and rates outside 8..192 kHz are refused by name.
#include "icars/audio/resample.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>

namespace icars::audio {
namespace {

Signal sine(int rate, double hz, double seconds, double amplitude = 0.5) {
  Signal s{rate, std::vector<float>(static_cast<std::size_t>(seconds * rate))};
  for (std::size_t i = 0; i < s.samples.size(); ++i) {
    s.samples[i] = static_cast<float>(
        amplitude * std::sin(2 * std::numbers::pi * hz * static_cast<double>(i) / rate));
  }
  return s;
}

// Frequency from upward zero crossings, away from the edges.
double frequency(const std::vector<float>& x, int rate) {
  const std::size_t margin = x.size() / 10;
  std::size_t first = 0, last = 0, crossings = 0;
  for (std::size_t i = margin; i + 1 < x.size() - margin; ++i) {
    if (x[i] <= 0 && x[i + 1] > 0) {
      if (crossings == 0) first = i;
      last = i;
      ++crossings;
    }
  }
  return static_cast<double>(crossings - 1) * rate / static_cast<double>(last - first);
}

double peak(const std::vector<float>& x) {
  double p = 0;
  for (std::size_t i = x.size() / 10; i < x.size() - x.size() / 10; ++i) {
    p = std::max(p, static_cast<double>(std::abs(x[i])));
  }
  return p;
}

TEST(Resample, KeepsPitchLevelAndLength) {
  for (const auto& [from, to] :
       {std::pair{22050, 16000}, std::pair{44100, 16000}, std::pair{48000, 16000},
        std::pair{16000, 44100}, std::pair{8000, 16000}, std::pair{16000, 8000}}) {
    SCOPED_TRACE(std::to_string(from) + " Hz to " + std::to_string(to) + " Hz");
    const Signal in = sine(from, 1000.0, 1.0);
    const Signal out = resample(in, to);
    EXPECT_EQ(out.sample_rate, to);
    EXPECT_NEAR(static_cast<double>(out.samples.size()), to * 1.0, 2.0);
    EXPECT_NEAR(frequency(out.samples, to), 1000.0, 1.0);
    EXPECT_NEAR(peak(out.samples), 0.5, 0.01);
  }
}

TEST(Resample, RemovesWhatTheNewRateCannotHold) {
  // 6 kHz is above 8 kHz audio's Nyquist frequency: the filter removes it instead of folding
  // it down to 2 kHz.
  const Signal out = resample(sine(16000, 6000.0, 0.5), 8000);
  EXPECT_LT(peak(out.samples), 0.005);
}

TEST(Resample, SameRateAndEmptySignals) {
  const Signal in = sine(16000, 440.0, 0.1);
  EXPECT_EQ(resample(in, 16000).samples, in.samples);
  const Signal empty = resample(Signal{44100, {}}, 16000);
  EXPECT_EQ(empty.sample_rate, 16000);
  EXPECT_TRUE(empty.samples.empty());
}

TEST(Resample, ConvertsEveryChannelAndScalesTheTimeline) {
  const Signal left = sine(48000, 500.0, 0.5, 0.5);
  const Signal right = sine(48000, 2000.0, 0.5, 0.25);
  AudioBlock stereo;
  stereo.format = {48000, 2};
  stereo.start = 96000;  // 2 s into the capture
  for (std::size_t i = 0; i < left.samples.size(); ++i) {
    stereo.samples.push_back(to_pcm16(left.samples[i]));
    stereo.samples.push_back(to_pcm16(right.samples[i]));
  }
  const AudioBlock out = resample(stereo, 16000);
  EXPECT_EQ(out.format, (AudioFormat{16000, 2}));
  EXPECT_EQ(out.start, 32000u);
  EXPECT_NEAR(static_cast<double>(out.frames()), 8000.0, 2.0);
  const auto as_float = [](const std::vector<std::int16_t>& x) {
    std::vector<float> f;
    for (const auto v : x) f.push_back(static_cast<float>(v) / 32767.0f);
    return f;
  };
  EXPECT_NEAR(frequency(as_float(out.channel(0)), 16000), 500.0, 1.0);
  EXPECT_NEAR(frequency(as_float(out.channel(1)), 16000), 2000.0, 2.0);
  EXPECT_NEAR(peak(as_float(out.channel(0))), 0.5, 0.01);
  EXPECT_NEAR(peak(as_float(out.channel(1))), 0.25, 0.01);
}

TEST(Resample, SaturatesInsteadOfWrapping) {
  // A full-scale square wave overshoots when filtered (Gibbs, about 9 %): the overshoot
  // saturates at the int16 limits instead of wrapping round to the other sign.
  AudioBlock square;
  square.format = {44100, 1};
  constexpr int kHalfPeriod = 50;
  for (int i = 0; i < 4410; ++i) {
    square.samples.push_back((i / kHalfPeriod) % 2 == 0 ? std::int16_t{32767}
                                                        : std::int16_t{-32768});
  }
  const AudioBlock out = resample(square, 16000);
  EXPECT_EQ(*std::max_element(out.samples.begin(), out.samples.end()), 32767);
  EXPECT_EQ(*std::min_element(out.samples.begin(), out.samples.end()), -32768);
  for (std::size_t i = 0; i < out.samples.size(); ++i) {
    const double t = static_cast<double>(i) * 44100 / 16000;  // in input samples
    const double into = std::fmod(t, kHalfPeriod);
    if (t < kHalfPeriod || t > 4410 - kHalfPeriod || into < 3 || into > kHalfPeriod - 3) continue;
    const bool high = static_cast<int>(t / kHalfPeriod) % 2 == 0;
    if (high) {
      EXPECT_GT(out.samples[i], 16000) << i;
    } else {
      EXPECT_LT(out.samples[i], -16000) << i;
    }
  }
}

TEST(Resample, RefusesRatesOutsideItsRange) {
  const auto message = [](auto&& call) {
    try {
      call();
    } catch (const AudioError& e) {
      return std::string(e.what());
    }
    return std::string("no AudioError");
  };
  EXPECT_EQ(message([] {
              resample(Signal{4000, {0.0f}}, 16000);
            }),
            "input sample rate 4000 Hz is outside 8000..192000 Hz");
  EXPECT_EQ(message([] {
              resample(Signal{16000, {0.0f}}, 1000000);
            }),
            "output sample rate 1000000 Hz is outside 8000..192000 Hz");
  EXPECT_EQ(message([] {
              resample(Signal{16000, {0.0f}}, 0);
            }),
            "output sample rate 0 Hz is outside 8000..192000 Hz");
  AudioBlock none;
  none.format = {16000, 0};
  EXPECT_EQ(message([&] { resample(none, 8000); }), "cannot resample audio with 0 channels");
  AudioBlock fast;
  fast.format = {384000, 1};
  EXPECT_EQ(message([&] { resample(fast, 16000); }),
            "input sample rate 384000 Hz is outside 8000..192000 Hz");
}

}  // namespace
}  // namespace icars::audio
