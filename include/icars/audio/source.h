// Sources of real audio for a microphone device: a sound card through ALSA, a WAV file, or raw
// 16-bit PCM from a pipe or file (what `arecord -t raw` or `sox ... -t raw -` writes). They all
// deliver AudioBlocks in periods of kFrameMs on one timeline, so the same device code serves a
// person speaking to a real machine and a test feeding a file.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "icars/audio/pcm.h"

namespace icars::audio {

class AudioSource {
 public:
  virtual ~AudioSource() = default;
  virtual AudioFormat format() const = 0;
  // The next period, blocking as a sound card does; nullopt at the end (a file ran out, the
  // pipe closed, the device was unplugged: see error()). Blocks start on one timeline from 0;
  // the last one of a file or pipe may be shorter (a trailing partial frame is dropped).
  // One reading thread.
  virtual std::optional<AudioBlock> read() = 0;
  // Why read() returned nullopt: "" at a clean end of a file or pipe, or after stop().
  virtual std::string error() const = 0;
  // Makes a blocked read() return nullopt soon, and every later one (from any thread).
  virtual void stop() = 0;
  // Periods the source lost because it was not read in time (a sound card's overruns); the
  // timeline skips them, so the next block starts after a gap.
  virtual std::uint64_t overruns() const { return 0; }
};

struct SourceOptions {
  AudioFormat format{kSpeechRate, 1};  // what to ask a sound card for; raw PCM's format
  bool real_time = true;  // files and pipes: deliver at the pace of their sample rate (a
                          // period once its last frame's time has come, from the first read)
  bool loop = false;      // files (not pipes): start again at the end, on the same timeline
};

// "alsa:NAME" (e.g. alsa:default, alsa:hw:1,0), "wav:PATH" (its own format), "raw:PATH" (PATH
// "-" is stdin; a named pipe works, opened without waiting for its writer). AudioError naming
// the spec if it is malformed or cannot be opened (a sound card that is missing or refuses the
// format included).
std::unique_ptr<AudioSource> open_source(const std::string& spec, SourceOptions options = {});

}  // namespace icars::audio
