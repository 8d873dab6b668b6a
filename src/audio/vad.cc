#include "icars/audio/vad.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>

#include "icars/audio/resample.h"

namespace icars::audio {
namespace {

constexpr int kAnalysisMs = 20;
// The noise floor falls at once to a quieter frame and rises by at most this much per second
// while frames are louder: it follows the quiet between words, yet a noise that comes to stay
// (a fan, a TV) is taken for the floor within seconds instead of being heard as speech forever.
constexpr double kFloorRiseDbPerSecond = 2.0;

double level_db(double mean_square) {
  constexpr double kFullScale = 32768.0 * 32768.0;
  return mean_square > 0.0 ? std::max(-120.0, 10.0 * std::log10(mean_square / kFullScale)) : -120.0;
}

std::size_t frames_of_ms(int ms) {
  return static_cast<std::size_t>(std::max(0, (ms + kAnalysisMs / 2) / kAnalysisMs));
}

}  // namespace

// Everything the detector keeps: a fixed-size pre-roll ring, one analysis frame and the
// utterance in progress (at most max_utterance_ms), allocated when the format is known.
struct VoiceActivityDetector::State {
  explicit State(const VadOptions& o) : options(o) {}

  void begin(const AudioFormat& f, std::uint64_t start);
  void feed_samples(const std::int16_t* samples, std::size_t frames);
  void feed_gap(std::uint64_t frames);
  void process_frame();
  void push_ring();
  void start_utterance();
  void append_to_utterance(const std::int16_t* samples, std::size_t frames);
  void finish_utterance(bool truncated, bool interrupted, std::vector<Utterance>& out);
  void to_idle();

  VadOptions options;
  std::size_t onset_frames = 0, hangover_frames = 0;  // analysis frames
  std::uint64_t min_frames = 0, max_frames = 0;       // timeline frames

  bool started = false;
  AudioFormat format;
  std::size_t channels = 1;
  std::size_t frame_len = 0;   // timeline frames per 20 ms analysis frame
  std::uint64_t position = 0;  // after everything fed

  // The analysis frame being filled.
  std::vector<std::int16_t> frame;
  std::size_t frame_fill = 0;
  bool frame_has_gap = false;

  // Noise floor.
  bool floor_known = false;
  double floor_db = -120.0;
  double floor_rise_db = 0;  // per analysis frame

  // Idle: the last frames (pre-roll and onset) in a ring.
  std::vector<std::int16_t> ring;
  std::size_t ring_capacity = 0;  // analysis frames
  std::size_t ring_head = 0;      // slot of the oldest frame
  std::size_t ring_count = 0;
  std::uint64_t ring_start = 0;  // timeline index of the oldest frame
  std::size_t onset_count = 0;
  double onset_square_sum = 0;
  std::size_t silent_frames_in_row = 0;  // whole gap frames since the last frame of audio

  // Speaking.
  bool in_speech = false;
  AudioBlock audio;  // the utterance so far
  std::uint64_t speech_start = 0;
  std::uint64_t speech_end = 0;
  std::size_t quiet_count = 0;
  double speech_square_sum = 0;  // first channel, over speech frames
  std::size_t speech_samples = 0;

  std::vector<Utterance>* out = nullptr;  // where feed() collects
};

void VoiceActivityDetector::State::begin(const AudioFormat& f, std::uint64_t start) {
  started = true;
  format = f;
  channels = static_cast<std::size_t>(f.channels);
  frame_len =
      std::max<std::size_t>(1, static_cast<std::size_t>(f.sample_rate) * kAnalysisMs / 1000);
  position = start;
  frame.assign(frame_len * channels, 0);
  onset_frames = std::max<std::size_t>(1, frames_of_ms(options.onset_ms));
  hangover_frames = std::max<std::size_t>(1, frames_of_ms(options.hangover_ms));
  ring_capacity = frames_of_ms(options.pre_roll_ms) + onset_frames;
  ring.assign(ring_capacity * frame_len * channels, 0);
  const auto rate = static_cast<std::uint64_t>(f.sample_rate);
  min_frames = static_cast<std::uint64_t>(options.min_utterance_ms) * rate / 1000;
  max_frames = static_cast<std::uint64_t>(options.max_utterance_ms) * rate / 1000;
  floor_rise_db = kFloorRiseDbPerSecond * kAnalysisMs / 1000.0;
  audio.format = f;
}

void VoiceActivityDetector::State::feed_samples(const std::int16_t* samples, std::size_t frames) {
  while (frames > 0) {
    const std::size_t n = std::min(frames, frame_len - frame_fill);
    std::copy(samples, samples + n * channels,
              frame.begin() + static_cast<std::ptrdiff_t>(frame_fill * channels));
    frame_fill += n;
    position += n;
    samples += n * channels;
    frames -= n;
    if (frame_fill == frame_len) {
      silent_frames_in_row = 0;
      process_frame();
    }
  }
}

void VoiceActivityDetector::State::feed_gap(std::uint64_t frames) {
  while (frames > 0) {
    if (frame_fill == 0 && !in_speech && onset_count == 0 &&
        silent_frames_in_row >= ring_capacity && frames >= frame_len) {
      // Idle, the ring all silence: more silence changes nothing but the timeline.
      const std::uint64_t skip = frames / frame_len * frame_len;
      position += skip;
      ring_start += skip;
      frames -= skip;
      continue;
    }
    const std::size_t n =
        static_cast<std::size_t>(std::min<std::uint64_t>(frames, frame_len - frame_fill));
    std::fill_n(frame.begin() + static_cast<std::ptrdiff_t>(frame_fill * channels), n * channels,
                0);
    const bool whole = frame_fill == 0 && n == frame_len;
    frame_fill += n;
    position += n;
    frames -= n;
    frame_has_gap = true;
    if (frame_fill == frame_len) {
      process_frame();
      if (whole) ++silent_frames_in_row;
    }
  }
}

void VoiceActivityDetector::State::process_frame() {
  const std::uint64_t frame_start = position - frame_len;
  double square_sum = 0, first_square_sum = 0;
  for (std::size_t i = 0; i < frame.size(); ++i) {
    const double v = frame[i];
    square_sum += v * v;
    if (i % channels == 0) first_square_sum += v * v;
  }
  const double level = level_db(square_sum / static_cast<double>(frame.size()));
  const bool speech =
      floor_known && level >= floor_db + options.threshold_db && level >= options.min_level_dbfs;
  if (!frame_has_gap) {  // a gap says nothing about the room's noise
    if (!floor_known || level < floor_db) {
      floor_db = level;
      floor_known = true;
    } else {
      floor_db += std::min(level - floor_db, floor_rise_db);
    }
  }
  frame_has_gap = false;
  frame_fill = 0;

  if (in_speech) {
    if (audio.frames() + frame_len > max_frames) {
      finish_utterance(/*truncated=*/true, /*interrupted=*/false, *out);
    } else {
      append_to_utterance(frame.data(), frame_len);
      if (speech) {
        quiet_count = 0;
        speech_end = frame_start + frame_len;
        speech_square_sum += first_square_sum;
        speech_samples += frame_len;
      } else if (++quiet_count >= hangover_frames) {
        finish_utterance(false, false, *out);
      }
      return;
    }
  }
  push_ring();
  if (!speech) {
    onset_count = 0;
    return;
  }
  if (onset_count == 0) {
    speech_start = frame_start;
    onset_square_sum = 0;
  }
  onset_square_sum += first_square_sum;
  if (++onset_count >= onset_frames) start_utterance();
}

void VoiceActivityDetector::State::push_ring() {
  const std::size_t frame_samples = frame_len * channels;
  const std::uint64_t frame_start = position - frame_len;
  std::size_t slot;
  if (ring_count < ring_capacity) {
    slot = (ring_head + ring_count) % ring_capacity;
    if (ring_count == 0) ring_start = frame_start;
    ++ring_count;
  } else {
    slot = ring_head;
    ring_head = (ring_head + 1) % ring_capacity;
    ring_start += frame_len;
  }
  std::copy(frame.begin(), frame.end(),
            ring.begin() + static_cast<std::ptrdiff_t>(slot * frame_samples));
}

void VoiceActivityDetector::State::start_utterance() {
  const std::size_t frame_samples = frame_len * channels;
  in_speech = true;
  audio.start = ring_start;
  audio.samples.clear();
  for (std::size_t i = 0; i < ring_count; ++i) {
    const auto slot =
        static_cast<std::ptrdiff_t>(((ring_head + i) % ring_capacity) * frame_samples);
    append_to_utterance(ring.data() + slot, frame_len);
  }
  ring_count = 0;
  ring_head = 0;
  quiet_count = 0;
  speech_end = position;
  speech_square_sum = onset_square_sum;
  speech_samples = onset_count * frame_len;
  onset_count = 0;
}

void VoiceActivityDetector::State::append_to_utterance(const std::int16_t* samples,
                                                       std::size_t frames) {
  audio.samples.insert(audio.samples.end(), samples, samples + frames * channels);
}

void VoiceActivityDetector::State::finish_utterance(bool truncated, bool interrupted,
                                                    std::vector<Utterance>& result) {
  if (speech_end - speech_start >= min_frames) {
    Utterance u;
    u.audio = std::move(audio);
    audio = AudioBlock{format, 0, {}};
    u.truncated = truncated;
    u.interrupted = interrupted;
    u.speech_end = truncated ? u.audio.end() : speech_end;
    u.level_dbfs =
        level_db(speech_square_sum / static_cast<double>(std::max<std::size_t>(1, speech_samples)));
    int peak = 0;
    for (std::int16_t s : u.audio.samples) {
      const int magnitude = std::abs(static_cast<int>(s));
      peak = std::max(peak, magnitude);
      if (magnitude >= 32767) ++u.clipped;
    }
    u.peak_dbfs = peak > 0 ? 20.0 * std::log10(peak / 32768.0) : -120.0;
    result.push_back(std::move(u));
  }
  to_idle();
}

void VoiceActivityDetector::State::to_idle() {
  in_speech = false;
  audio.samples.clear();
  quiet_count = 0;
  onset_count = 0;
  ring_count = 0;  // the pre-roll of the next utterance starts after this one
  ring_head = 0;
}

VoiceActivityDetector::VoiceActivityDetector(VadOptions options)
    : options_(options), state_(std::make_shared<State>(options)) {
  if (options.onset_ms < kAnalysisMs || options.hangover_ms < kAnalysisMs ||
      options.pre_roll_ms < 0 || options.min_utterance_ms < 0 ||
      options.max_utterance_ms < options.onset_ms + options.pre_roll_ms + kAnalysisMs) {
    throw AudioError(fmt::format(
        "VadOptions: onset_ms {} and hangover_ms {} must be at least {} ms, pre_roll_ms {} and "
        "min_utterance_ms {} not negative, max_utterance_ms {} at least onset_ms + pre_roll_ms + "
        "{} ms",
        options.onset_ms, options.hangover_ms, kAnalysisMs, options.pre_roll_ms,
        options.min_utterance_ms, options.max_utterance_ms, kAnalysisMs));
  }
}

std::vector<Utterance> VoiceActivityDetector::feed(const AudioBlock& audio) {
  State& s = *state_;
  if (audio.format.channels < 1 || audio.format.channels > 64 ||
      audio.format.sample_rate < kMinSampleRate || audio.format.sample_rate > kMaxSampleRate) {
    throw AudioError(fmt::format("VoiceActivityDetector: format of {} channels at {} Hz",
                                 audio.format.channels, audio.format.sample_rate));
  }
  if (audio.samples.size() % static_cast<std::size_t>(audio.format.channels) != 0) {
    throw AudioError(
        fmt::format("VoiceActivityDetector: {} samples are not whole frames of {} channels",
                    audio.samples.size(), audio.format.channels));
  }
  if (!s.started) {
    s.begin(audio.format, audio.start);
  } else if (audio.format != s.format) {
    throw AudioError(fmt::format(
        "VoiceActivityDetector: format changed from {} channels at {} Hz to {} channels at {} Hz",
        s.format.channels, s.format.sample_rate, audio.format.channels, audio.format.sample_rate));
  } else if (audio.start < s.position) {
    throw AudioError(fmt::format(
        "VoiceActivityDetector: block starts at frame {}, before the end of the previous one ({})",
        audio.start, s.position));
  }
  std::vector<Utterance> result;
  s.out = &result;
  if (audio.start > s.position) s.feed_gap(audio.start - s.position);
  s.feed_samples(audio.samples.data(), audio.frames());
  s.out = nullptr;
  return result;
}

std::optional<Utterance> VoiceActivityDetector::flush() {
  State& s = *state_;
  std::vector<Utterance> result;
  if (s.in_speech) {
    const std::size_t room = static_cast<std::size_t>(
        s.max_frames - std::min<std::uint64_t>(s.max_frames, s.audio.frames()));
    s.append_to_utterance(s.frame.data(), std::min(s.frame_fill, room));
    s.finish_utterance(false, /*interrupted=*/true, result);
  } else {
    s.to_idle();
  }
  s.frame_fill = 0;
  s.frame_has_gap = false;
  s.silent_frames_in_row = 0;
  if (result.empty()) return std::nullopt;
  return std::move(result.front());
}

bool VoiceActivityDetector::in_speech() const { return state_->in_speech; }
double VoiceActivityDetector::noise_floor_dbfs() const { return state_->floor_db; }
std::uint64_t VoiceActivityDetector::position() const { return state_->position; }

}  // namespace icars::audio
