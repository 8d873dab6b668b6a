#include "icars/audio/source.h"

#include <alsa/asoundlib.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <system_error>
#include <vector>

#include "icars/audio/audio_stream.h"
#include "icars/audio/resample.h"
#include "icars/audio/wav.h"

namespace icars::audio {
namespace {

using Clock = std::chrono::steady_clock;

// errno as words, thread-safely (strerror is not).
std::string errno_text() { return std::generic_category().message(errno); }

std::size_t period_frames(const AudioFormat& format) {
  return std::max<std::size_t>(1, static_cast<std::size_t>(format.sample_rate) * kFrameMs / 1000);
}

// What stop() raises: a condition variable for timed waits and an eventfd for poll().
class StopSignal {
 public:
  StopSignal() : fd_(::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK)) {
    if (fd_ < 0) throw AudioError(fmt::format("audio source: eventfd: {}", errno_text()));
  }
  ~StopSignal() { ::close(fd_); }
  StopSignal(const StopSignal&) = delete;
  StopSignal& operator=(const StopSignal&) = delete;

  void raise() {
    {
      std::lock_guard lock(mutex_);
      stopped_ = true;
    }
    condition_.notify_all();
    const std::uint64_t one = 1;
    [[maybe_unused]] const auto n = ::write(fd_, &one, sizeof one);  // full only if raised before
  }
  bool raised() const {
    std::lock_guard lock(mutex_);
    return stopped_;
  }
  // Sleeps until `deadline`; false if stop() came first.
  bool sleep_until(Clock::time_point deadline) {
    std::unique_lock lock(mutex_);
    return !condition_.wait_until(lock, deadline, [this] { return stopped_; });
  }
  int fd() const { return fd_; }

 private:
  int fd_;
  mutable std::mutex mutex_;
  std::condition_variable condition_;
  bool stopped_ = false;
};

// Files and pipes at the pace of their sample rate: a period is delivered no earlier than its
// last frame would have been captured, counting from the first read (no drift: the deadline
// comes from the frame count, not from the previous wake-up).
class Pacer {
 public:
  Pacer(bool real_time, int sample_rate) : real_time_(real_time), sample_rate_(sample_rate) {}
  // Waits for `frames` more frames' time; false if stopped.
  bool wait(std::size_t frames, StopSignal& stop) {
    if (!real_time_) return !stop.raised();
    const auto now = Clock::now();
    if (!started_) {
      started_ = true;
      origin_ = now;
    }
    delivered_ += frames;
    const auto deadline =
        origin_ + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(
                      static_cast<double>(delivered_) / sample_rate_));
    return stop.sleep_until(deadline);
  }

 private:
  bool real_time_;
  int sample_rate_;
  bool started_ = false;
  Clock::time_point origin_;
  std::uint64_t delivered_ = 0;
};

// What every source has: the stop signal and the error.
class SourceBase : public AudioSource {
 public:
  std::string error() const override {
    std::lock_guard lock(error_mutex_);
    return error_;
  }
  void stop() override { stop_.raise(); }

 protected:
  std::optional<AudioBlock> fail(std::string why) {
    std::lock_guard lock(error_mutex_);
    error_ = std::move(why);
    return std::nullopt;
  }

  StopSignal stop_;

 private:
  mutable std::mutex error_mutex_;
  std::string error_;
};

// A WAV file, read whole (read_wav), delivered in periods; looping wraps within a period.
class WavSource final : public SourceBase {
 public:
  WavSource(AudioBlock audio, const SourceOptions& options)
      : audio_(std::move(audio)),
        loop_(options.loop),
        period_(period_frames(audio_.format)),
        pacer_(options.real_time, audio_.format.sample_rate) {}

  AudioFormat format() const override { return audio_.format; }

  std::optional<AudioBlock> read() override {
    if (stop_.raised()) return std::nullopt;
    const std::size_t total = audio_.frames();
    const auto channels = static_cast<std::size_t>(audio_.format.channels);
    AudioBlock block;
    block.format = audio_.format;
    block.start = next_start_;
    while (block.frames() < period_) {
      if (cursor_ == total) {
        if (!loop_ || total == 0) break;
        cursor_ = 0;
      }
      const std::size_t n = std::min(period_ - block.frames(), total - cursor_);
      const auto first = audio_.samples.begin() + static_cast<std::ptrdiff_t>(cursor_ * channels);
      block.samples.insert(block.samples.end(), first,
                           first + static_cast<std::ptrdiff_t>(n * channels));
      cursor_ += n;
    }
    if (block.frames() == 0) return std::nullopt;  // the end: error() stays ""
    if (!pacer_.wait(block.frames(), stop_)) return std::nullopt;
    next_start_ = block.end();
    return block;
  }

 private:
  AudioBlock audio_;
  bool loop_;
  std::size_t period_;
  Pacer pacer_;
  std::size_t cursor_ = 0;
  std::uint64_t next_start_ = 0;
};

// Raw interleaved 16-bit little-endian PCM from a file, a named pipe or stdin. A pipe is opened
// without waiting for its writer; reads wait in poll() beside the stop signal.
class RawSource final : public SourceBase {
 public:
  RawSource(std::string spec, int fd, bool owned, bool seekable, const SourceOptions& options)
      : spec_(std::move(spec)),
        fd_(fd),
        owned_(owned),
        loop_(options.loop && seekable),
        format_(options.format),
        period_(period_frames(options.format)),
        frame_bytes_(static_cast<std::size_t>(options.format.channels) * 2),
        pacer_(options.real_time, options.format.sample_rate) {}
  ~RawSource() override {
    if (owned_) ::close(fd_);
  }

  AudioFormat format() const override { return format_; }

  std::optional<AudioBlock> read() override {
    if (ended_ || stop_.raised()) return std::nullopt;
    const std::size_t want = period_ * frame_bytes_;
    while (bytes_.size() < want) {
      const auto got = read_some(want - bytes_.size());
      if (!got) return std::nullopt;  // stopped or failed
      if (*got > 0) {
        bytes_since_rewind_ += *got;
        continue;
      }
      // End of file: start again (a file that had frames; a partial frame at its end is
      // dropped, so that frames stay aligned), or deliver what is left.
      if (loop_ && bytes_since_rewind_ >= frame_bytes_ && ::lseek(fd_, 0, SEEK_SET) == 0) {
        bytes_.resize(bytes_.size() - bytes_since_rewind_ % frame_bytes_);
        bytes_since_rewind_ = 0;
        continue;
      }
      ended_ = true;
      break;
    }
    const std::size_t frames = std::min(period_, bytes_.size() / frame_bytes_);
    if (frames == 0) return std::nullopt;  // a trailing partial frame cannot be delivered
    AudioBlock block;
    block.format = format_;
    block.start = next_start_;
    block.samples.resize(frames * static_cast<std::size_t>(format_.channels));
    for (std::size_t i = 0; i < block.samples.size(); ++i) {
      const auto lo = static_cast<unsigned>(bytes_[2 * i]);
      const auto hi = static_cast<unsigned>(bytes_[2 * i + 1]);
      block.samples[i] = static_cast<std::int16_t>(static_cast<std::uint16_t>(lo | (hi << 8)));
    }
    bytes_.erase(bytes_.begin(),
                 bytes_.begin() + static_cast<std::ptrdiff_t>(frames * frame_bytes_));
    if (!pacer_.wait(frames, stop_)) return std::nullopt;
    next_start_ = block.end();
    return block;
  }

 private:
  // Up to `max` bytes appended to bytes_: their count (0 at the end of the file or pipe), or
  // nullopt when stopped or on an error (set).
  std::optional<std::size_t> read_some(std::size_t max) {
    for (;;) {
      pollfd fds[2] = {{fd_, POLLIN, 0}, {stop_.fd(), POLLIN, 0}};
      if (::poll(fds, 2, -1) < 0) {
        if (errno == EINTR) continue;
        fail(fmt::format("{}: poll: {}", spec_, errno_text()));
        return std::nullopt;
      }
      if (fds[1].revents != 0) return std::nullopt;
      if (fds[0].revents == 0) continue;
      const std::size_t old = bytes_.size();
      bytes_.resize(old + max);
      const ssize_t n = ::read(fd_, bytes_.data() + old, max);
      const int read_errno = errno;
      bytes_.resize(old + static_cast<std::size_t>(std::max<ssize_t>(n, 0)));
      if (n >= 0) return static_cast<std::size_t>(n);
      if (read_errno == EAGAIN || read_errno == EINTR) continue;
      fail(fmt::format("{}: read: {}", spec_, std::generic_category().message(read_errno)));
      return std::nullopt;
    }
  }

  std::string spec_;
  int fd_;
  bool owned_;
  bool loop_;
  AudioFormat format_;
  std::size_t period_;
  std::size_t frame_bytes_;
  Pacer pacer_;
  std::vector<unsigned char> bytes_;
  std::size_t bytes_since_rewind_ = 0;
  bool ended_ = false;
  std::uint64_t next_start_ = 0;
};

// A sound card through ALSA: S16_LE interleaved capture in periods of kFrameMs, non-blocking
// reads waiting in poll() beside the stop signal. An overrun (the reader fell behind and the
// card's buffer filled) loses what the card captured since the last read: the timeline skips
// it, so the next block starts after a gap, and overruns() counts the periods lost.
class AlsaSource final : public SourceBase {
 public:
  AlsaSource(const std::string& spec, std::string device, const AudioFormat& format)
      : device_(std::move(device)), format_(format), period_(period_frames(format)) {
    int err = snd_pcm_open(&pcm_, device_.c_str(), SND_PCM_STREAM_CAPTURE, SND_PCM_NONBLOCK);
    if (err < 0) {
      pcm_ = nullptr;
      throw AudioError(fmt::format(
          "audio source \"{}\": cannot open ALSA capture device \"{}\": {} (arecord -L lists "
          "the devices)",
          spec, device_, snd_strerror(err)));
    }
    constexpr unsigned kLatencyUs = 200000;  // the card's buffer: ten periods
    err = snd_pcm_set_params(pcm_, SND_PCM_FORMAT_S16_LE, SND_PCM_ACCESS_RW_INTERLEAVED,
                             static_cast<unsigned>(format_.channels),
                             static_cast<unsigned>(format_.sample_rate), /*soft_resample=*/1,
                             kLatencyUs);
    if (err < 0) {
      snd_pcm_close(pcm_);
      pcm_ = nullptr;
      const bool raw_hardware = device_.starts_with("hw:");
      throw AudioError(fmt::format(
          "audio source \"{}\": ALSA capture device \"{}\" refuses 16-bit {} Hz, {} channel(s): "
          "{} ({})",
          spec, device_, format_.sample_rate, format_.channels, snd_strerror(err),
          raw_hardware ? "alsa:plug" + device_ + " converts what the card lacks"
                       : std::string("try another rate or channel count")));
    }
    buffer_.resize(period_ * static_cast<std::size_t>(format_.channels));
  }
  ~AlsaSource() override {
    if (pcm_ != nullptr) snd_pcm_close(pcm_);
  }

  AudioFormat format() const override { return format_; }
  std::uint64_t overruns() const override { return overruns_.load(); }

  std::optional<AudioBlock> read() override {
    if (stop_.raised() || failed_) return std::nullopt;
    if (!running_) {
      if (const int err = snd_pcm_start(pcm_); err < 0) return device_error("start", err);
      running_ = true;
      last_data_ = Clock::now();
    }
    const auto channels = static_cast<std::size_t>(format_.channels);
    std::size_t filled = 0;
    while (filled < period_) {
      const snd_pcm_sframes_t n =
          snd_pcm_readi(pcm_, buffer_.data() + filled * channels, period_ - filled);
      if (n > 0) {
        filled += static_cast<std::size_t>(n);
        last_data_ = Clock::now();
      } else if (n == -EAGAIN || n == 0) {
        if (!wait_readable()) return std::nullopt;
      } else if (n == -EPIPE) {
        overrun(filled);
        filled = 0;
      } else if (n == -ESTRPIPE) {  // suspended (the machine slept): resume or start again
        int err;
        while ((err = snd_pcm_resume(pcm_)) == -EAGAIN) {
          if (!stop_.sleep_until(Clock::now() + std::chrono::milliseconds(50))) return std::nullopt;
        }
        if (err < 0 && (err = snd_pcm_prepare(pcm_)) < 0) return device_error("resume", err);
        if (err = snd_pcm_start(pcm_); err < 0) return device_error("start", err);
        overrun(filled);
        filled = 0;
      } else {  // -ENODEV (unplugged), -EBADFD, ...
        return device_error("read", static_cast<int>(n));
      }
    }
    AudioBlock block;
    block.format = format_;
    block.start = next_start_;
    block.samples = buffer_;
    next_start_ = block.end();
    return block;
  }

 private:
  // Waits until the card has data; false when stopped or on an error (set).
  bool wait_readable() {
    const int count = snd_pcm_poll_descriptors_count(pcm_);
    if (count <= 0) {
      device_error("poll descriptors", count < 0 ? count : -EINVAL);
      return false;
    }
    std::vector<pollfd> fds(static_cast<std::size_t>(count) + 1);
    snd_pcm_poll_descriptors(pcm_, fds.data(), static_cast<unsigned>(count));
    fds.back() = {stop_.fd(), POLLIN, 0};
    constexpr int kSilentMs = 2000;  // a card that delivers nothing this long has gone
    for (;;) {
      const int ready = ::poll(fds.data(), fds.size(), kSilentMs);
      if (ready < 0 && errno == EINTR) continue;
      if (ready < 0) {
        device_error("poll", -errno);
        return false;
      }
      if (ready == 0) {
        failed_ = true;
        fail(fmt::format("ALSA capture device \"{}\" delivered nothing for {} ms", device_,
                         kSilentMs));
        return false;
      }
      if (fds.back().revents != 0) return false;
      unsigned short revents = 0;
      snd_pcm_poll_descriptors_revents(pcm_, fds.data(), static_cast<unsigned>(count), &revents);
      if (revents & (POLLIN | POLLERR)) return true;  // data, or an error readi will report
    }
  }

  // The card overran: what it captured since the last read is gone. The timeline skips it in
  // whole periods; capture starts again.
  void overrun(std::size_t partial) {
    const double elapsed = std::chrono::duration<double>(Clock::now() - last_data_).count();
    const auto lost_frames = static_cast<double>(partial) + elapsed * format_.sample_rate;
    const auto periods = std::max<std::uint64_t>(
        1, static_cast<std::uint64_t>(std::llround(lost_frames / static_cast<double>(period_))));
    overruns_ += periods;
    next_start_ += periods * period_;
    snd_pcm_prepare(pcm_);
    snd_pcm_start(pcm_);
    last_data_ = Clock::now();
  }

  std::optional<AudioBlock> device_error(const char* what, int err) {
    failed_ = true;
    return fail(
        fmt::format("ALSA capture device \"{}\": {}: {}", device_, what, snd_strerror(err)));
  }

  std::string device_;
  AudioFormat format_;
  std::size_t period_;
  snd_pcm_t* pcm_ = nullptr;
  std::vector<std::int16_t> buffer_;
  bool running_ = false;
  bool failed_ = false;
  Clock::time_point last_data_;
  std::atomic<std::uint64_t> overruns_{0};
  std::uint64_t next_start_ = 0;
};

std::unique_ptr<AudioSource> open_raw(const std::string& spec, const std::string& path,
                                      const SourceOptions& options) {
  if (path == "-") return std::make_unique<RawSource>(spec, STDIN_FILENO, false, false, options);
  // O_NONBLOCK: a named pipe opens at once instead of waiting here for its writer.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    throw AudioError(
        fmt::format("audio source \"{}\": cannot open {}: {}", spec, path, errno_text()));
  }
  struct stat info {};
  if (::fstat(fd, &info) != 0 || S_ISDIR(info.st_mode)) {
    ::close(fd);
    throw AudioError(fmt::format("audio source \"{}\": {} is a directory", spec, path));
  }
  return std::make_unique<RawSource>(spec, fd, true, S_ISREG(info.st_mode), options);
}

std::unique_ptr<AudioSource> open_wav(const std::string& spec, const std::string& path,
                                      const SourceOptions& options) {
  AudioBlock audio;
  try {
    audio = read_wav(path);
  } catch (const std::exception& e) {
    throw AudioError(fmt::format("audio source \"{}\": {}", spec, e.what()));
  }
  audio.start = 0;
  return std::make_unique<WavSource>(std::move(audio), options);
}

}  // namespace

std::unique_ptr<AudioSource> open_source(const std::string& spec, SourceOptions options) {
  const auto colon = spec.find(':');
  const std::string scheme = colon == std::string::npos ? std::string() : spec.substr(0, colon);
  const std::string rest = colon == std::string::npos ? std::string() : spec.substr(colon + 1);
  if (scheme != "alsa" && scheme != "wav" && scheme != "raw") {
    throw AudioError(fmt::format(
        "audio source \"{}\": unknown kind (use alsa:NAME, wav:PATH or raw:PATH)", spec));
  }
  if (rest.empty()) {
    throw AudioError(fmt::format("audio source \"{}\": no {} after \"{}:\"", spec,
                                 scheme == "alsa" ? "device name" : "path", scheme));
  }
  const AudioFormat& f = options.format;
  if (f.channels < 1 || f.channels > kMaxChannels || f.sample_rate < kMinSampleRate ||
      f.sample_rate > kMaxSampleRate) {
    throw AudioError(fmt::format(
        "audio source \"{}\": format of {} channels at {} Hz (1..{} channels, {}..{} Hz)", spec,
        f.channels, f.sample_rate, kMaxChannels, kMinSampleRate, kMaxSampleRate));
  }
  if (scheme == "alsa") return std::make_unique<AlsaSource>(spec, rest, options.format);
  if (scheme == "wav") return open_wav(spec, rest, options);
  return open_raw(spec, rest, options);
}

}  // namespace icars::audio
