// Audio as ICARS devices and services pass it around: interleaved signed 16-bit PCM with its
// format and the index of its first sample on the capture's timeline.
//
// The audio layer (icars_audio) is the generic sound processing the home's voice path is built
// from: speech synthesis (espeak-ng), speech recognition (PocketSphinx), voice-activity
// detection, direction of arrival from a microphone array, rendering a voice as a microphone
// array hears it in a room, the framing of audio on a PLANET stream, and sources of real
// audio (ALSA, WAV files, raw pipes). It knows nothing of houses, devices or PLANET objects.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace icars::audio {

inline constexpr int kSpeechRate = 16000;  // what the recognizer and the simulated microphones use

struct AudioFormat {
  int sample_rate = kSpeechRate;  // frames per second
  int channels = 1;               // samples per frame, interleaved
  bool operator==(const AudioFormat&) const = default;
};

// A stretch of audio. `samples` holds frames() * format.channels values, channel-interleaved.
struct AudioBlock {
  AudioFormat format;
  std::uint64_t start = 0;  // index of the first frame on the capture's timeline
  std::vector<std::int16_t> samples;

  std::size_t frames() const {
    return format.channels > 0 ? samples.size() / static_cast<std::size_t>(format.channels) : 0;
  }
  std::uint64_t end() const { return start + frames(); }  // one past the last frame
  double seconds() const { return static_cast<double>(frames()) / format.sample_rate; }
  // One channel as a plain signal.
  std::vector<std::int16_t> channel(int c) const;
};

// Mono float signal in [-1, 1] at some rate: what synthesis and rendering work in.
struct Signal {
  int sample_rate = kSpeechRate;
  std::vector<float> samples;
  double seconds() const { return static_cast<double>(samples.size()) / sample_rate; }
};

// Bad audio input (a malformed frame, an unsupported rate); the message names what was wrong.
class AudioError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Float [-1, 1] → int16 (scaled by 32767) with saturation (counts how many samples clipped when
// `clipped` is set). NaN becomes 0.
std::int16_t to_pcm16(float v, std::size_t* clipped = nullptr);
// Level of int16 audio in dB full scale (RMS against 32768; -120 for digital silence).
double rms_dbfs(std::span<const std::int16_t> samples);

// A signal as one-channel PCM starting at frame 0, saturated as to_pcm16 does.
AudioBlock to_block(const Signal& signal, std::size_t* clipped = nullptr);
// The mean of all channels as a float signal (the inverse of to_block's scaling); AudioError for
// a block with no channels.
Signal mix_down(const AudioBlock& audio);

// Samples as the 16-bit little-endian bytes that travel in PLANET binaries and streams, and back
// (an odd trailing byte is ignored).
std::vector<std::byte> pcm_bytes(std::span<const std::int16_t> samples);
std::vector<std::int16_t> pcm_samples(std::span<const std::byte> bytes);

}  // namespace icars::audio
