#include "icars/audio/resample.h"

#include <samplerate.h>

#include <cmath>
#include <string>

namespace icars::audio {
namespace {

void check_rate(int rate, const char* what) {
  if (rate < kMinSampleRate || rate > kMaxSampleRate) {
    throw AudioError(std::string(what) + " sample rate " + std::to_string(rate) +
                     " Hz is outside " + std::to_string(kMinSampleRate) + ".." +
                     std::to_string(kMaxSampleRate) + " Hz");
  }
}

// Interleaved float frames from `from` to `to` Hz; libsamplerate's one-shot interface flushes
// the filter at the end, so the output is the whole input (about frames * to / from frames).
std::vector<float> convert(const std::vector<float>& in, int channels, int from, int to) {
  const long frames = static_cast<long>(in.size()) / channels;
  if (frames == 0) return {};
  const double ratio = static_cast<double>(to) / from;
  std::vector<float> out(
      static_cast<std::size_t>(std::ceil(static_cast<double>(frames) * ratio) + 16) *
      static_cast<std::size_t>(channels));
  SRC_DATA data{};
  data.data_in = in.data();
  data.data_out = out.data();
  data.input_frames = frames;
  data.output_frames = static_cast<long>(out.size()) / channels;
  data.src_ratio = ratio;
  data.end_of_input = 1;
  if (const int error = src_simple(&data, SRC_SINC_BEST_QUALITY, channels); error != 0) {
    throw AudioError("resampling " + std::to_string(from) + " Hz to " + std::to_string(to) +
                     " Hz failed: " + src_strerror(error));
  }
  out.resize(static_cast<std::size_t>(data.output_frames_gen) * static_cast<std::size_t>(channels));
  return out;
}

}  // namespace

Signal resample(const Signal& in, int to_rate) {
  check_rate(in.sample_rate, "input");
  check_rate(to_rate, "output");
  if (in.sample_rate == to_rate) return in;
  return Signal{to_rate, convert(in.samples, 1, in.sample_rate, to_rate)};
}

AudioBlock resample(const AudioBlock& in, int to_rate) {
  check_rate(in.format.sample_rate, "input");
  check_rate(to_rate, "output");
  if (in.format.channels <= 0) {
    throw AudioError("cannot resample audio with " + std::to_string(in.format.channels) +
                     " channels");
  }
  if (in.format.sample_rate == to_rate) return in;
  std::vector<float> interleaved(in.samples.size());
  for (std::size_t i = 0; i < in.samples.size(); ++i) interleaved[i] = in.samples[i] / 32767.0f;
  const std::vector<float> converted =
      convert(interleaved, in.format.channels, in.format.sample_rate, to_rate);
  AudioBlock out;
  out.format = {to_rate, in.format.channels};
  // long double's 64-bit mantissa keeps any frame index exact.
  out.start = static_cast<std::uint64_t>(
      std::round(static_cast<long double>(in.start) * to_rate / in.format.sample_rate));
  out.samples.reserve(converted.size());
  for (const float v : converted) out.samples.push_back(to_pcm16(v));
  return out;
}

}  // namespace icars::audio
