#include "icars/audio/acoustics.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <numbers>
#include <random>

#include "icars/audio/direction.h"
#include "icars/audio/resample.h"
#include "real_fft.h"

namespace icars::audio {
namespace {

using detail::fft_size_for;
using detail::RealFft;

constexpr int kDelayTaps = 32;           // windowed-sinc fractional delay
constexpr double kVoicedRangeDb = 40.0;  // frames this far below the loudest count as voiced
enum class Stream : std::uint64_t { reverberation = 1, noise = 2 };

// One random stream per channel and purpose, all from the room's seed.
std::mt19937_64 random_stream(std::uint64_t seed, std::size_t channel, Stream purpose) {
  std::seed_seq sequence{static_cast<std::uint32_t>(seed), static_cast<std::uint32_t>(seed >> 32),
                         static_cast<std::uint32_t>(channel), static_cast<std::uint32_t>(purpose)};
  return std::mt19937_64(sequence);
}

double amplitude_of_spl(double spl) { return std::pow(10.0, (spl - kFullScaleSpl) / 20.0); }

// RMS over the 20 ms frames within kVoicedRangeDb of the loudest frame: the level of speech
// without its pauses.
double voiced_rms(const std::vector<float>& x, int sample_rate) {
  const auto frame = static_cast<std::size_t>(std::max(1, sample_rate / 50));
  std::vector<double> energy;
  for (std::size_t at = 0; at < x.size(); at += frame) {
    const std::size_t end = std::min(x.size(), at + frame);
    double sum = 0;
    for (std::size_t i = at; i < end; ++i) sum += static_cast<double>(x[i]) * x[i];
    energy.push_back(sum / static_cast<double>(end - at));
  }
  if (energy.empty()) return 0.0;
  const double floor =
      *std::max_element(energy.begin(), energy.end()) * std::pow(10.0, -kVoicedRangeDb / 10.0);
  double sum = 0;
  std::size_t count = 0;
  for (std::size_t f = 0; f < energy.size(); ++f) {
    if (energy[f] < floor || energy[f] == 0.0) continue;
    const std::size_t n = std::min(frame, x.size() - f * frame);
    sum += energy[f] * static_cast<double>(n);
    count += n;
  }
  return count > 0 ? std::sqrt(sum / static_cast<double>(count)) : 0.0;
}

// Adds `gain` * `source` delayed by `delay` samples (fractional: a Blackman-windowed sinc of
// kDelayTaps taps) to `out` from index `offset` on.
void add_delayed(const std::vector<float>& source, double gain, double delay, std::size_t offset,
                 std::vector<float>& out) {
  const double whole = std::floor(delay);
  const double fraction = delay - whole;
  constexpr int kHalf = kDelayTaps / 2;
  std::vector<double> taps;
  double sum = 0;
  for (int j = -kHalf + 1; j <= kHalf; ++j) {
    const double t = j - fraction;
    const double sinc = t == 0.0 ? 1.0 : std::sin(std::numbers::pi * t) / (std::numbers::pi * t);
    const double x = t / kHalf;  // within (-1, 1]
    const double window = std::abs(x) >= 1.0 ? 0.0
                                             : 0.42 + 0.5 * std::cos(std::numbers::pi * x) +
                                                   0.08 * std::cos(2.0 * std::numbers::pi * x);
    taps.push_back(sinc * window);
    sum += taps.back();
  }
  for (auto& tap : taps) tap *= gain / sum;  // unity gain at low frequencies
  const auto base = static_cast<long>(offset) + static_cast<long>(whole) - kHalf + 1;
  const auto size = static_cast<long>(out.size());
  for (std::size_t m = 0; m < source.size(); ++m) {
    const long first = base + static_cast<long>(m);
    for (int k = 0; k < kDelayTaps; ++k) {
      const long n = first + k;
      if (n >= 0 && n < size) {
        out[static_cast<std::size_t>(n)] +=
            static_cast<float>(taps[static_cast<std::size_t>(k)] * source[m]);
      }
    }
  }
}

// A diffuse tail: `direct` convolved with exponentially decaying Gaussian noise (60 dB down
// after rt60), scaled to `ratio` times the direct sound's energy, added to `out`.
void add_reverberation(const std::vector<float>& direct, double rt60, int sample_rate, double ratio,
                       std::mt19937_64& rng, std::vector<float>& out) {
  const auto length = static_cast<std::size_t>(std::ceil(rt60 * sample_rate));
  if (length < 2 || ratio <= 0.0) return;
  std::vector<float> response(length, 0.0f);
  std::normal_distribution<float> gauss;
  const double decay = -3.0 * std::log(10.0) / (rt60 * sample_rate);  // amplitude, per sample
  for (std::size_t t = 1; t < length; ++t) {
    response[t] = gauss(rng) * static_cast<float>(std::exp(decay * static_cast<double>(t)));
  }
  RealFft fft(fft_size_for(direct.size() + length));
  std::vector<std::complex<float>> a(fft.bins()), b(fft.bins());
  fft.forward(direct, a);
  fft.forward(response, b);
  for (std::size_t k = 0; k < a.size(); ++k) a[k] *= b[k];
  std::vector<float> tail(fft.size());
  fft.inverse(a, tail);
  double direct_energy = 0, tail_energy = 0;
  for (float v : direct) direct_energy += static_cast<double>(v) * v;
  for (float v : tail) tail_energy += static_cast<double>(v) * v;
  if (tail_energy <= 0.0) return;
  const auto scale = static_cast<float>(std::sqrt(ratio * direct_energy / tail_energy));
  for (std::size_t i = 0; i < out.size(); ++i) out[i] += scale * tail[i];
}

// `n` samples of pinkish noise (Kellet's economy filter on white Gaussian noise, -3 dB per
// octave above ~20 Hz) at RMS `amplitude`, added to `out`.
void add_noise(double amplitude, std::mt19937_64& rng, std::vector<float>& out) {
  if (amplitude <= 0.0 || out.empty()) return;
  std::normal_distribution<double> gauss;
  double b0 = 0, b1 = 0, b2 = 0;
  auto next = [&] {
    const double white = gauss(rng);
    b0 = 0.99765 * b0 + white * 0.0990460;
    b1 = 0.96300 * b1 + white * 0.2965164;
    b2 = 0.57000 * b2 + white * 1.0526913;
    return b0 + b1 + b2 + white * 0.1848;
  };
  for (int i = 0; i < 2000; ++i) next();  // past the filter's start-up
  std::vector<double> noise(out.size());
  double energy = 0;
  for (auto& v : noise) {
    v = next();
    energy += v * v;
  }
  const double scale = amplitude / std::sqrt(energy / static_cast<double>(noise.size()));
  for (std::size_t i = 0; i < out.size(); ++i) out[i] += static_cast<float>(scale * noise[i]);
}

void check_rate(const char* what, int sample_rate) {
  if (sample_rate < kMinSampleRate || sample_rate > kMaxSampleRate) {
    throw AudioError(fmt::format("{}: sample rate {} out of range {}..{}", what, sample_rate,
                                 kMinSampleRate, kMaxSampleRate));
  }
}

void check_room(const char* what, const RoomSound& room) {
  if (!(room.rt60 >= 0.0 && room.rt60 <= 10.0)) {
    throw AudioError(fmt::format("{}: rt60 {} s out of range 0..10", what, room.rt60));
  }
  if (!(room.critical_distance > 0.0)) {
    throw AudioError(
        fmt::format("{}: critical_distance {} m (must be positive)", what, room.critical_distance));
  }
}

AudioBlock interleave(const std::vector<std::vector<float>>& channels, int sample_rate,
                      std::size_t* clipped) {
  AudioBlock block;
  block.format = {sample_rate, static_cast<int>(channels.size())};
  const std::size_t frames = channels.empty() ? 0 : channels[0].size();
  block.samples.resize(frames * channels.size());
  std::size_t count = 0;
  for (std::size_t i = 0; i < frames; ++i) {
    for (std::size_t c = 0; c < channels.size(); ++c) {
      block.samples[i * channels.size() + c] = to_pcm16(channels[c][i], &count);
    }
  }
  if (clipped != nullptr) *clipped = count;
  return block;
}

}  // namespace

AudioBlock render(const Signal& source, const std::vector<Path>& paths, const RoomSound& room,
                  double lead, double tail, std::size_t* clipped) {
  check_rate("render", source.sample_rate);
  check_room("render", room);
  if (paths.empty()) throw AudioError("render: no paths (one per microphone)");
  for (const auto& path : paths) {
    if (!(path.distance >= 0.0 && path.distance <= 1000.0)) {
      throw AudioError(
          fmt::format("render: path distance {} m out of range 0..1000", path.distance));
    }
  }
  if (!(lead >= 0.0 && tail >= 0.0)) {
    throw AudioError(
        fmt::format("render: lead {} s and tail {} s (must not be negative)", lead, tail));
  }
  const int rate = source.sample_rate;
  const auto lead_samples = static_cast<std::size_t>(std::lround(lead * rate));
  const std::size_t total =
      lead_samples + source.samples.size() + static_cast<std::size_t>(std::lround(tail * rate));
  const double rms = voiced_rms(source.samples, rate);

  std::vector<std::vector<float>> channels(paths.size(), std::vector<float>(total, 0.0f));
  for (std::size_t c = 0; c < paths.size(); ++c) {
    const Path& path = paths[c];
    const double gain = rms > 0.0 ? amplitude_of_spl(path.level_db) / rms : 0.0;
    add_delayed(source.samples, gain, path.distance / kSpeedOfSound * rate, lead_samples,
                channels[c]);
    if (room.rt60 > 0.0) {
      // Diffuse sound: as loud as the direct sound at the critical distance, its share growing
      // with the square of the distance beyond.
      const double ratio = std::pow(path.distance / room.critical_distance, 2.0);
      auto rng = random_stream(room.seed, c, Stream::reverberation);
      const std::vector<float> direct = channels[c];
      add_reverberation(direct, room.rt60, rate, ratio, rng, channels[c]);
    }
    auto rng = random_stream(room.seed, c, Stream::noise);
    add_noise(room.noise_db >= 0.0 ? amplitude_of_spl(room.noise_db) : 0.0, rng, channels[c]);
  }
  return interleave(channels, rate, clipped);
}

AudioBlock room_noise(double seconds, int channels, const RoomSound& room, int sample_rate) {
  check_rate("room_noise", sample_rate);
  check_room("room_noise", room);
  if (channels < 1) throw AudioError(fmt::format("room_noise: {} channels", channels));
  if (!(seconds >= 0.0)) throw AudioError(fmt::format("room_noise: {} seconds", seconds));
  const auto frames = static_cast<std::size_t>(std::lround(seconds * sample_rate));
  std::vector<std::vector<float>> out(static_cast<std::size_t>(channels),
                                      std::vector<float>(frames, 0.0f));
  for (std::size_t c = 0; c < out.size(); ++c) {
    auto rng = random_stream(room.seed, c, Stream::noise);
    add_noise(room.noise_db >= 0.0 ? amplitude_of_spl(room.noise_db) : 0.0, rng, out[c]);
  }
  return interleave(out, sample_rate, nullptr);
}

Signal suppress_late_reverberation(const Signal& signal, const Dereverberation& options) {
  if (!(options.rt60 >= kMinDereverberationRt60 && options.rt60 <= kMaxRt60)) {
    throw AudioError(fmt::format("a reverberation time of {} s: dereverberation takes {} to {} s", options.rt60,
                                 kMinDereverberationRt60, kMaxRt60));
  }
  if (!(options.early >= 0.01 && options.early <= 0.5)) {
    throw AudioError(fmt::format("an early part of {} s: dereverberation takes 0.01 to 0.5 s", options.early));
  }
  check_rate("suppress_late_reverberation", signal.sample_rate);
  const double rate = signal.sample_rate;
  const std::size_t n = detail::fft_size_for(static_cast<std::size_t>(0.032 * rate));
  const std::size_t hop = n / 4;
  const std::size_t length = signal.samples.size();
  if (length == 0) return signal;
  // sqrt-Hann for analysis and synthesis; the overlap-add is divided by the windows' sum.
  std::vector<float> window(n);
  for (std::size_t i = 0; i < n; ++i) {
    window[i] = static_cast<float>(std::sqrt(0.5 - 0.5 * std::cos(2 * std::numbers::pi * static_cast<double>(i) / static_cast<double>(n))));
  }
  const std::size_t frames = (length + n) / hop + 1;  // frames start at -n + hop .. past the end
  const auto start_of = [&](std::size_t f) { return static_cast<std::ptrdiff_t>(f * hop) - static_cast<std::ptrdiff_t>(n - hop); };
  const auto delay = std::max<std::size_t>(1, static_cast<std::size_t>(std::lround(options.early * rate / static_cast<double>(hop))));
  const double decay_per_second = 3.0 * std::log(10.0) / options.rt60;  // amplitude: -60 dB in rt60
  const double floor = std::clamp(options.floor, 0.0, 1.0);

  detail::RealFft fft(n);
  // The power of a reverberant tail in one frame and bin is as random as noise's, so the late
  // part is predicted from three frames around `delay` before, each decayed by its own distance,
  // and each bin's power may be averaged with its neighbours (smoothing_bins). (A recursive
  // average over time would decay slower than the tail it must follow.)
  const std::size_t spread = static_cast<std::size_t>(std::clamp(options.smoothing_bins, 0, 64));
  const double beta = std::clamp(options.oversubtraction, 0.0, 10.0);
  const std::size_t kept = delay + 2;  // frames of power kept: f - delay - 1 .. f
  std::vector<std::vector<double>> power(kept, std::vector<double>(fft.bins()));
  std::array<double, 3> share{};  // for frames f - delay - 1, f - delay, f - delay + 1
  for (std::size_t j = 0; j < 3; ++j) {
    share[j] = std::exp(-2.0 * decay_per_second * static_cast<double>((delay + 1 - j) * hop) / rate) / 3.0;
  }
  std::vector<std::complex<float>> spectrum(fft.bins());
  std::vector<float> frame(n), out(n);
  std::vector<double> sum(length, 0.0), weight(length, 0.0);
  for (std::size_t f = 0; f < frames; ++f) {
    const auto begin = start_of(f);
    for (std::size_t i = 0; i < n; ++i) {
      const auto at = begin + static_cast<std::ptrdiff_t>(i);
      frame[i] = at >= 0 && static_cast<std::size_t>(at) < length ? signal.samples[static_cast<std::size_t>(at)] * window[i] : 0.0f;
    }
    fft.forward(frame, spectrum);
    auto& now = power[f % kept];
    for (std::size_t k = 0; k < fft.bins(); ++k) {
      double total = 0;
      const std::size_t from = k >= spread ? k - spread : 0, to = std::min(fft.bins() - 1, k + spread);
      for (std::size_t j = from; j <= to; ++j) total += std::norm(spectrum[j]);
      now[k] = total / static_cast<double>(to - from + 1);
    }
    // The first frames have no past to predict from: they pass as they are.
    for (std::size_t k = 0; f > delay && k < fft.bins(); ++k) {
      const double p = now[k];
      if (p <= 0.0) continue;
      double late = 0;
      for (std::size_t j = 0; j < 3; ++j) late += share[j] * power[(f - delay - 1 + j) % kept][k];
      const double gain = std::max(std::sqrt(std::max(0.0, 1.0 - beta * late / p)), floor);
      spectrum[k] *= static_cast<float>(gain);
    }
    fft.inverse(spectrum, out);
    for (std::size_t i = 0; i < n; ++i) {
      const auto at = begin + static_cast<std::ptrdiff_t>(i);
      if (at < 0 || static_cast<std::size_t>(at) >= length) continue;
      sum[static_cast<std::size_t>(at)] += static_cast<double>(out[i]) * window[i] / static_cast<double>(n);
      weight[static_cast<std::size_t>(at)] += static_cast<double>(window[i]) * window[i];
    }
  }
  Signal result{signal.sample_rate, std::vector<float>(length)};
  for (std::size_t i = 0; i < length; ++i) {
    result.samples[i] = weight[i] > 1e-9 ? static_cast<float>(sum[i] / weight[i]) : 0.0f;
  }
  return result;
}

}  // namespace icars::audio
