#include "icars/audio/pcm.h"

namespace icars::audio {

std::vector<std::byte> pcm_bytes(std::span<const std::int16_t> samples) {
  std::vector<std::byte> bytes(samples.size() * 2);
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const auto v = static_cast<std::uint16_t>(samples[i]);
    bytes[2 * i] = static_cast<std::byte>(v & 0xFF);
    bytes[2 * i + 1] = static_cast<std::byte>(v >> 8);
  }
  return bytes;
}

std::vector<std::int16_t> pcm_samples(std::span<const std::byte> bytes) {
  std::vector<std::int16_t> samples(bytes.size() / 2);
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const auto lo = static_cast<std::uint16_t>(bytes[2 * i]);
    const auto hi = static_cast<std::uint16_t>(bytes[2 * i + 1]);
    samples[i] = static_cast<std::int16_t>(lo | (hi << 8));
  }
  return samples;
}

}  // namespace icars::audio
