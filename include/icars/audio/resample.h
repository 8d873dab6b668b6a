// Sample-rate conversion (libsamplerate, best-quality sinc): what makes espeak-ng's 22,050 Hz
// voice and a sound card's 44,100 / 48,000 Hz capture into the recognizer's 16,000 Hz.
#pragma once

#include "icars/audio/pcm.h"

namespace icars::audio {

inline constexpr int kMinSampleRate = 8000;
inline constexpr int kMaxSampleRate = 192000;

// `in` at another rate; an AudioError for rates outside kMinSampleRate..kMaxSampleRate.
Signal resample(const Signal& in, int to_rate);
// Every channel of `in` resampled to `to_rate`; `start` scaled to the new rate.
AudioBlock resample(const AudioBlock& in, int to_rate);

}  // namespace icars::audio
