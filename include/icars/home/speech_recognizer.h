// The SpeechRecognizer device: PocketSphinx (audio::Recognizer) behind the home's
// SpeechRecognizer interface, a software device a device manager hosts like any other. Each call
// decodes one utterance against the phrases the caller sent (grammars are cached, so the same
// vocabulary costs nothing after the first call). Decoding runs on `decoders` threads of the
// device's own, never on the PLANET io thread: the other devices of its manager go on answering
// and publishing while it decodes (a lock-step clock waits for it). More calls wait their turn.
#pragma once

#include <asio/thread_pool.hpp>
#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <vector>

#include "home.planet.h"
#include "icars/audio/recognizer.h"

namespace icars::home {

class SpeechRecognizerDevice final : public home::SpeechRecognizerServant {
 public:
  explicit SpeechRecognizerDevice(audio::RecognizerOptions options = {}, int decoders = 1);
  ~SpeechRecognizerDevice() override;

  home::Recognition recognize(const planet::Binary& audio, std::int32_t sample_rate, std::int32_t channels,
                              const std::vector<std::string>& phrases, const planet::Current&) override;

  std::uint64_t decoded() const { return decoded_.load(); }

 private:
  home::Recognition decode(const planet::Binary& audio, std::int32_t sample_rate, std::int32_t channels,
                           const std::vector<std::string>& phrases);
  std::unique_ptr<audio::Recognizer> take();
  void give_back(std::unique_ptr<audio::Recognizer> r);
  audio::RecognizerOptions options_;
  std::mutex mutex_;
  int unmade_ = 0;  // decoders not made yet
  std::condition_variable returned_;
  std::vector<std::unique_ptr<audio::Recognizer>> idle_;
  std::atomic<std::uint64_t> decoded_{0};
  asio::thread_pool workers_;  // last: joined first, while what the decodes use still exists
};

}  // namespace icars::home
