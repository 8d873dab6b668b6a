// Voice-activity detection: cuts a continuous capture into utterances, so nothing needs a
// push-to-talk. Energy in 20 ms frames (the mean over channels) against a noise floor the
// detector learns (it falls at once to a quieter frame and rises at most 2 dB a second, so it
// follows the quiet between words, and a noise that comes to stay, a fan or a TV, becomes the
// floor within seconds), with an onset of a few loud frames, a hangover of quiet frames before
// an utterance ends, and bounds on an utterance's length. Gaps in the timeline (a microphone
// that sends nothing while it hears nothing) count as silence. Memory is bounded: hours of
// silence keep nothing; an utterance longer than max_utterance is cut there, and the next one
// starts where it was cut.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "icars/audio/pcm.h"

namespace icars::audio {

struct VadOptions {
  double threshold_db = 9.0;      // a frame is speech this far above the noise floor
  double min_level_dbfs = -65.0;  // ... and at least this loud
  int onset_ms = 60;              // speech frames in a row that start an utterance
  int hangover_ms = 400;          // quiet after which an utterance ends
  int pre_roll_ms = 200;          // audio kept from before the onset
  int min_utterance_ms = 150;     // shorter bursts (onset to speech end: a knock) are dropped
  int max_utterance_ms = 10000;   // longer ones are cut and reported (`truncated`)
};

struct Utterance {
  AudioBlock audio;              // every channel, from pre-roll to the end of the hangover
  double level_dbfs = -120;      // RMS over the speech frames, first channel
  double peak_dbfs = -120;       // loudest sample
  std::size_t clipped = 0;       // samples at full scale
  bool truncated = false;        // cut at max_utterance_ms
  bool interrupted = false;      // the capture ended (flush) before the hangover
  std::uint64_t speech_end = 0;  // the frame index where speech (not the hangover) ended;
                                 // a truncated utterance's end
};

// One capture's detector; not thread-safe. Copies share their state: make one per capture.
class VoiceActivityDetector {
 public:
  // AudioError for options that cannot work (onset or hangover under 20 ms, max_utterance_ms
  // shorter than onset and pre-roll).
  explicit VoiceActivityDetector(VadOptions options = {});

  // Feeds the next audio, in blocks of any size; its format must stay the same (AudioError
  // otherwise). `audio.start` before the end of the previous block is an AudioError; after it,
  // the gap is silence (it ends an utterance, but does not teach the noise floor). Returns the
  // utterances that ended within it. The first block's start begins the timeline.
  std::vector<Utterance> feed(const AudioBlock& audio);
  // The capture ended: an utterance in progress is returned (interrupted), if long enough. The
  // noise floor is kept; feeding may go on after it.
  std::optional<Utterance> flush();

  bool in_speech() const;
  double noise_floor_dbfs() const;
  std::uint64_t position() const;  // the frame index after everything fed

 private:
  struct State;
  VadOptions options_;
  std::shared_ptr<State> state_;
};

}  // namespace icars::audio
