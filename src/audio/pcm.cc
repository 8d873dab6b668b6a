#include "icars/audio/pcm.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace icars::audio {

std::vector<std::int16_t> AudioBlock::channel(int c) const {
  if (c < 0 || c >= format.channels) {
    throw std::out_of_range("AudioBlock::channel(" + std::to_string(c) + ") of audio with " +
                            std::to_string(format.channels) + " channels");
  }
  const auto step = static_cast<std::size_t>(format.channels);
  std::vector<std::int16_t> out;
  out.reserve(frames());
  for (std::size_t i = static_cast<std::size_t>(c); i < samples.size(); i += step) {
    out.push_back(samples[i]);
  }
  return out;
}

std::int16_t to_pcm16(float v, std::size_t* clipped) {
  if (std::isnan(v)) return 0;
  const float scaled = std::nearbyint(v * 32767.0f);
  if (scaled > 32767.0f || scaled < -32768.0f) {
    if (clipped != nullptr) ++*clipped;
    return scaled > 0 ? std::int16_t{32767} : std::int16_t{-32768};
  }
  return static_cast<std::int16_t>(scaled);
}

double rms_dbfs(std::span<const std::int16_t> samples) {
  constexpr double kSilence = -120.0;
  if (samples.empty()) return kSilence;
  double sum = 0;
  for (const std::int16_t s : samples) sum += static_cast<double>(s) * s;
  const double rms = std::sqrt(sum / static_cast<double>(samples.size())) / 32768.0;
  return rms > 0 ? std::max(kSilence, 20.0 * std::log10(rms)) : kSilence;
}

AudioBlock to_block(const Signal& signal, std::size_t* clipped) {
  AudioBlock out;
  out.format = {signal.sample_rate, 1};
  out.samples.reserve(signal.samples.size());
  for (const float v : signal.samples) out.samples.push_back(to_pcm16(v, clipped));
  return out;
}

Signal mix_down(const AudioBlock& audio) {
  if (audio.format.channels <= 0) {
    throw AudioError("cannot mix down audio with " + std::to_string(audio.format.channels) +
                     " channels: a block needs at least one");
  }
  const auto channels = static_cast<std::size_t>(audio.format.channels);
  Signal out;
  out.sample_rate = audio.format.sample_rate;
  out.samples.resize(audio.frames());
  const float scale = 1.0f / (32767.0f * static_cast<float>(channels));  // to_pcm16 inverted
  for (std::size_t f = 0; f < out.samples.size(); ++f) {
    float sum = 0;
    for (std::size_t c = 0; c < channels; ++c) sum += audio.samples[f * channels + c];
    out.samples[f] = sum * scale;
  }
  return out;
}

}  // namespace icars::audio
