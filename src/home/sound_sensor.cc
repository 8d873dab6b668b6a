#include "icars/home/sound_sensor.h"

#include <spdlog/spdlog.h>

#include <asio/steady_timer.hpp>
#include <chrono>
#include <cstring>

#include "icars/audio/audio_stream.h"
#include "icars/audio/acoustics.h"
#include "icars/planet/stream.h"

namespace icars::home {

namespace p = icars::planet;

struct SoundSensor::Capture {
  std::uint64_t generation = 0;
  std::shared_ptr<p::InputStream> in;
  audio::AudioStreamDecoder decoder;
  std::unique_ptr<audio::VoiceActivityDetector> vad;
  int sample_rate = audio::kSpeechRate;
  bool ended = false;
};

namespace {

// A reopened capture waits after one that broke, twice as long each time it broke without a
// frame in between (up to kMaxReopenDelay), so a device that refuses every capture (a source
// that ended) is not asked in a tight loop.
constexpr std::chrono::milliseconds kReopenDelay{500};
constexpr std::chrono::milliseconds kMaxReopenDelay{30000};

audio::VadOptions vad_options(const MicrophoneInfo& info) {
  audio::VadOptions o;
  o.min_level_dbfs = info.threshold_db - audio::kFullScaleSpl;
  return o;
}

std::int64_t to_ms(std::uint64_t frame, int rate) {
  return static_cast<std::int64_t>(frame * 1000 / static_cast<std::uint64_t>(rate));
}

}  // namespace

SoundSensor::SoundSensor(const df::DeviceInfo& d, const df::CapabilityInfo& c) : AdaptorOf("SoundSensor", d, c) {}

SoundSensor::~SoundSensor() { stop_capture(); }

std::optional<MicrophoneInfo> SoundSensor::info() const {
  std::lock_guard lock(mutex_);
  return info_;
}

Activity::Hold SoundSensor::hold_work() const {
  std::lock_guard lock(mutex_);
  return Activity::Hold(communicator_ ? communicator_->activity().get() : nullptr);
}

SoundSensor::Stats SoundSensor::stats() const {
  std::lock_guard lock(mutex_);
  return stats_;
}

void SoundSensor::on_bind(p::Communicator& communicator, const std::shared_ptr<p::Link>& link) {
  AdaptorOf::on_bind(communicator, link);
  std::uint64_t generation = 0;
  {
    std::lock_guard lock(mutex_);
    communicator_ = &communicator;
    link_ = link;
    generation = ++generation_;
  }
  stop_capture();
  start_capture(generation);
}

void SoundSensor::on_unbind() {
  {
    std::lock_guard lock(mutex_);
    ++generation_;
    link_.reset();
  }
  stop_capture();
}

void SoundSensor::on_removed() { on_unbind(); }

void SoundSensor::stop_capture() {
  std::shared_ptr<Capture> capture;
  {
    std::lock_guard lock(mutex_);
    capture = std::move(capture_);
  }
  if (capture && capture->in && !capture->ended) capture->in->cancel("the sound sensor stopped listening");
}

void SoundSensor::start_capture(std::uint64_t generation) {
  auto weak = std::weak_ptr<SoundSensor>(std::static_pointer_cast<SoundSensor>(shared_from_this()));
  proxy().info_async([weak, generation](std::exception_ptr e, MicrophoneInfo info) {
    auto self = weak.lock();
    if (!self) return;
    if (e) {
      std::lock_guard lock(self->mutex_);
      if (generation != self->generation_) return;
      ++self->stats_.broken;
      self->stats_.last_error = "info: " + p::describe(e);
      if (self->communicator_) self->log_failure(*self->communicator_, "could not read its microphone's format", e);
      return;
    }
    if (info.sample_rate < 8000 || info.sample_rate > 192000 || info.channels < 1 || info.channels > 16) {
      std::lock_guard lock(self->mutex_);
      ++self->stats_.broken;
      self->stats_.last_error = "the microphone reports an unusable format";
      return;
    }
    {
      std::lock_guard lock(self->mutex_);
      if (generation != self->generation_) return;
      self->info_ = info;
    }
    std::uint64_t since = 0;
    {
      std::lock_guard lock(self->mutex_);
      since = self->resume_from_;
    }
    self->proxy().capture_async(static_cast<std::int64_t>(since), [weak, generation, info](std::exception_ptr failed, std::shared_ptr<p::InputStream> in) {
      auto sensor = weak.lock();
      if (!sensor) return;
      auto capture = std::make_shared<Capture>();
      capture->generation = generation;
      capture->sample_rate = info.sample_rate;
      capture->vad = std::make_unique<audio::VoiceActivityDetector>(vad_options(info));
      capture->in = std::move(in);
      {
        std::lock_guard lock(sensor->mutex_);
        if (generation != sensor->generation_) {
          if (capture->in) capture->in->cancel("the sound sensor was rebound");
          return;
        }
        if (!failed) {
          sensor->capture_ = capture;
          ++sensor->stats_.captures;
        }
      }
      if (failed) return sensor->capture_ended(capture, "capture: " + p::describe(failed));
      sensor->read_next(capture);
    });
  });
}

void SoundSensor::read_next(const std::shared_ptr<Capture>& capture) {
  auto weak = std::weak_ptr<SoundSensor>(std::static_pointer_cast<SoundSensor>(shared_from_this()));
  capture->in->async_read([weak, capture](std::exception_ptr e, std::vector<std::byte> bytes) {
    auto self = weak.lock();
    if (!self) return;
    if (e) return self->capture_ended(capture, p::describe(e));
    if (bytes.empty()) return self->capture_ended(capture, "the microphone ended the capture");
    std::vector<audio::Utterance> sounds;
    std::size_t frames = 0;
    try {
      for (const auto& block : capture->decoder.feed(bytes)) {
        ++frames;
        if (!self->resume_at(block)) continue;  // heard already, before the capture broke
        auto ended = capture->vad->feed(block);
        for (auto& u : ended) sounds.push_back(std::move(u));
      }
    } catch (const audio::AudioError& bad) {
      for (const auto& u : sounds) self->publish(u, *capture);
      capture->in->cancel(std::string("malformed audio: ") + bad.what());
      return self->capture_ended(capture, std::string("malformed audio: ") + bad.what());
    }
    {
      std::lock_guard lock(self->mutex_);
      self->stats_.frames += frames;
      if (frames > 0) self->reopen_delay_ = kReopenDelay;
    }
    for (const auto& u : sounds) self->publish(u, *capture);
    self->read_next(capture);
  });
}

bool SoundSensor::resume_at(const audio::AudioBlock& block) {
  std::lock_guard lock(mutex_);
  const auto window = static_cast<std::uint64_t>(block.format.sample_rate) * 120;  // beyond any replay
  if (block.end() <= resume_from_ && block.end() + window > resume_from_) return false;
  // A frame far behind the last one is a new timeline (a device that restarted with its clock
  // behind): take it from there.
  resume_from_ = block.end();
  return true;
}

void SoundSensor::capture_ended(const std::shared_ptr<Capture>& capture, const std::string& error) {
  if (capture->ended) return;
  capture->ended = true;
  if (auto rest = capture->vad->flush()) publish(*rest, *capture);
  p::Communicator* communicator = nullptr;
  bool again = false;
  std::chrono::milliseconds delay{};
  {
    std::lock_guard lock(mutex_);
    delay = reopen_delay_;
    reopen_delay_ = std::min(kMaxReopenDelay, reopen_delay_ * 2);
    ++stats_.broken;
    stats_.last_error = error;
    if (capture_ == capture) capture_.reset();
    again = capture->generation == generation_ && link_ != nullptr;
    communicator = communicator_;
  }
  if (!communicator) return;
  if (again) {
    communicator->log().warn("service {}: the capture broke ({}); opening it again in {} ms", id(), error,
                             delay.count());
  }
  if (!again) return;
  auto timer = std::make_shared<asio::steady_timer>(communicator->executor(), delay);
  auto weak = std::weak_ptr<SoundSensor>(std::static_pointer_cast<SoundSensor>(shared_from_this()));
  timer->async_wait([weak, timer, generation = capture->generation](std::error_code ec) {
    auto self = weak.lock();
    if (ec || !self) return;
    {
      std::lock_guard lock(self->mutex_);
      if (generation != self->generation_ || !self->link_) return;
    }
    self->start_capture(generation);
  });
}

void SoundSensor::publish(const audio::Utterance& u, const Capture& capture) {
  SoundEvent e;
  e.device = attributes().device;
  e.room = attributes().room;
  e.level_db = u.level_dbfs + audio::kFullScaleSpl;
  e.time_ms = to_ms(u.audio.start, capture.sample_rate);
  e.end_ms = to_ms(u.speech_end, capture.sample_rate);
  e.sample_rate = u.audio.format.sample_rate;
  e.channels = u.audio.format.channels;
  e.clipped = u.clipped > 0;
  e.interrupted = u.interrupted;
  e.audio.bytes = audio::pcm_bytes(u.audio.samples);
  {
    std::lock_guard lock(mutex_);
    ++stats_.sounds;
    if (u.interrupted) ++stats_.interrupted;
  }
  events_.notify(e);
}

audio::AudioBlock audio_of(const SoundEvent& e) {
  if (e.channels < 1 || e.sample_rate <= 0 || e.audio.bytes.size() % (2 * static_cast<std::size_t>(e.channels)) != 0) {
    throw audio::AudioError("a sound of " + std::to_string(e.audio.bytes.size()) + " bytes does not hold " +
                            std::to_string(e.channels) + "-channel 16-bit audio");
  }
  audio::AudioBlock block;
  block.format = {e.sample_rate, e.channels};
  block.samples = audio::pcm_samples(e.audio.bytes);
  return block;
}

std::optional<audio::DirectionEstimate> locate_sound(const SoundEvent& e, const MicrophoneInfo& info) {
  if (e.channels < 2 || info.channels != e.channels || info.mic_x.size() != static_cast<std::size_t>(e.channels) ||
      info.mic_y.size() != info.mic_x.size()) {
    return std::nullopt;
  }
  std::vector<audio::MicPosition> mics;
  for (std::size_t i = 0; i < info.mic_x.size(); ++i) mics.push_back({info.mic_x[i], info.mic_y[i]});
  try {
    return audio::estimate_direction(audio_of(e), mics);
  } catch (const audio::AudioError&) {
    return std::nullopt;
  }
}

}  // namespace icars::home
