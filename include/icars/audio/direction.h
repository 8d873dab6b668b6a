// Direction of arrival from a microphone array: GCC-PHAT cross-correlations of every pair of
// channels (FFTW, interpolated for sub-sample delays), combined by steered response power over
// candidate directions in the array's plane (SRP-PHAT). A far-field source is assumed.
#pragma once

#include <vector>

#include "icars/audio/pcm.h"

namespace icars::audio {

inline constexpr double kSpeedOfSound = 343.0;  // m/s

struct MicPosition {
  double x = 0;  // metres, in the array's frame (x forward, y left)
  double y = 0;
};

// `count` microphones on a circle of `radius` metres, the first one straight ahead.
std::vector<MicPosition> circular_array(int count, double radius);

struct DirectionEstimate {
  bool valid = false;     // false for audio with nothing in it (digital silence, no frames)
  double bearing = 0;     // radians, counter-clockwise from the array's x axis, in (-pi, pi]
  double confidence = 0;  // 0..1: how much the best direction stands out from the others
};

// The direction a sound came from, from the ~64 ms frames within 20 dB of the loudest (the
// sound, not the pauses around it). Needs at least two channels, one per entry of `mics`
// (AudioError otherwise, naming both counts). Confidence is the steered power of the best
// bearing above the median bearing's, per microphone pair: near 1 for one clean source, near 0
// for diffuse noise; in a reverberant room 0.05..0.3 is usual.
// A two-microphone array hears a source and its mirror image across the line through the
// microphones alike: it reports the image further to the front, so a pair side by side (on
// the y axis) cannot tell front from back and gives |bearing| <= pi/2. A pair on the x axis
// (circular_array(2, r)) tells front from back but not left from right and reports the image
// on the left (bearing >= 0). Near the line through a pair its bearings are coarse.
DirectionEstimate estimate_direction(const AudioBlock& audio, const std::vector<MicPosition>& mics,
                                     double resolution_deg = 1.0);

// Delay-and-sum beamforming: every channel delayed (fractionally, in the frequency domain) so
// that a far-field sound from `bearing` (radians, as DirectionEstimate's) lines up across the
// array, then averaged into one channel at the array's centre. Sound from that direction adds
// up in phase; noise and reverberation from elsewhere partly cancel. One channel per entry of
// `mics` (AudioError otherwise); no frames give an empty signal.
Signal steer_towards(const AudioBlock& audio, const std::vector<MicPosition>& mics, double bearing);

// The delay of `b` relative to `a` in seconds by GCC-PHAT over the whole signals (positive:
// the sound reached `a` first), searched within +-max_delay seconds and interpolated to about
// a hundredth of a sample. AudioError for an empty signal.
double gcc_phat_delay(const std::vector<float>& a, const std::vector<float>& b, int sample_rate,
                      double max_delay);

}  // namespace icars::audio
