// The voice path with a real microphone's device code (SourceMicrophone) standing on a file or
// a pipe instead of a sound card, over real PLANET connections to the Service Framework, with
// PocketSphinx as the speech engine: a recorded sentence becomes a SpeechEvent; bad input (a
// stream that stops mid-sentence, an unknown sentence, clipping, another sample rate, an hour of
// silence) gets an answer or a report, never a crash or a hang.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <future>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "child_process.h"
#include "scoped_subscription.h"
#include "test_directory.h"
#include "icars/audio/pcm.h"
#include "icars/audio/wav.h"
#include "icars/clock/sim_clock.h"
#include "icars/device/device_manager.h"
#include "icars/home/adaptors.h"
#include "icars/home/microphone.h"
#include "icars/home/services.h"
#include "icars/home/speech_recognizer.h"
#include "icars/service/service_framework.h"

namespace icars::home {
namespace {

using namespace icars::service;
using namespace std::chrono_literals;
namespace p = icars::planet;
namespace fs = std::filesystem;

const std::vector<std::string> kPhrases = {"turn on the tv", "turn off the tv", "channel 5", "play music", "stop"};

// A WAV of `text` made the way a user would: espeak-ng's program, then sox to the rate wanted,
// with a second of quiet around it. `sox_effects` are appended (e.g. "vol 30" to clip it).
std::string speak_to_wav(const fs::path& dir, const std::string& name, const std::string& text, int rate = 16000,
                         const std::string& sox_effects = "") {
  const auto raw = dir / (name + ".espeak.wav");
  const auto out = dir / (name + ".wav");
  const auto speak = "espeak-ng -v en-us -w '" + raw.string() + "' '" + text + "'";
  EXPECT_EQ(std::system(speak.c_str()), 0) << speak;
  const auto convert = "sox '" + raw.string() + "' -r " + std::to_string(rate) + " -c 1 -b 16 '" + out.string() +
                       "' pad 1 1 " + sox_effects;
  EXPECT_EQ(std::system(convert.c_str()), 0) << convert;
  return out.string();
}

class VoicePath : public ::testing::Test {
 protected:
  void SetUp() override { port_ = server_.listen("127.0.0.1", 0); }

  // The microphone (on `source`) and the speech engine, served by a device manager.
  void start_devices(std::unique_ptr<audio::AudioSource> source, const std::string& spec) {
    mic_ = std::make_shared<SourceMicrophone>(std::move(source), spec, clock_, devices_);
    auto ears = std::make_shared<device::Device>("ears", "Microphone", "living_room");
    ears->add("sound_sensor", mic_);
    auto engine = std::make_shared<device::Device>("speech_engine", "SpeechEngine");
    engine->add("speech_recognizer", std::make_shared<SpeechRecognizerDevice>());
    manager_.add(ears);
    manager_.add(engine);
    manager_.connect("127.0.0.1", port_);
    ASSERT_TRUE(manager_.wait_registered(1, 30s)) << manager_.last_error();
    ASSERT_TRUE(planet_test::wait_until([&] {
      speech_ = sf_.container().find_first<SpeechSensor>(ServiceQuery::of_type("SpeechSensor").available());
      sound_ = sf_.container().find_first<SoundSensor>(ServiceQuery::of_type("SoundSensor"));
      return speech_ && sound_ && sound_->stats().captures > 0;
    }, 30s));
    speech_->want_phrases(this, kPhrases);
    subscription_.emplace(planet_test::subscribe_scoped(*speech_, Heard{this}));
  }

  struct Heard {
    VoicePath* test;
    void operator()(const SpeechEvent& e) const {
      std::lock_guard lock(test->mutex_);
      test->recognized_.push_back(e);
    }
    void operator()(const UnrecognizedSpeech& e) const {
      std::lock_guard lock(test->mutex_);
      test->unrecognized_.push_back(e);
    }
  };
  std::size_t answers() {
    std::lock_guard lock(mutex_);
    return recognized_.size() + unrecognized_.size();
  }

  planet_test::TestDirectory dir_{"icars_voice"};
  SimClock clock_{at_time(0, 18, 0)};
  p::Communicator server_;
  ServiceFramework sf_{server_, adaptors(), {}, {composer()}};
  std::uint16_t port_ = 0;
  p::Communicator devices_;
  device::DeviceManager manager_{devices_};
  std::shared_ptr<SourceMicrophone> mic_;
  std::shared_ptr<SpeechSensor> speech_;
  std::shared_ptr<SoundSensor> sound_;
  std::mutex mutex_;
  std::vector<SpeechEvent> recognized_;
  std::vector<UnrecognizedSpeech> unrecognized_;
  std::optional<planet_test::ScopedSubscription<SpeechSensor>> subscription_;
};

TEST_F(VoicePath, ARecordedSentenceThroughTheMicrophonesDeviceCodeIsRecognized) {
  const auto wav = speak_to_wav(dir_.path(), "tv_on", "turn on the TV");
  start_devices(audio::open_source("wav:" + wav), "wav:" + wav);
  mic_->start();
  ASSERT_TRUE(planet_test::wait_until([&] { return answers() >= 1; }, 60s));
  ASSERT_TRUE(planet_test::wait_until([&] { return mic_->ended(); }, 30s));
  std::lock_guard lock(mutex_);
  ASSERT_EQ(recognized_.size(), 1u) << (unrecognized_.empty() ? "" : unrecognized_[0].reason);
  EXPECT_EQ(recognized_[0].text, "turn on the tv");
  EXPECT_EQ(recognized_[0].device, "ears");
  EXPECT_EQ(recognized_[0].room, "living_room");
  // Timed on the clock: the sentence starts about a second into the file.
  EXPECT_NEAR(static_cast<double>(recognized_[0].time_ms), static_cast<double>(at_time(0, 18, 0).count()) + 1000, 400);
  EXPECT_GT(recognized_[0].end_ms, recognized_[0].time_ms);
}

TEST_F(VoicePath, AnUnknownSentenceIsHeardAsUnrecognizedSpeech) {
  const auto wav = speak_to_wav(dir_.path(), "weather", "what will the weather be like tomorrow");
  start_devices(audio::open_source("wav:" + wav), "wav:" + wav);
  mic_->start();
  ASSERT_TRUE(planet_test::wait_until([&] { return answers() >= 1; }, 60s));
  std::lock_guard lock(mutex_);
  EXPECT_TRUE(recognized_.empty()) << "taken for \"" << recognized_[0].text << "\"";
  ASSERT_FALSE(unrecognized_.empty());
  EXPECT_FALSE(unrecognized_[0].reason.empty());
  EXPECT_EQ(unrecognized_[0].device, "ears");
}

TEST_F(VoicePath, ClippedAudioAndAnotherSampleRateAreStillHeard) {
  // 44.1 kHz, amplified until a good part of it clips.
  const auto wav = speak_to_wav(dir_.path(), "loud", "play music", 44100, "vol 40");
  start_devices(audio::open_source("wav:" + wav), "wav:" + wav);
  EXPECT_EQ(sound_->info()->sample_rate, 44100);
  std::promise<SoundEvent> sound;
  std::atomic<bool> once{false};
  const auto sounds = planet_test::subscribe_scoped(*sound_, [&](const SoundEvent& e) {
    if (!once.exchange(true)) sound.set_value(e);
  });
  mic_->start();
  auto heard = sound.get_future();
  ASSERT_EQ(heard.wait_for(60s), std::future_status::ready);
  const auto e = heard.get();
  EXPECT_TRUE(e.clipped);
  EXPECT_EQ(e.sample_rate, 44100);
  ASSERT_TRUE(planet_test::wait_until([&] { return answers() >= 1; }, 60s));
  std::lock_guard lock(mutex_);
  // Clipped speech may or may not be understood; it is answered either way.
  if (!recognized_.empty()) {
    EXPECT_EQ(recognized_[0].text, "play music");
  }
}

// A pipe that stops in the middle of a sentence: what was heard is published as an interrupted
// sound and answered, the capture is reported broken, and nothing waits for the rest.
TEST_F(VoicePath, AStreamThatStopsMidSentenceIsAnsweredAndReported) {
  const auto wav = audio::read_wav(speak_to_wav(dir_.path(), "cut", "turn off the TV"));
  const auto fifo = dir_ / "mic.fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::thread writer([&] {
    const int fd = ::open(fifo.c_str(), O_WRONLY);
    ASSERT_GE(fd, 0);
    // One second of quiet, then half the sentence, then the pipe closes.
    const auto bytes = audio::pcm_bytes(wav.samples);
    const std::size_t half = (16000 * 2) + (bytes.size() - 2 * 16000 * 2) / 2;
    ASSERT_EQ(::write(fd, bytes.data(), half), static_cast<ssize_t>(half));
    ::close(fd);
  });
  audio::SourceOptions options;
  options.real_time = false;
  std::unique_ptr<audio::AudioSource> source;
  source = audio::open_source("raw:" + fifo.string(), options);
  start_devices(std::move(source), "raw:" + fifo.string());
  mic_->start();
  writer.join();
  ASSERT_TRUE(planet_test::wait_until([&] { return sound_->stats().interrupted >= 1; }, 60s))
      << "sounds " << sound_->stats().sounds << ", last error " << sound_->stats().last_error;
  ASSERT_TRUE(planet_test::wait_until([&] { return answers() >= 1; }, 60s));
  EXPECT_GE(sound_->stats().broken, 1u);
  EXPECT_NE(sound_->stats().last_error, "");
  EXPECT_TRUE(mic_->ended());
}

// An hour of silence from a pipe, as fast as it can be read: no sound is cut from it, and the
// capture carried it all or dropped what fell too far behind (bounded memory either way).
TEST_F(VoicePath, AnHourOfSilenceIsNoSoundAndCostsNoMemory) {
  const auto fifo = dir_ / "silence.fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::thread writer([&] {
    const int fd = ::open(fifo.c_str(), O_WRONLY);
    ASSERT_GE(fd, 0);
    std::vector<std::byte> second(32000);
    std::uint32_t noise = 1;
    for (auto& b : second) {
      noise = noise * 1664525u + 1013904223u;
      b = static_cast<std::byte>((noise >> 24) & 0x03);  // the faintest hiss
    }
    for (int s = 0; s < 3600; ++s) {
      if (::write(fd, second.data(), second.size()) != static_cast<ssize_t>(second.size())) break;
    }
    ::close(fd);
  });
  audio::SourceOptions options;
  options.real_time = false;
  start_devices(audio::open_source("raw:" + fifo.string(), options), "raw:" + fifo.string());
  mic_->start();
  writer.join();
  ASSERT_TRUE(planet_test::wait_until([&] { return mic_->ended(); }, 300s));
  EXPECT_EQ(mic_->frames_read(), 3600u * 50) << "an hour in 20 ms periods";
  ASSERT_TRUE(planet_test::wait_until([&] { return sound_->stats().broken >= 1; }, 60s)) << "the capture ended";
  EXPECT_EQ(sound_->stats().sounds, 0u);
  EXPECT_EQ(answers(), 0u);
}

}  // namespace
}  // namespace icars::home
