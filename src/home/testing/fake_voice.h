// Test support: a microphone and a speech recognizer served over PLANET that need no audio
// engine. The microphone "says" a sentence as a burst of loud noise whose length tells which
// (300 ms for the first of kSentences, 200 ms more for each next), among quiet noise; the
// recognizer measures the burst and answers the sentence.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "home.planet.h"
#include "icars/audio/audio_stream.h"
#include "icars/audio/pcm.h"
#include "icars/home/microphone.h"

namespace home_test {

namespace p = icars::planet;
namespace audio = icars::audio;

// What the fake microphone can "say": each sentence is a burst of noise of its own length
// (300 ms for the first, 200 ms more for each next), which the fake recognizer measures.
inline const std::vector<std::string> kSentences = {"turn on the TV", "channel 5", "volume up", "play music", "stop"};

// A microphone whose capture is bursts of loud noise among quiet noise, a burst per sentence.
class FakeMicrophone final : public icars::home::MicrophoneServant {
 public:
  explicit FakeMicrophone(p::Communicator& communicator) : captures_(communicator) {}
  icars::home::MicrophoneInfo info(const p::Current&) override {
    return icars::home::microphone_info({16000, 1}, {{0, 0}}, 30.0, "fake");
  }
  p::StreamRef capture(std::int64_t since, const p::Current&) override {
    return captures_.open(static_cast<std::uint64_t>(since));
  }
  void hear(const std::string& text) {
    const auto index = static_cast<std::size_t>(std::find(kSentences.begin(), kSentences.end(), text) - kSentences.begin());
    ASSERT_LT(index, kSentences.size()) << text;
    audio::AudioBlock block;
    block.format = {16000, 1};
    block.start = position_;
    const std::size_t quiet = 16 * 300, loud = 16 * (300 + 200 * index), after = 16 * 700;
    for (std::size_t i = 0; i < quiet + loud + after; ++i) {
      noise_ = noise_ * 1664525u + 1013904223u;
      const int amplitude = i >= quiet && i < quiet + loud ? 6000 : 20;
      block.samples.push_back(static_cast<std::int16_t>(static_cast<int>(noise_ >> 20) % amplitude));
    }
    position_ += block.frames();
    captures_.push(block);
  }
  std::size_t subscribers() const { return captures_.readers(); }

 private:
  icars::home::CaptureStreams captures_;
  std::uint64_t position_ = 16000;
  std::uint32_t noise_ = 1;
};

// Tells the sentence from the length of the loud part.
class FakeRecognizer final : public icars::home::SpeechRecognizerServant {
 public:
  icars::home::Recognition recognize(const p::Binary& audio, std::int32_t, std::int32_t,
                              const std::vector<std::string>&, const p::Current&) override {
    const auto samples = audio::pcm_samples(audio.bytes);
    std::size_t loud = 0;
    for (std::size_t f = 0; f + 320 <= samples.size(); f += 320) {
      double energy = 0;
      for (std::size_t i = f; i < f + 320; ++i) energy += double(samples[i]) * samples[i];
      if (energy / 320 > 1e5) ++loud;
    }
    const double ms = static_cast<double>(loud) * 20;
    const auto index = static_cast<std::size_t>(std::max(0L, std::lround((ms - 300) / 200.0)));
    if (loud == 0 || index >= kSentences.size()) throw icars::home::NotRecognized("no sentence", "no sentence");
    return icars::home::Recognition{kSentences[index], 0.9, kSentences[index], 1.0};
  }
};

}  // namespace home_test
