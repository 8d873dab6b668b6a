#include "icars/audio/direction.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <numbers>

#include "real_fft.h"

namespace icars::audio {
namespace {

using detail::fft_size_for;
using detail::RealFft;

constexpr double kPi = std::numbers::pi;
constexpr int kUpsample = 8;             // the SRP's correlations, interpolated to 1/8 sample
constexpr double kFrameSeconds = 0.064;  // analysis frame of estimate_direction
constexpr double kFrameRangeDb = 20.0;   // frames this far below the loudest are left out
constexpr double kLowCutHz = 80.0;       // below: rumble and hum, no direction to speak of

// The PHAT weighting: the cross-spectrum conj(a)·b with unit magnitude (0 where it vanishes).
std::complex<double> phat(std::complex<float> a, std::complex<float> b) {
  const std::complex<double> cross = std::conj(std::complex<double>(a)) * std::complex<double>(b);
  const double magnitude = std::abs(cross);
  return magnitude > 1e-30 ? cross / magnitude : std::complex<double>{};
}

// The generalised cross-correlation at a fractional lag `tau` (samples) from a weighted
// cross-spectrum of an n-point transform, evaluated directly (band-limited interpolation).
double correlation_at(const std::vector<std::complex<double>>& w, std::size_t n, double tau) {
  const std::complex<double> step = std::polar(1.0, 2.0 * kPi * tau / static_cast<double>(n));
  std::complex<double> rotation = step;
  double sum = w[0].real();
  for (std::size_t k = 1; k + 1 < w.size(); ++k) {
    sum += 2.0 * (w[k] * rotation).real();
    rotation *= step;
  }
  sum += (w.back() * std::polar(1.0, kPi * tau)).real();
  return sum / static_cast<double>(n);
}

double wrap_bearing(double b) {  // to (-pi, pi]
  b = std::remainder(b, 2.0 * kPi);
  return b <= -kPi ? b + 2.0 * kPi : b;
}

std::vector<float> channel_as_float(const AudioBlock& audio, std::size_t c) {
  const auto channels = static_cast<std::size_t>(audio.format.channels);
  std::vector<float> out(audio.frames());
  for (std::size_t i = 0; i < out.size(); ++i) {
    out[i] = static_cast<float>(audio.samples[i * channels + c]) / 32768.0f;
  }
  return out;
}

}  // namespace

std::vector<MicPosition> circular_array(int count, double radius) {
  if (count < 1) throw AudioError(fmt::format("circular_array: count {} (at least 1)", count));
  std::vector<MicPosition> mics;
  for (int i = 0; i < count; ++i) {
    const double angle = 2.0 * kPi * i / count;
    mics.push_back({radius * std::cos(angle), radius * std::sin(angle)});
  }
  return mics;
}

double gcc_phat_delay(const std::vector<float>& a, const std::vector<float>& b, int sample_rate,
                      double max_delay) {
  if (a.empty() || b.empty()) throw AudioError("gcc_phat_delay: an empty signal");
  if (sample_rate <= 0) {
    throw AudioError(fmt::format("gcc_phat_delay: sample rate {}", sample_rate));
  }
  const std::size_t n = fft_size_for(2 * std::max(a.size(), b.size()));
  RealFft fft(n);
  std::vector<std::complex<float>> spectrum_a(fft.bins()), spectrum_b(fft.bins());
  fft.forward(a, spectrum_a);
  fft.forward(b, spectrum_b);
  std::vector<std::complex<double>> weighted(fft.bins());
  std::vector<std::complex<float>> weighted_f(fft.bins());
  for (std::size_t k = 0; k < fft.bins(); ++k) {
    weighted[k] = phat(spectrum_a[k], spectrum_b[k]);
    weighted_f[k] = std::complex<float>(weighted[k]);
  }
  std::vector<float> correlation(n);
  fft.inverse(weighted_f, correlation);

  // The integer lag of the peak within +-max_delay, then the fractional one around it.
  const double max_lag =
      std::min(std::max(max_delay, 0.0) * sample_rate, static_cast<double>(n) / 2.0 - 1.0);
  const auto limit = static_cast<long>(std::floor(max_lag));
  long best = 0;
  for (long lag = -limit; lag <= limit; ++lag) {
    const auto index = static_cast<std::size_t>(lag < 0 ? lag + static_cast<long>(n) : lag);
    const auto best_index = static_cast<std::size_t>(best < 0 ? best + static_cast<long>(n) : best);
    if (correlation[index] > correlation[best_index]) best = lag;
  }
  constexpr int kSteps = 16;  // a grid of 1/16 sample over +-1 sample, then a parabola
  const double h = 1.0 / kSteps;
  double best_tau = static_cast<double>(best);
  double best_value = correlation_at(weighted, n, best_tau);
  for (int s = -kSteps; s <= kSteps; ++s) {
    const double tau = std::clamp(static_cast<double>(best) + s * h, -max_lag, max_lag);
    const double value = correlation_at(weighted, n, tau);
    if (value > best_value) {
      best_value = value;
      best_tau = tau;
    }
  }
  if (best_tau - h >= -max_lag && best_tau + h <= max_lag) {
    const double before = correlation_at(weighted, n, best_tau - h);
    const double after = correlation_at(weighted, n, best_tau + h);
    const double curvature = before - 2.0 * best_value + after;
    if (curvature < 0) best_tau += std::clamp(0.5 * h * (before - after) / curvature, -h, h);
  }
  return best_tau / sample_rate;
}

Signal steer_towards(const AudioBlock& audio, const std::vector<MicPosition>& mics, double bearing) {
  const auto channels = static_cast<std::size_t>(audio.format.channels);
  if (mics.empty() || channels != mics.size()) {
    throw AudioError(fmt::format("steer_towards: {} channels of audio for {} microphone positions",
                                 audio.format.channels, mics.size()));
  }
  const int rate = audio.format.sample_rate;
  Signal out;
  out.sample_rate = rate;
  const std::size_t frames = audio.frames();
  if (frames == 0) return out;
  // A microphone nearer the source by d metres hears it d / c earlier: delay it by that much.
  std::vector<double> delays;  // samples
  double longest = 0;
  for (const auto& m : mics) {
    delays.push_back((m.x * std::cos(bearing) + m.y * std::sin(bearing)) / kSpeedOfSound * rate);
    longest = std::max(longest, std::abs(delays.back()));
  }
  const auto pad = static_cast<std::size_t>(std::ceil(longest)) + 1;
  RealFft fft(fft_size_for(frames + 2 * pad));
  const double n = static_cast<double>(fft.size());
  std::vector<float> channel(frames + 2 * pad, 0.0f);
  std::vector<std::complex<float>> spectrum(fft.bins()), sum(fft.bins());
  for (std::size_t c = 0; c < channels; ++c) {
    for (std::size_t i = 0; i < frames; ++i) {
      channel[pad + i] = static_cast<float>(audio.samples[i * channels + c]) / 32768.0f;
    }
    fft.forward(channel, spectrum);
    for (std::size_t k = 0; k < spectrum.size(); ++k) {
      const double phase = -2.0 * std::numbers::pi * static_cast<double>(k) / n * delays[c];
      sum[k] += spectrum[k] * std::complex<float>(static_cast<float>(std::cos(phase)),
                                                  static_cast<float>(std::sin(phase)));
    }
  }
  std::vector<float> aligned(fft.size());
  fft.inverse(sum, aligned);
  const auto scale = static_cast<float>(1.0 / (n * static_cast<double>(channels)));
  out.samples.resize(frames);
  for (std::size_t i = 0; i < frames; ++i) out.samples[i] = aligned[pad + i] * scale;
  return out;
}

DirectionEstimate estimate_direction(const AudioBlock& audio, const std::vector<MicPosition>& mics,
                                     double resolution_deg) {
  if (mics.size() < 2) {
    throw AudioError(fmt::format(
        "estimate_direction: {} microphone(s); a direction needs at least two", mics.size()));
  }
  if (audio.format.channels != static_cast<int>(mics.size())) {
    throw AudioError(fmt::format("estimate_direction: audio of {} channels for {} microphones",
                                 audio.format.channels, mics.size()));
  }
  if (audio.format.sample_rate <= 0) {
    throw AudioError(fmt::format("estimate_direction: sample rate {}", audio.format.sample_rate));
  }
  if (!(resolution_deg > 0.0 && resolution_deg <= 90.0)) {
    throw AudioError(
        fmt::format("estimate_direction: resolution {} degrees (0 < it <= 90)", resolution_deg));
  }
  const int rate = audio.format.sample_rate;
  const auto channels = static_cast<std::size_t>(audio.format.channels);
  DirectionEstimate estimate;
  if (audio.frames() == 0) return estimate;

  struct Pair {
    std::size_t a, b;
    double dx, dy;  // (position a - position b) / c, in upsampled samples per unit bearing vector
    std::vector<std::complex<double>> cross;  // accumulated PHAT cross-spectrum
    std::vector<float> correlation;           // upsampled, lag 0 at index 0
  };
  std::vector<Pair> pairs;
  double max_spacing = 0;
  for (std::size_t a = 0; a < channels; ++a) {
    for (std::size_t b = a + 1; b < channels; ++b) {
      const double dx = mics[a].x - mics[b].x, dy = mics[a].y - mics[b].y;
      max_spacing = std::max(max_spacing, std::hypot(dx, dy));
      const double scale = static_cast<double>(rate) * kUpsample / kSpeedOfSound;
      pairs.push_back({a, b, dx * scale, dy * scale, {}, {}});
    }
  }

  // Frames of ~64 ms (longer than the array's largest delay many times over), half overlapping,
  // Hann-windowed and zero-padded to twice their length.
  const std::size_t max_lag =
      static_cast<std::size_t>(std::ceil(max_spacing / kSpeedOfSound * rate));
  const std::size_t frame = std::max(fft_size_for(static_cast<std::size_t>(rate * kFrameSeconds)),
                                     fft_size_for(8 * max_lag + 8));
  const std::size_t hop = frame / 2;
  const std::size_t total = audio.frames();
  std::vector<std::size_t> starts;
  for (std::size_t s = 0; s == 0 || s + frame <= total; s += hop) starts.push_back(s);

  std::vector<std::vector<float>> signal(channels);
  for (std::size_t c = 0; c < channels; ++c) signal[c] = channel_as_float(audio, c);
  std::vector<double> energy(starts.size(), 0.0);
  for (std::size_t f = 0; f < starts.size(); ++f) {
    const std::size_t end = std::min(total, starts[f] + frame);
    for (std::size_t c = 0; c < channels; ++c) {
      for (std::size_t i = starts[f]; i < end; ++i) {
        energy[f] += static_cast<double>(signal[c][i]) * signal[c][i];
      }
    }
  }
  const double loudest = *std::max_element(energy.begin(), energy.end());
  if (loudest <= 0.0) return estimate;  // digital silence has no direction
  const double floor = loudest * std::pow(10.0, -kFrameRangeDb / 10.0);

  RealFft fft(2 * frame);
  const std::size_t bins = fft.bins();
  const auto low_bin =
      static_cast<std::size_t>(std::ceil(kLowCutHz * static_cast<double>(fft.size()) / rate));
  std::vector<float> window(frame), windowed(frame);
  for (std::size_t i = 0; i < frame; ++i) {
    const double phase = (static_cast<double>(i) + 0.5) / static_cast<double>(frame);
    window[i] = static_cast<float>(0.5 - 0.5 * std::cos(2.0 * kPi * phase));
  }
  std::vector<std::vector<std::complex<float>>> spectra(channels,
                                                        std::vector<std::complex<float>>(bins));
  for (auto& pair : pairs) pair.cross.assign(bins, {});
  std::size_t used = 0;
  for (std::size_t f = 0; f < starts.size(); ++f) {
    if (energy[f] < floor) continue;
    ++used;
    for (std::size_t c = 0; c < channels; ++c) {
      const std::size_t end = std::min(total, starts[f] + frame);
      std::fill(windowed.begin(), windowed.end(), 0.0f);
      for (std::size_t i = starts[f]; i < end; ++i) {
        windowed[i - starts[f]] = signal[c][i] * window[i - starts[f]];
      }
      fft.forward(windowed, spectra[c]);
    }
    for (auto& pair : pairs) {
      for (std::size_t k = std::max<std::size_t>(low_bin, 1); k + 1 < bins; ++k) {
        pair.cross[k] += phat(spectra[pair.a][k], spectra[pair.b][k]);
      }
    }
  }

  // Each pair's correlation, upsampled by zero-padding its cross-spectrum: peak 1 for a pair
  // that hears one source with no noise.
  RealFft upsampled(fft.size() * kUpsample);
  std::vector<std::complex<float>> padded(upsampled.bins());
  const double norm = 1.0 / (static_cast<double>(fft.size()) * static_cast<double>(used));
  for (auto& pair : pairs) {
    std::fill(padded.begin(), padded.end(), std::complex<float>{});
    for (std::size_t k = 0; k < bins; ++k) padded[k] = std::complex<float>(pair.cross[k] * norm);
    pair.correlation.resize(upsampled.size());
    upsampled.inverse(padded, pair.correlation);
  }

  // Steered response power over the candidate bearings: the sound from bearing u reaches mic a
  // (p_a - p_b)·u / c before mic b.
  const auto steps = static_cast<int>(std::lround(360.0 / resolution_deg));
  const auto length = static_cast<double>(upsampled.size());
  std::vector<double> power(static_cast<std::size_t>(steps));
  for (int s = 0; s < steps; ++s) {
    const double bearing = 2.0 * kPi * s / steps;
    const double ux = std::cos(bearing), uy = std::sin(bearing);
    double sum = 0;
    for (const auto& pair : pairs) {
      double lag = pair.dx * ux + pair.dy * uy;
      if (lag < 0) lag += length;
      const auto i0 = static_cast<std::size_t>(lag) % pair.correlation.size();
      const std::size_t i1 = (i0 + 1) % pair.correlation.size();
      const double t = lag - std::floor(lag);
      sum += (1.0 - t) * pair.correlation[i0] + t * pair.correlation[i1];
    }
    power[static_cast<std::size_t>(s)] = sum;
  }
  const auto best = std::max_element(power.begin(), power.end());
  std::vector<double> sorted = power;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2),
                   sorted.end());
  const double median = sorted[sorted.size() / 2];

  double bearing = wrap_bearing(2.0 * kPi * static_cast<double>(best - power.begin()) / steps);
  if (mics.size() == 2) {
    // A pair hears a source and its mirror image across the line through it alike: report the
    // image further to the front, or (a pair on the x axis) the one on the left.
    const double axis = std::atan2(mics[1].y - mics[0].y, mics[1].x - mics[0].x);
    const double mirror = wrap_bearing(2.0 * axis - bearing);
    const double front = std::cos(bearing), mirror_front = std::cos(mirror);
    if (mirror_front > front + 1e-9 ||
        (std::abs(mirror_front - front) <= 1e-9 && std::sin(mirror) > std::sin(bearing))) {
      bearing = mirror;
    }
  }
  estimate.valid = true;
  estimate.bearing = bearing;
  estimate.confidence = std::clamp((*best - median) / static_cast<double>(pairs.size()), 0.0, 1.0);
  return estimate;
}

}  // namespace icars::audio
