#include "icars/home/microphone.h"

#include "icars/audio/audio_stream.h"
#include "icars/clock/activity.h"
#include "icars/planet/error.h"
#include "icars/planet/stream.h"

namespace icars::home {

namespace p = icars::planet;

struct CaptureStreams::Reader {
  std::shared_ptr<p::OutputStream> out;
  struct Chunk {
    std::vector<std::byte> bytes;
    std::uint64_t frames = 0;  // audio frames (one sample of every channel) in it
  };
  std::deque<Chunk> queue;
  std::size_t queued_bytes = 0;
  bool writing = false;
  bool failed = false;
  bool closing = false;  // close once the queue is written
  // While audio waits here (not yet a PLANET message), a lock-step clock must not move on: the
  // sound would reach its reader after the time it was heard.
  Activity::Hold busy;
};

CaptureStreams::CaptureStreams(p::Communicator& communicator, std::chrono::milliseconds max_behind,
                               std::chrono::milliseconds history)
    : communicator_(communicator), max_behind_(max_behind), history_span_(history) {}

CaptureStreams::~CaptureStreams() {
  std::vector<std::shared_ptr<Reader>> readers;
  {
    std::lock_guard lock(mutex_);
    readers.swap(readers_);
  }
  for (const auto& r : readers) r->out->close();
}

void CaptureStreams::close_all() {
  std::vector<std::shared_ptr<Reader>> readers;
  {
    std::lock_guard lock(mutex_);
    readers = readers_;
  }
  // Each stream ends once its writer has sent what is queued: closing now would cut it short.
  for (const auto& r : readers) {
    std::lock_guard lock(mutex_);
    r->closing = true;
    if (!r->writing) r->out->close();
  }
}

p::StreamRef CaptureStreams::open(std::uint64_t since) {
  auto reader = std::make_shared<Reader>();
  reader->out = p::OutputStream::create(communicator_);
  std::vector<std::shared_ptr<Reader>> start;
  {
    std::lock_guard lock(mutex_);
    for (const auto& sent : history_) {
      if (sent.end <= since) continue;
      reader->queue.push_back({sent.bytes, sent.end - sent.start});
      reader->queued_bytes += sent.bytes.size();
    }
    readers_.push_back(reader);
    listened_to_ = true;
    if (!reader->queue.empty()) {
      reader->writing = true;
      reader->busy = Activity::Hold(communicator_.activity().get());
      start.push_back(reader);
    }
  }
  const auto ref = reader->out->ref();
  for (const auto& r : start) write_next(r);
  return ref;
}

std::size_t CaptureStreams::readers() const {
  std::lock_guard lock(mutex_);
  return readers_.size();
}

void CaptureStreams::push(const audio::AudioBlock& block) {
  if (block.frames() == 0) return;
  std::vector<std::byte> bytes;
  audio::encode_frames(block, bytes);
  const std::size_t limit = static_cast<std::size_t>(max_behind_.count()) * static_cast<std::size_t>(block.format.sample_rate) /
                            1000 * 2 * static_cast<std::size_t>(block.format.channels);
  std::vector<std::shared_ptr<Reader>> start;
  {
    std::lock_guard lock(mutex_);
    // What a reader that comes back may ask for again: the last history_span_ of audio.
    history_.push_back({bytes, block.start, block.end()});
    history_frames_ += block.frames();
    const auto keep = static_cast<std::uint64_t>(history_span_.count()) * static_cast<std::uint64_t>(block.format.sample_rate) / 1000;
    while (history_.size() > 1 && history_frames_ - (history_.front().end - history_.front().start) >= keep) {
      history_frames_ -= history_.front().end - history_.front().start;
      history_.pop_front();
    }
    for (const auto& r : readers_) {
      r->queue.push_back({bytes, block.frames()});
      r->queued_bytes += bytes.size();
      // Too far behind: the oldest audio goes (never the chunk being written).
      while (r->queued_bytes > limit && r->queue.size() > (r->writing ? 2u : 1u)) {
        auto victim = r->writing ? std::next(r->queue.begin()) : r->queue.begin();
        r->queued_bytes -= victim->bytes.size();
        dropped_ += victim->frames;
        r->queue.erase(victim);
      }
      if (!r->writing) {
        r->writing = true;
        r->busy = Activity::Hold(communicator_.activity().get());
        start.push_back(r);
      }
    }
  }
  for (const auto& r : start) write_next(r);
}

void CaptureStreams::write_next(const std::shared_ptr<Reader>& reader) {
  std::vector<std::byte> chunk;
  {
    std::lock_guard lock(mutex_);
    if (reader->queue.empty() || reader->failed) {
      reader->writing = false;
      reader->busy.release();
      if (reader->closing && !reader->failed) reader->out->close();
      return;
    }
    chunk = reader->queue.front().bytes;
  }
  reader->out->async_write(std::move(chunk), [this, weak = std::weak_ptr<Reader>(reader)](std::exception_ptr e) {
    auto r = weak.lock();
    if (!r) return;
    {
      std::lock_guard lock(mutex_);
      if (e) {
        // The reader cancelled or went away: forget it.
        r->failed = true;
        r->queue.clear();
        r->writing = false;
        r->busy.release();
        std::erase(readers_, r);  // NOLINT: by value
        return;
      }
      if (!r->queue.empty()) {
        r->queued_bytes -= r->queue.front().bytes.size();
        r->queue.pop_front();
      }
    }
    write_next(r);
  });
}

MicrophoneInfo microphone_info(const audio::AudioFormat& format, const std::vector<audio::MicPosition>& mics,
                               double threshold_db, std::string source) {
  MicrophoneInfo info;
  info.sample_rate = format.sample_rate;
  info.channels = format.channels;
  for (const auto& m : mics) {
    info.mic_x.push_back(m.x);
    info.mic_y.push_back(m.y);
  }
  info.threshold_db = threshold_db;
  info.source = std::move(source);
  return info;
}

// --- SourceMicrophone ------------------------------------------------------------------------

SourceMicrophone::SourceMicrophone(std::unique_ptr<audio::AudioSource> source, std::string spec, const icars::Clock& clock,
                                   p::Communicator& communicator, std::vector<audio::MicPosition> mics,
                                   double threshold_db)
    : source_(std::move(source)), spec_(std::move(spec)), clock_(clock), mics_(std::move(mics)),
      threshold_db_(threshold_db), captures_(communicator) {
  if (mics_.empty() && source_->format().channels == 1) mics_.push_back({0, 0});
  if (mics_.size() != static_cast<std::size_t>(source_->format().channels)) {
    throw std::invalid_argument(spec_ + " has " + std::to_string(source_->format().channels) + " channels but " +
                                std::to_string(mics_.size()) + " microphone positions were given");
  }
}

SourceMicrophone::~SourceMicrophone() {
  source_->stop();
  if (thread_.joinable()) thread_.join();
}

void SourceMicrophone::start() {
  std::call_once(started_, [this] { thread_ = std::thread([this] { run(); }); });
}

MicrophoneInfo SourceMicrophone::info(const p::Current&) {
  return microphone_info(source_->format(), mics_, threshold_db_, spec_);
}

p::StreamRef SourceMicrophone::capture(std::int64_t since, const p::Current&) {
  if (ended_) {
    const auto why = error();
    throw p::Error(p::ErrorKind::failed, "the microphone's source " + spec_ + " ended" + (why.empty() ? "" : ": " + why));
  }
  return captures_.open(static_cast<std::uint64_t>(std::max<std::int64_t>(0, since)));
}

std::string SourceMicrophone::error() const {
  std::lock_guard lock(mutex_);
  return error_;
}

void SourceMicrophone::run() {
  const auto rate = static_cast<std::uint64_t>(source_->format().sample_rate);
  const std::uint64_t base = static_cast<std::uint64_t>(clock_.now().count()) * rate / 1000;
  while (auto block = source_->read()) {
    block->start += base;
    ++frames_;
    captures_.push(*block);
  }
  {
    std::lock_guard lock(mutex_);
    error_ = source_->error();
  }
  ended_ = true;
  captures_.close_all();
}

}  // namespace icars::home
