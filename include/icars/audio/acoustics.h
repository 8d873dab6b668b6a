// A voice as a microphone array in a room hears it: delay and attenuation of the direct path to
// each microphone, diffuse reverberation of the room (an exponentially decaying noise tail per
// channel, RT60 given), and background noise, on a calibrated level scale. Deterministic for a
// seed. The simulated microphones render every utterance with it.
#pragma once

#include <cstdint>
#include <vector>

#include "icars/audio/pcm.h"

namespace icars::audio {

// 0 dBFS RMS is this sound pressure level: speech at 60 dB SPL comes out at -40 dBFS.
inline constexpr double kFullScaleSpl = 100.0;

struct Path {              // from the source to one microphone
  double distance = 1.0;   // metres (the delay is distance / speed of sound)
  double level_db = 60.0;  // SPL of the direct sound at the microphone (walls included)
};

struct RoomSound {
  double rt60 = 0.4;               // seconds for the reverberation to decay by 60 dB; 0: anechoic
  double critical_distance = 1.0;  // metres where reverberant and direct sound are equally loud
  double noise_db = 30.0;          // background noise, SPL (quiet room ~30, a TV or kitchen ~50);
                                   // pinkish, independent per microphone; below 0 (under the
                                   // converter's last bit): none
  std::uint64_t seed = 1;
};

// `source` (any level; it is scaled so that its RMS over the voiced part, the 20 ms frames
// within 40 dB of its loudest, is `paths[i].level_db` at microphone i) rendered to one channel
// per path, at source.sample_rate, starting with `lead` seconds of noise and ending with `tail`
// seconds after the source (the reverberation's decay and noise). Each path delays the source
// by distance / kSpeedOfSound (direction.h; a fractional delay), and its reverberation is
// (distance / critical_distance)^2 times as strong as its direct sound. Clipping saturates (as
// a real converter does) and is counted in `clipped`. AudioError for a rate outside
// kMinSampleRate..kMaxSampleRate, no paths or an out-of-range room.
AudioBlock render(const Signal& source, const std::vector<Path>& paths, const RoomSound& room,
                  double lead = 0.2, double tail = 0.6, std::size_t* clipped = nullptr);

// `signal` with the late reverberation of a room suppressed: single-channel spectral
// subtraction (Lebart, Boucher and Denbigh 2001). In 32 ms frames every 8 ms, the power of the
// late reverberation in each frequency bin is predicted from the signal `early` seconds before,
// decayed as a room of `rt60` decays (60 dB in rt60 seconds), and subtracted (times
// `oversubtraction`); what is left keeps at least `floor` of its amplitude. The direct sound and
// the early reflections, which carry speech's phones, stay; the tail that smears one phone over
// the next goes. The defaults take off about 5 dB of a tail and keep speech's spectrum as it is
// (what the recognizer measured best); smoothing_bins 3 and oversubtraction 1.5 take off 10 dB
// and blur the spectrum. AudioError for an rt60 outside kMinDereverberationRt60..kMaxRt60 s, an
// early part outside 0.01..0.5 s or a rate outside kMinSampleRate..kMaxSampleRate.
inline constexpr double kMaxRt60 = 5.0;                   // s: a cathedral's; rooms stay below
inline constexpr double kMinDereverberationRt60 = 0.05;  // s: below it there is no tail to take
struct Dereverberation {
  double rt60 = 0.4;
  double early = 0.05;
  double floor = 0.1;
  int smoothing_bins = 0;        // each bin's power averaged with this many neighbours each side
  double oversubtraction = 1.0;  // the predicted late power is subtracted this many times
};
Signal suppress_late_reverberation(const Signal& signal, const Dereverberation& options = {});

// `seconds` of the room's background noise on `channels` channels (what a microphone hears
// when nobody speaks), starting at frame 0.
AudioBlock room_noise(double seconds, int channels, const RoomSound& room,
                      int sample_rate = kSpeechRate);

}  // namespace icars::audio
