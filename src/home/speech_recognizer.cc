#include "icars/home/speech_recognizer.h"

#include <fmt/format.h>

#include <asio/co_spawn.hpp>
#include <asio/use_awaitable.hpp>

#include "icars/clock/activity.h"
#include "icars/planet/communicator.h"
#include "icars/planet/error.h"

namespace icars::home {

SpeechRecognizerDevice::SpeechRecognizerDevice(audio::RecognizerOptions options, int decoders)
    : options_(std::move(options)), unmade_(std::max(1, decoders)),
      workers_(static_cast<std::size_t>(std::max(1, decoders))) {
  // recognize() as a coroutine: the decoding runs on the workers and the answer goes back from
  // the io thread, which meanwhile serves every other call of this process. (A bare
  // `co_await asio::post(workers_, use_awaitable)` would not move it: a coroutine resumes on its
  // own executor, so the decoding would block the io thread. co_spawn runs the inner coroutine
  // on the workers and resumes this one on the io thread with its result or exception.)
  implement(home::SpeechRecognizer::recognize,
            [this](planet::Binary audio, std::int32_t sample_rate, std::int32_t channels,
                   std::vector<std::string> phrases, const planet::Current& current) -> asio::awaitable<home::Recognition> {
              Activity::Hold busy(current.communicator ? current.communicator->activity().get() : nullptr);
              // A capture-less coroutine: its arguments live in its own frame, on the workers.
              const auto on_worker = [](SpeechRecognizerDevice* self, planet::Binary pcm, std::int32_t rate,
                                        std::int32_t count, std::vector<std::string> wanted)
                  -> asio::awaitable<home::Recognition> { co_return self->decode(pcm, rate, count, wanted); };
              co_return co_await asio::co_spawn(
                  workers_, on_worker(this, std::move(audio), sample_rate, channels, std::move(phrases)),
                  asio::use_awaitable);
            });
}

SpeechRecognizerDevice::~SpeechRecognizerDevice() { workers_.join(); }

std::unique_ptr<audio::Recognizer> SpeechRecognizerDevice::take() {
  std::unique_lock lock(mutex_);
  if (idle_.empty() && unmade_ > 0) {
    --unmade_;  // a decoder loads its model on first use: a house that never hears speech pays nothing
    lock.unlock();
    try {
      return std::make_unique<audio::Recognizer>(options_);
    } catch (...) {
      std::lock_guard again(mutex_);
      ++unmade_;
      throw;
    }
  }
  returned_.wait(lock, [this] { return !idle_.empty(); });
  auto r = std::move(idle_.back());
  idle_.pop_back();
  return r;
}

void SpeechRecognizerDevice::give_back(std::unique_ptr<audio::Recognizer> r) {
  {
    std::lock_guard lock(mutex_);
    idle_.push_back(std::move(r));
  }
  returned_.notify_one();
}

home::Recognition SpeechRecognizerDevice::recognize(const planet::Binary& audio, std::int32_t sample_rate,
                                                    std::int32_t channels, const std::vector<std::string>& phrases,
                                                    const planet::Current&) {
  return decode(audio, sample_rate, channels, phrases);
}

home::Recognition SpeechRecognizerDevice::decode(const planet::Binary& audio, std::int32_t sample_rate,
                                                 std::int32_t channels, const std::vector<std::string>& phrases) {
  const auto bad = [](std::string reason) { return home::BadAudio(reason, reason); };
  if (channels < 1 || channels > 16) throw bad(fmt::format("{} channels: expected 1 to 16", channels));
  const auto frame_bytes = 2 * static_cast<std::size_t>(channels);
  if (audio.bytes.size() % frame_bytes != 0) {
    throw bad(fmt::format("{} bytes are not whole frames of {} 16-bit channels", audio.bytes.size(), channels));
  }
  audio::AudioBlock block;
  block.format = {sample_rate, channels};
  block.samples = audio::pcm_samples(audio.bytes);
  std::unique_ptr<audio::Recognizer> recognizer;
  try {
    recognizer = take();
  } catch (const audio::AudioError& e) {
    throw planet::Error(planet::ErrorKind::failed, std::string("the speech recognizer cannot start: ") + e.what());
  }
  audio::Recognition r;
  try {
    recognizer->set_phrases(phrases);
    r = recognizer->recognize(block);
  } catch (const audio::AudioError& e) {
    give_back(std::move(recognizer));
    throw bad(e.what());
  }
  give_back(std::move(recognizer));
  ++decoded_;
  if (!r.recognized) {
    const auto why = r.heard.empty() ? r.reason : fmt::format("{} (heard \"{}\")", r.reason, r.heard);
    throw home::NotRecognized(why, why);
  }
  return home::Recognition{r.text, r.confidence, r.heard, r.decode_seconds * 1000.0};
}

}  // namespace icars::home
