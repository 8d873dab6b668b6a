// Speech synthesis with espeak-ng: what comes out (16 kHz, -3 dBFS peak, no silence around it,
// a plausible length), voices and their parameters, the cache, the errors that name the voice,
// and several threads speaking at once through the one engine.
#include "icars/audio/synthesizer.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <future>

namespace icars::audio {
namespace {

double peak_dbfs(const Signal& s) {
  float peak = 0;
  for (const float v : s.samples) peak = std::max(peak, std::abs(v));
  return 20 * std::log10(peak);
}

// Seconds until the signal first gets within 40 dB of its peak.
double onset_seconds(const Signal& s) {
  const auto it = std::find_if(s.samples.begin(), s.samples.end(),
                               [](float v) { return std::abs(v) > 0.007f; });
  return static_cast<double>(it - s.samples.begin()) / s.sample_rate;
}

std::string error_of(const std::string& text, const Voice& voice) {
  try {
    Synthesizer().speak(text, voice);
  } catch (const AudioError& e) {
    return e.what();
  }
  return "no AudioError";
}

TEST(Synthesizer, SpeaksAtTheSpeechRateNormalisedAndTrimmed) {
  Synthesizer synthesizer;
  const Signal s = synthesizer.speak("turn on the tv");
  EXPECT_EQ(s.sample_rate, kSpeechRate);
  EXPECT_GT(s.seconds(), 0.6);  // four words at 160 words per minute, no pauses around them
  EXPECT_LT(s.seconds(), 1.6);
  EXPECT_NEAR(peak_dbfs(s), -3.0, 0.05);
  EXPECT_LT(onset_seconds(s), 0.03);
  Signal reversed = s;
  std::reverse(reversed.samples.begin(), reversed.samples.end());
  EXPECT_LT(onset_seconds(reversed), 0.03);
}

TEST(Synthesizer, VoicesAndTheirParametersChangeTheSound) {
  Synthesizer synthesizer;
  const Signal us = synthesizer.speak("play music", Voice{"en-us"});
  const Signal female = synthesizer.speak("play music", Voice{"en-us+f3"});
  const Signal british = synthesizer.speak("play music", Voice{"en"});
  EXPECT_NE(us.samples, female.samples);
  EXPECT_NE(us.samples, british.samples);

  const Signal slow = synthesizer.speak("play music", Voice{"en-us", 100});
  const Signal fast = synthesizer.speak("play music", Voice{"en-us", 300});
  EXPECT_GT(slow.seconds(), 1.5 * us.seconds());
  EXPECT_LT(fast.seconds(), 0.8 * us.seconds());

  const Signal high = synthesizer.speak("play music", Voice{"en-us", 160, 90});
  EXPECT_NE(high.samples, us.samples);
}

TEST(Synthesizer, CachesByVoiceAndText) {
  Synthesizer synthesizer;
  const std::string text = "the cache test sentence number " + std::to_string(::getpid());
  const auto t0 = std::chrono::steady_clock::now();
  const Signal first = synthesizer.speak(text);
  const auto t1 = std::chrono::steady_clock::now();
  const Signal again = Synthesizer().speak(text);  // another Synthesizer shares the engine
  const auto t2 = std::chrono::steady_clock::now();
  EXPECT_EQ(first.samples, again.samples);
  EXPECT_LT(t2 - t1, (t1 - t0) / 4);
  EXPECT_NE(synthesizer.speak(text, Voice{"en-us", 200}).samples, first.samples);
}

TEST(Synthesizer, ErrorsNameTheVoiceOrWhatWasWrong) {
  EXPECT_NE(error_of("hello", Voice{"xx-nosuch"}).find("no voice \"xx-nosuch\""),
            std::string::npos);
  EXPECT_NE(error_of("hello", Voice{"en-us+nosuchvariant"}).find("\"en-us+nosuchvariant\""),
            std::string::npos);
  EXPECT_NE(error_of("hello", Voice{""}).find("no voice \"\""), std::string::npos);
  EXPECT_NE(error_of("", Voice{}).find("text is empty"), std::string::npos);
  EXPECT_NE(error_of(" \n\t", Voice{}).find("text is empty"), std::string::npos);
  EXPECT_NE(error_of("hello", Voice{"en-us", 160, 120}).find("pitch 120"), std::string::npos);
  EXPECT_NE(error_of("hello", Voice{"en-us", 20}).find("20 words per minute"), std::string::npos);
  // An error leaves the engine usable.
  EXPECT_FALSE(Synthesizer().speak("hello").samples.empty());
}

TEST(Synthesizer, ListsTheVoicesOfALanguage) {
  const auto english = Synthesizer::voices("en");
  for (const char* name : {"en", "en-us", "en-gb-x-rp"}) {
    EXPECT_NE(std::find(english.begin(), english.end(), name), english.end()) << name;
  }
  EXPECT_TRUE(std::is_sorted(english.begin(), english.end()));
  for (const auto& name : english) {
    EXPECT_TRUE(name == "en" || name.starts_with("en-")) << name;
    EXPECT_FALSE(Synthesizer().speak("yes", Voice{name}).samples.empty()) << name;
  }
  const auto german = Synthesizer::voices("de");
  EXPECT_NE(std::find(german.begin(), german.end(), "de"), german.end());
  EXPECT_TRUE(Synthesizer::voices("xx").empty());
}

TEST(Synthesizer, ThreadsShareTheEngine) {
  // espeak-ng is one engine per process: concurrent speakers take turns and each gets its own
  // sentence, as spoken alone.
  const std::vector<std::string> texts = {"volume up", "volume down", "stop the music",
                                          "channel five"};
  std::vector<Signal> alone;
  for (const auto& t : texts) alone.push_back(Synthesizer().speak(t, Voice{"en-us", 170}));
  std::vector<std::future<Signal>> results;
  for (const auto& t : texts) {
    results.push_back(std::async(std::launch::async, [t] {
      return Synthesizer().speak(t, Voice{"en-us", 171});  // not cached yet
    }));
  }
  for (std::size_t i = 0; i < texts.size(); ++i) {
    const Signal s = results[i].get();
    EXPECT_NEAR(s.seconds(), alone[i].seconds(), 0.05) << texts[i];
  }
}

}  // namespace
}  // namespace icars::audio
