// Synthetic signals for the signal tests (detection, direction, acoustics): noise, tones,
// noise shaped like syllables, fractional delays. Built from a seed, so every run hears the same.
#pragma once

#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <vector>

#include "icars/audio/pcm.h"

namespace icars::audio::testing {

inline std::size_t samples_of(double seconds, int rate = kSpeechRate) {
  return static_cast<std::size_t>(std::lround(seconds * rate));
}

inline double rms(const std::vector<float>& x) {
  double sum = 0;
  for (float v : x) sum += static_cast<double>(v) * v;
  return x.empty() ? 0.0 : std::sqrt(sum / static_cast<double>(x.size()));
}

// `x` scaled to RMS `level_dbfs` (0 dBFS: RMS 1).
inline Signal at_level(Signal x, double level_dbfs) {
  const double scale = std::pow(10.0, level_dbfs / 20.0) / rms(x.samples);
  for (auto& v : x.samples) v = static_cast<float>(v * scale);
  return x;
}

inline Signal white_noise(double seconds, double level_dbfs, std::uint64_t seed,
                          int rate = kSpeechRate) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> gauss;
  Signal x{rate, std::vector<float>(samples_of(seconds, rate))};
  for (auto& v : x.samples) v = gauss(rng);
  return at_level(std::move(x), level_dbfs);
}

inline Signal silence(double seconds, int rate = kSpeechRate) {
  return Signal{rate, std::vector<float>(samples_of(seconds, rate), 0.0f)};
}

inline Signal tone(double seconds, double hz, double level_dbfs, int rate = kSpeechRate) {
  Signal x{rate, std::vector<float>(samples_of(seconds, rate))};
  for (std::size_t i = 0; i < x.samples.size(); ++i) {
    x.samples[i] =
        static_cast<float>(std::sin(2.0 * std::numbers::pi * hz * static_cast<double>(i) / rate));
  }
  return at_level(std::move(x), level_dbfs);
}

// Noise in syllables of `syllable` seconds (a |sine| envelope, silent between them): something
// with the rhythm of speech. RMS over the whole is `level_dbfs`.
inline Signal speech_like(double seconds, double level_dbfs, std::uint64_t seed,
                          double syllable = 0.2, int rate = kSpeechRate) {
  Signal x = white_noise(seconds, 0.0, seed, rate);
  for (std::size_t i = 0; i < x.samples.size(); ++i) {
    const double t = static_cast<double>(i) / rate;
    x.samples[i] *= static_cast<float>(std::abs(std::sin(std::numbers::pi * t / syllable)));
  }
  return at_level(std::move(x), level_dbfs);
}

// Bursts of noise (`on` seconds) with pauses (`off`), broadband like consonants and clapping.
inline Signal noise_bursts(int bursts, double on, double off, double level_dbfs, std::uint64_t seed,
                           int rate = kSpeechRate) {
  Signal x{rate, {}};
  for (int b = 0; b < bursts; ++b) {
    const Signal burst =
        white_noise(on, level_dbfs, seed * 1000 + static_cast<std::uint64_t>(b), rate);
    x.samples.insert(x.samples.end(), burst.samples.begin(), burst.samples.end());
    x.samples.insert(x.samples.end(), samples_of(off, rate), 0.0f);
  }
  return x;
}

inline Signal concat(std::initializer_list<Signal> parts) {
  Signal x{parts.begin()->sample_rate, {}};
  for (const auto& p : parts) x.samples.insert(x.samples.end(), p.samples.begin(), p.samples.end());
  return x;
}

// `x` delayed by `delay` samples (fractional), by a 64-tap Hann-windowed sinc; same length.
inline std::vector<float> delayed(const std::vector<float>& x, double delay) {
  constexpr int kHalf = 32;
  std::vector<float> out(x.size(), 0.0f);
  const auto whole = static_cast<long>(std::floor(delay));
  const double fraction = delay - static_cast<double>(whole);
  std::vector<double> taps;
  for (int j = -kHalf + 1; j <= kHalf; ++j) {
    const double t = j - fraction;
    const double sinc = t == 0 ? 1.0 : std::sin(std::numbers::pi * t) / (std::numbers::pi * t);
    const double window = 0.5 + 0.5 * std::cos(std::numbers::pi * t / kHalf);
    taps.push_back(sinc * window);
  }
  const auto size = static_cast<long>(x.size());
  for (long n = 0; n < size; ++n) {
    double sum = 0;
    for (int k = 0; k < 2 * kHalf; ++k) {
      const long m = n - whole - (k - kHalf + 1);
      if (m >= 0 && m < size)
        sum += taps[static_cast<std::size_t>(k)] * x[static_cast<std::size_t>(m)];
    }
    out[static_cast<std::size_t>(n)] = static_cast<float>(sum);
  }
  return out;
}

// Channels (equal lengths) interleaved into one block, saturated to 16 bits.
inline AudioBlock interleave(const std::vector<std::vector<float>>& channels,
                             int rate = kSpeechRate) {
  AudioBlock block;
  block.format = {rate, static_cast<int>(channels.size())};
  for (std::size_t i = 0; i < channels[0].size(); ++i) {
    for (const auto& c : channels) block.samples.push_back(to_pcm16(c[i]));
  }
  return block;
}

// `audio` cut into consecutive blocks of `frames` frames (the last one shorter).
inline std::vector<AudioBlock> split(const AudioBlock& audio, std::size_t frames) {
  std::vector<AudioBlock> out;
  const auto channels = static_cast<std::size_t>(audio.format.channels);
  for (std::size_t at = 0; at < audio.frames(); at += frames) {
    AudioBlock b;
    b.format = audio.format;
    b.start = audio.start + at;
    const std::size_t n = std::min(frames, audio.frames() - at);
    b.samples.assign(audio.samples.begin() + static_cast<std::ptrdiff_t>(at * channels),
                     audio.samples.begin() + static_cast<std::ptrdiff_t>((at + n) * channels));
    out.push_back(std::move(b));
  }
  return out;
}

inline std::vector<float> as_float(const std::vector<std::int16_t>& x) {
  std::vector<float> out(x.size());
  for (std::size_t i = 0; i < x.size(); ++i) out[i] = static_cast<float>(x[i]) / 32767.0f;
  return out;
}

}  // namespace icars::audio::testing
