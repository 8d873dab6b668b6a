#include "icars/audio/audio_stream.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <string>

#include "icars/audio/resample.h"

namespace icars::audio {
namespace {

constexpr std::array<std::byte, 4> kMagic{std::byte{'I'}, std::byte{'C'}, std::byte{'A'},
                                          std::byte{'U'}};
constexpr std::uint8_t kVersion = 1;

// Little-endian fields, whatever the host's byte order.
template <typename T>
void put_le(std::vector<std::byte>& out, T value) {
  for (std::size_t i = 0; i < sizeof(T); ++i) {
    out.push_back(static_cast<std::byte>((static_cast<std::uint64_t>(value) >> (8 * i)) & 0xff));
  }
}

template <typename T>
T get_le(const std::byte* p) {
  std::uint64_t v = 0;
  for (std::size_t i = 0; i < sizeof(T); ++i) v |= static_cast<std::uint64_t>(p[i]) << (8 * i);
  return static_cast<T>(v);
}

std::string describe_magic(std::span<const std::byte> got) {
  std::string out;
  for (std::byte b : got) {
    const auto c = static_cast<unsigned char>(b);
    out += (c >= 0x20 && c < 0x7f) ? fmt::format("{}", static_cast<char>(c))
                                   : fmt::format("\\x{:02x}", c);
  }
  return out;
}

void check_format(int channels, std::uint32_t sample_rate) {
  if (channels < 1 || channels > kMaxChannels) {
    throw AudioError(
        fmt::format("audio frame: channels {} out of range 1..{}", channels, kMaxChannels));
  }
  if (sample_rate < static_cast<std::uint32_t>(kMinSampleRate) ||
      sample_rate > static_cast<std::uint32_t>(kMaxSampleRate)) {
    throw AudioError(fmt::format("audio frame: sample_rate {} out of range {}..{}", sample_rate,
                                 kMinSampleRate, kMaxSampleRate));
  }
}

std::uint64_t max_frame_count(std::uint32_t sample_rate) {
  return static_cast<std::uint64_t>(sample_rate) * kMaxFrameMs / 1000;
}

}  // namespace

void encode_frames(const AudioBlock& audio, std::vector<std::byte>& out, int frame_ms) {
  check_format(audio.format.channels,
               static_cast<std::uint32_t>(std::max(audio.format.sample_rate, 0)));
  if (frame_ms < 1 || frame_ms > kMaxFrameMs) {
    throw AudioError(
        fmt::format("encode_frames: frame_ms {} out of range 1..{}", frame_ms, kMaxFrameMs));
  }
  const auto channels = static_cast<std::size_t>(audio.format.channels);
  if (audio.samples.size() % channels != 0) {
    throw AudioError(fmt::format("encode_frames: {} samples are not whole frames of {} channels",
                                 audio.samples.size(), channels));
  }
  const std::size_t per_frame =
      std::max<std::size_t>(1, static_cast<std::size_t>(audio.format.sample_rate) *
                                   static_cast<std::size_t>(frame_ms) / 1000);
  const std::size_t total = audio.frames();
  out.reserve(out.size() + (total / per_frame + 1) * kAudioFrameHeader + audio.samples.size() * 2);
  for (std::size_t first = 0; first < total; first += per_frame) {
    const std::size_t count = std::min(per_frame, total - first);
    out.insert(out.end(), kMagic.begin(), kMagic.end());
    put_le<std::uint8_t>(out, kVersion);
    put_le<std::uint8_t>(out, static_cast<std::uint8_t>(channels));
    put_le<std::uint16_t>(out, 0);
    put_le<std::uint32_t>(out, static_cast<std::uint32_t>(audio.format.sample_rate));
    put_le<std::uint64_t>(out, audio.start + first);
    put_le<std::uint32_t>(out, static_cast<std::uint32_t>(count));
    const auto begin = audio.samples.begin() + static_cast<std::ptrdiff_t>(first * channels);
    std::for_each(
        begin, begin + static_cast<std::ptrdiff_t>(count * channels),
        [&](std::int16_t s) { put_le<std::uint16_t>(out, static_cast<std::uint16_t>(s)); });
  }
}

std::vector<AudioBlock> AudioStreamDecoder::feed(std::span<const std::byte> bytes) {
  buffer_.insert(buffer_.end(), bytes.begin(), bytes.end());
  std::vector<AudioBlock> frames;
  std::size_t at = 0;  // first byte of the frame being decoded
  try {
    for (;;) {
      const std::span<const std::byte> rest(buffer_.data() + at, buffer_.size() - at);
      // The magic is checked as soon as its bytes arrive, so garbage fails fast.
      const std::size_t magic_bytes = std::min(rest.size(), kMagic.size());
      if (!std::equal(rest.begin(), rest.begin() + static_cast<std::ptrdiff_t>(magic_bytes),
                      kMagic.begin())) {
        throw AudioError(fmt::format("audio frame: bad magic \"{}\" (expected \"ICAU\")",
                                     describe_magic(rest.first(magic_bytes))));
      }
      if (rest.size() < kAudioFrameHeader) break;
      const auto version = get_le<std::uint8_t>(rest.data() + 4);
      if (version != kVersion) {
        throw AudioError(fmt::format("audio frame: unknown version {} (this reader knows {})",
                                     version, kVersion));
      }
      const int channels = get_le<std::uint8_t>(rest.data() + 5);
      const auto sample_rate = get_le<std::uint32_t>(rest.data() + 8);
      check_format(channels, sample_rate);
      const auto start = get_le<std::uint64_t>(rest.data() + 12);
      const auto count = get_le<std::uint32_t>(rest.data() + 20);
      if (count > max_frame_count(sample_rate)) {
        throw AudioError(
            fmt::format("audio frame: frame count {} longer than {} ms at {} Hz (at most {})",
                        count, kMaxFrameMs, sample_rate, max_frame_count(sample_rate)));
      }
      if (started_ && start < next_start_) {
        throw AudioError(fmt::format("audio frame: start {} before the previous frame's end {}",
                                     start, next_start_));
      }
      const std::size_t samples =
          static_cast<std::size_t>(count) * static_cast<std::size_t>(channels);
      const std::size_t payload = samples * 2;
      if (rest.size() < kAudioFrameHeader + payload) break;

      AudioBlock block;
      block.format = {static_cast<int>(sample_rate), channels};
      block.start = start;
      block.samples.resize(samples);
      const std::byte* p = rest.data() + kAudioFrameHeader;
      for (auto& s : block.samples) {
        s = static_cast<std::int16_t>(get_le<std::uint16_t>(p));
        p += 2;
      }
      started_ = true;
      next_start_ = block.end();
      frames.push_back(std::move(block));
      at += kAudioFrameHeader + payload;
    }
  } catch (const AudioError&) {
    buffer_.clear();
    started_ = false;
    next_start_ = 0;
    throw;
  }
  buffer_.erase(buffer_.begin(), buffer_.begin() + static_cast<std::ptrdiff_t>(at));
  return frames;
}

}  // namespace icars::audio
