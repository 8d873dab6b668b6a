// Microphones as devices: what every Microphone servant of the home shares. CaptureStreams
// serves the live captures (Microphone::capture) of one microphone: each reader gets the audio
// frames pushed from the moment it opened, through a PLANET stream with its flow control; a
// reader that falls more than `max_behind` behind loses its oldest frames (counted), as a
// sound card overruns, instead of holding the microphone up. SourceMicrophone is a real
// microphone: audio from an audio::AudioSource (ALSA, a WAV file, a raw pipe) timed on a clock,
// so a person can speak to ICARS on a real machine, and a test can stand a file in for the
// sound card through the same code.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "home.planet.h"
#include "icars/audio/direction.h"
#include "icars/audio/source.h"
#include "icars/clock/clock.h"
#include "icars/planet/communicator.h"

namespace icars::planet {
class OutputStream;
}

namespace icars::home {

class CaptureStreams {
 public:
  explicit CaptureStreams(planet::Communicator& communicator,
                          std::chrono::milliseconds max_behind = std::chrono::seconds(5),
                          std::chrono::milliseconds history = std::chrono::seconds(60));
  ~CaptureStreams();  // closes every capture
  CaptureStreams(const CaptureStreams&) = delete;
  CaptureStreams& operator=(const CaptureStreams&) = delete;

  // A new capture: the reader of the returned stream gets the frames it still holds that end
  // after `since` (at most `history` of audio), then every frame pushed from now on.
  planet::StreamRef open(std::uint64_t since = 0);
  // Sends `audio` to every capture as frames of audio::kFrameMs. Thread-safe, never blocks.
  void push(const audio::AudioBlock& audio);
  std::size_t readers() const;
  // Whether anyone ever opened a capture (and so may come back for what it missed).
  bool listened_to() const { return listened_to_.load(); }
  std::uint64_t dropped_frames() const { return dropped_.load(); }
  // Ends every capture after what was pushed so far (the microphone is gone).
  void close_all();

 private:
  struct Reader;
  void write_next(const std::shared_ptr<Reader>& reader);
  planet::Communicator& communicator_;
  std::chrono::milliseconds max_behind_;
  std::chrono::milliseconds history_span_;
  mutable std::mutex mutex_;
  std::vector<std::shared_ptr<Reader>> readers_;
  struct Sent {
    std::vector<std::byte> bytes;
    std::uint64_t start = 0, end = 0;  // frame indexes
  };
  std::deque<Sent> history_;
  std::uint64_t history_frames_ = 0;
  std::atomic<std::uint64_t> dropped_{0};
  std::atomic<bool> listened_to_{false};
};

// The info() of a microphone: its format, the positions of its array's microphones (one per
// channel) and its detection threshold.
MicrophoneInfo microphone_info(const audio::AudioFormat& format, const std::vector<audio::MicPosition>& mics,
                               double threshold_db, std::string source);

// A microphone reading a real audio source on a thread of its own. Its capture's timeline is
// the clock's: the first frame read is stamped with the clock's time at start(). When the
// source ends (a file ran out, a pipe closed, the card was unplugged) its captures end too.
class SourceMicrophone final : public home::MicrophoneServant {
 public:
  SourceMicrophone(std::unique_ptr<audio::AudioSource> source, std::string spec, const icars::Clock& clock,
                   planet::Communicator& communicator, std::vector<audio::MicPosition> mics = {},
                   double threshold_db = 40.0);
  ~SourceMicrophone() override;  // stops the source and joins its thread

  void start();  // starts reading; idempotent
  MicrophoneInfo info(const planet::Current&) override;
  // planet::Error(failed) naming the source once it ended: there is nothing more to hear.
  planet::StreamRef capture(std::int64_t since, const planet::Current&) override;

  std::uint64_t frames_read() const { return frames_.load(); }
  // Why the source stopped ("" while it runs or after a clean end of a file).
  std::string error() const;
  bool ended() const { return ended_.load(); }

 private:
  void run();
  std::unique_ptr<audio::AudioSource> source_;
  std::string spec_;
  const icars::Clock& clock_;
  std::vector<audio::MicPosition> mics_;
  double threshold_db_;
  CaptureStreams captures_;
  std::thread thread_;
  std::once_flag started_;
  std::atomic<std::uint64_t> frames_{0};
  std::atomic<bool> ended_{false};
  mutable std::mutex mutex_;
  std::string error_;
};

}  // namespace icars::home
