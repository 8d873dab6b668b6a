// Speech recognition end to end: the paper house's commands spoken by espeak-ng voices and
// heard in a quiet room are recognized, sentences that are no command are not, and the
// recognizer copes with what a capture brings (other rates, several channels, clipping,
// silence) and with a vocabulary it cannot say.
#include "icars/audio/recognizer.h"

#include <gtest/gtest.h>

#include <chrono>
#include <iostream>

#include "icars/audio/acoustics.h"
#include "icars/audio/resample.h"
#include "icars/audio/synthesizer.h"
#include "test_signals.h"

namespace icars::audio {
namespace {

namespace signals = icars::audio::testing;

// The voice commands of the paper's house (VoiceTVControl, VoiceAudioControl).
const std::vector<std::string> kCommands = {"turn on the tv", "turn off the tv", "channel 5",
                                            "volume up",      "volume down",     "play music",
                                            "stop",           "stop the music"};

// `speech` as a microphone in a quiet room hears it: 0.3 s of the room before and after and
// the room's noise, white at -60 dBFS, under all of it (the voice peaks at -3 dBFS).
Signal in_room(const Signal& speech, double noise_dbfs = -60.0) {
  Signal x = signals::concat({signals::silence(0.3), speech, signals::silence(0.3)});
  const Signal noise = signals::white_noise(x.seconds(), noise_dbfs, 1);
  for (std::size_t i = 0; i < x.samples.size() && i < noise.samples.size(); ++i) {
    x.samples[i] += noise.samples[i];
  }
  return x;
}

Signal spoken(const std::string& text, const std::string& voice = "en-us") {
  return in_room(Synthesizer().speak(text, Voice{voice}));
}

AudioBlock said(const std::string& text, const std::string& voice = "en-us") {
  return to_block(spoken(text, voice));
}

std::string error_of(auto&& call) {
  try {
    call();
  } catch (const AudioError& e) {
    return e.what();
  }
  return "no AudioError";
}

TEST(Recognizer, RecognizesTheHouseCommandsInTwoVoices) {
  Recognizer recognizer;
  recognizer.set_phrases(kCommands);
  int right = 0;
  double decoding = 0, speech = 0;
  for (const std::string voice : {"en-us", "en-us+f3"}) {
    for (const auto& command : kCommands) {
      const Recognition r = recognizer.recognize(said(command, voice));
      std::cout << voice << " \"" << command << "\": " << (r.recognized ? "recognized" : r.reason)
                << ", heard \"" << r.heard << "\", confidence " << r.confidence << ", "
                << r.decode_seconds << " s for " << r.speech_seconds << " s\n";
      // A command may be missed, never taken for another one.
      if (r.recognized) {
        EXPECT_EQ(r.text, command) << voice;
      }
      if (r.recognized && r.text == command) {
        ++right;
        EXPECT_GE(r.confidence, 0.3);
        EXPECT_LE(r.confidence, 1.0);
      } else {
        EXPECT_FALSE(r.reason.empty());
      }
      decoding += r.decode_seconds;
      speech += r.speech_seconds;
    }
  }
  // Measured: 15 of 16; en-us+f3's "stop" is heard as the filler word "still".
  EXPECT_GE(right, 15);
  std::cout << "real-time factor " << decoding / speech << "\n";
  EXPECT_LT(decoding / speech, 1.0);
}

// `text` said 2 m from the microphone in a living room (RT60 0.4 s, 30 dB SPL of noise), the
// speech_bench's quiet room.
AudioBlock said_across_the_room(const std::string& text, const std::string& voice, std::uint64_t seed) {
  const RoomSound room{.rt60 = 0.4, .critical_distance = 1.0, .noise_db = 30.0, .seed = seed};
  return render(Synthesizer().speak(text, Voice{voice}), {Path{.distance = 2.0, .level_db = 54.0}}, room, 0.5, 0.8);
}

// A one-word command in a reverberant room: the room blurs its plosives, and "stop" (S T AA P)
// was heard as the filler word "saw" (S AO) in 3 to 5 of 10 trials; such filler words are left
// out of the loop beside a one-word phrase. Words that are no command stay unrecognized.
TEST(Recognizer, AOneWordCommandAcrossAReverberantRoomIsNotLostToAFillerWordInsideIt) {
  Recognizer recognizer;
  recognizer.set_phrases(kCommands);
  int stops = 0, trials = 0;
  for (const std::string voice : {"en-us", "en"}) {
    for (std::uint64_t seed = 1; seed <= 4; ++seed, ++trials) {
      const Recognition r = recognizer.recognize(said_across_the_room("stop", voice, seed * 7));
      std::cout << voice << " seed " << seed << ": " << (r.recognized ? r.text : r.reason) << ", heard \"" << r.heard << "\"\n";
      if (r.recognized) {
        EXPECT_EQ(r.text, "stop") << voice;
      }
      stops += r.recognized && r.text == "stop" ? 1 : 0;
    }
  }
  // Measured with Debian's model: 7 of 8 after the other tests of this suite, 5 of 8 alone
  // (espeak-ng's output is not the same on every call: "sun", "all"); 1 of 8 when the whole
  // filler loop stood beside "stop" (6 times "saw").
  EXPECT_GE(stops, trials / 2);
  for (const std::string word : {"saw", "so", "top"}) {
    const Recognition r = recognizer.recognize(said_across_the_room(word, "en-us", 3));
    EXPECT_FALSE(r.recognized) << "\"" << word << "\" heard as " << r.text;
  }
}

TEST(Recognizer, SentencesThatAreNoCommandAreNotRecognized) {
  Recognizer recognizer;
  recognizer.set_phrases(kCommands);
  for (const std::string voice : {"en-us", "en-us+f3"}) {
    for (const std::string sentence : {"what is the weather like tomorrow", "open the garage"}) {
      const Recognition r = recognizer.recognize(said(sentence, voice));
      EXPECT_FALSE(r.recognized) << voice << " \"" << sentence << "\" heard as " << r.text;
      EXPECT_EQ(r.reason, "not a known phrase") << voice << " " << sentence;
      EXPECT_FALSE(r.heard.empty()) << "the filler words it was heard as";
      EXPECT_TRUE(r.text.empty());
    }
  }
}

TEST(Recognizer, PhrasesAreReportedAsGivenAndNumbersSpokenAsWords) {
  Recognizer recognizer;
  recognizer.set_phrases({"Turn on the TV!", "channel 5", "channel 21"});
  EXPECT_EQ(recognizer.phrases(),
            (std::vector<std::string>{"Turn on the TV!", "channel 5", "channel 21"}));
  Recognition r = recognizer.recognize(said("turn on the tv"));
  EXPECT_TRUE(r.recognized) << r.reason;
  EXPECT_EQ(r.text, "Turn on the TV!");
  EXPECT_EQ(r.heard, "turn on the tv");
  r = recognizer.recognize(said("channel twenty one"));
  EXPECT_TRUE(r.recognized) << r.reason;
  EXPECT_EQ(r.text, "channel 21");
  EXPECT_EQ(r.heard, "channel twenty one");

  EXPECT_EQ(spoken_form("channel 5"), "channel five");
  EXPECT_EQ(spoken_form("  Channel 42, please!"), "channel forty two please");
  EXPECT_EQ(spoken_form("set 0 to 115 or 900"), "set zero to one hundred fifteen or nine hundred");
  EXPECT_EQ(spoken_form("What's up?"), "what's up");
  EXPECT_EQ(spoken_form("'quoted' words -- and dashes"), "quoted words and dashes");
  EXPECT_EQ(spoken_form("room 1000"), "room 1000");  // beyond 999: left as it is
}

TEST(Recognizer, ResamplesAndMixesDownWhatACaptureDelivers) {
  Recognizer recognizer;
  recognizer.set_phrases(kCommands);
  const Signal speech = spoken("volume up");

  const Recognition at_44k = recognizer.recognize(to_block(resample(speech, 44100)));
  EXPECT_TRUE(at_44k.recognized) << at_44k.reason;
  EXPECT_EQ(at_44k.text, "volume up");
  EXPECT_NEAR(at_44k.speech_seconds, speech.seconds(), 0.01);

  // A telephone's 8 kHz has nothing above 4 kHz: it still decodes (measured: recognized).
  const Recognition at_8k = recognizer.recognize(to_block(resample(speech, 8000)));
  std::cout << "8 kHz: " << (at_8k.recognized ? at_8k.text : at_8k.reason) << ", heard \""
            << at_8k.heard << "\"\n";
  EXPECT_NEAR(at_8k.speech_seconds, speech.seconds(), 0.01);
  EXPECT_TRUE(at_8k.recognized && at_8k.text == "volume up") << at_8k.heard;

  // A stereo sound card at 48 kHz, the voice weaker on one side.
  const Signal at_48k = resample(speech, 48000);
  AudioBlock stereo;
  stereo.format = {48000, 2};
  for (const float v : at_48k.samples) {
    stereo.samples.push_back(to_pcm16(v));
    stereo.samples.push_back(to_pcm16(v * 0.5f));
  }
  const Recognition both = recognizer.recognize(stereo);
  EXPECT_TRUE(both.recognized) << both.reason;
  EXPECT_EQ(both.text, "volume up");
}

TEST(Recognizer, AbsurdFormatsAreErrorsThatSayWhy) {
  Recognizer recognizer;
  recognizer.set_phrases(kCommands);
  AudioBlock audio = said("stop");
  audio.format.sample_rate = 1000;
  EXPECT_EQ(error_of([&] { recognizer.recognize(audio); }),
            "audio at 1000 Hz: the recognizer takes 8000..192000 Hz");
  audio.format.sample_rate = 1000000;
  EXPECT_EQ(error_of([&] { recognizer.recognize(audio); }),
            "audio at 1000000 Hz: the recognizer takes 8000..192000 Hz");
  audio.format = {kSpeechRate, 0};
  EXPECT_EQ(error_of([&] { recognizer.recognize(audio); }),
            "audio with 0 channels: the recognizer needs at least one");
  // The recognizer goes on working.
  const Recognition r = recognizer.recognize(said("play music"));
  EXPECT_TRUE(r.recognized) << r.reason;
  EXPECT_EQ(r.text, "play music");
}

TEST(Recognizer, HeavilyClippedSpeechStillDecodes) {
  Recognizer recognizer;
  recognizer.set_phrases(kCommands);
  Signal loud = spoken("volume down");
  for (float& v : loud.samples) v *= 30.0f;  // +30 dB: most of the voice saturates
  std::size_t clipped = 0;
  const AudioBlock audio = to_block(loud, &clipped);
  EXPECT_GT(clipped, audio.samples.size() / 10);
  const Recognition r = recognizer.recognize(audio);
  std::cout << "clipped " << clipped << " of " << audio.samples.size()
            << " samples: " << (r.recognized ? r.text : r.reason) << ", heard \"" << r.heard
            << "\"\n";
  EXPECT_NEAR(r.speech_seconds, loud.seconds(), 0.01);
  if (r.recognized) {
    EXPECT_EQ(r.text, "volume down");
  } else {
    EXPECT_EQ(r.reason, "not a known phrase");
  }
}

TEST(Recognizer, SilenceIsNoSpeech) {
  Recognizer recognizer;
  recognizer.set_phrases(kCommands);
  Recognition r = recognizer.recognize(AudioBlock{});
  EXPECT_FALSE(r.recognized);
  EXPECT_EQ(r.reason, "no speech");
  EXPECT_EQ(r.speech_seconds, 0);

  r = recognizer.recognize(to_block(signals::silence(1.0)));
  EXPECT_EQ(r.reason, "no speech");
  EXPECT_DOUBLE_EQ(r.speech_seconds, 1.0);

  // A quiet room, nobody speaking.
  r = recognizer.recognize(to_block(signals::white_noise(1.5, -70, 3)));
  EXPECT_FALSE(r.recognized);
  EXPECT_EQ(r.reason, "no speech");
  EXPECT_TRUE(r.heard.empty());
}

TEST(Recognizer, AWordOutsideTheDictionaryIsAnErrorNamingIt) {
  Recognizer recognizer;
  recognizer.set_phrases(kCommands);
  std::string message = error_of([&] { recognizer.set_phrases({"stop", "frobnicate the tv"}); });
  EXPECT_NE(message.find("phrase \"frobnicate the tv\""), std::string::npos) << message;
  EXPECT_NE(message.find("word \"frobnicate\""), std::string::npos) << message;
  message = error_of([&] { recognizer.set_phrases({"go to room 1000"}); });
  EXPECT_NE(message.find("word \"1000\""), std::string::npos) << message;
  EXPECT_NE(error_of([&] {
              recognizer.set_phrases({"stop", "?!"});
            }).find("\"?!\" has no words"),
            std::string::npos);
  // The vocabulary stays as it was.
  EXPECT_EQ(recognizer.phrases(), kCommands);
  const Recognition r = recognizer.recognize(said("stop the music"));
  EXPECT_TRUE(r.recognized) << r.reason;
  EXPECT_EQ(r.text, "stop the music");
}

TEST(Recognizer, WithoutPhrasesItTakesDictation) {
  Recognizer recognizer;
  const std::string sentence = "i would like a cup of coffee";
  const Recognition r = recognizer.recognize(said(sentence));
  std::cout << "dictation: \"" << r.text << "\", confidence " << r.confidence << ", "
            << r.decode_seconds << " s for " << r.speech_seconds << " s\n";
  EXPECT_TRUE(r.recognized) << r.reason;
  EXPECT_EQ(r.text, r.heard);
  int found = 0;
  for (const char* word : {"i", "would", "like", "a", "cup", "of", "coffee"}) {
    found += (" " + r.text + " ").find(std::string(" ") + word + " ") != std::string::npos;
  }
  EXPECT_GE(found, 5) << r.text;  // measured: all seven

  // Back to dictation after a vocabulary.
  recognizer.set_phrases(kCommands);
  EXPECT_FALSE(recognizer.recognize(said(sentence)).recognized);
  recognizer.set_phrases({});
  EXPECT_TRUE(recognizer.recognize(said(sentence)).recognized);
}

TEST(Recognizer, PiecesGiveTheSameResultAsTheWhole) {
  Recognizer recognizer;
  recognizer.set_phrases(kCommands);
  for (const int rate : {kSpeechRate, 44100}) {
    SCOPED_TRACE(rate);
    const AudioBlock whole = to_block(resample(spoken("turn off the tv", "en-us+f3"), rate));
    const Recognition at_once = recognizer.recognize(whole);
    EXPECT_TRUE(at_once.recognized) << at_once.reason;

    recognizer.start();
    const auto pieces = signals::split(whole, static_cast<std::size_t>(rate / 50));  // 20 ms
    for (const auto& piece : pieces) recognizer.feed(piece);
    const Recognition in_pieces = recognizer.finish();
    EXPECT_EQ(in_pieces.recognized, at_once.recognized);
    EXPECT_EQ(in_pieces.text, at_once.text);
    EXPECT_EQ(in_pieces.heard, at_once.heard);
    EXPECT_DOUBLE_EQ(in_pieces.confidence, at_once.confidence);
    EXPECT_NEAR(in_pieces.speech_seconds, at_once.speech_seconds, 1e-9);
  }

  // A cancelled utterance leaves nothing behind; feeding without start() is a bug.
  recognizer.start();
  recognizer.feed(said("what is the weather like tomorrow"));
  recognizer.cancel();
  EXPECT_THROW(recognizer.feed(said("stop")), std::logic_error);
  EXPECT_THROW(recognizer.finish(), std::logic_error);
  recognizer.start();
  recognizer.feed(said("stop the music"));
  const Recognition r = recognizer.finish();
  EXPECT_EQ(r.text, "stop the music");
  EXPECT_THROW(recognizer.finish(), std::logic_error);

  // A piece the recognizer refuses ends the utterance.
  recognizer.start();
  AudioBlock bad = said("stop");
  bad.format.channels = 0;
  EXPECT_THROW(recognizer.feed(bad), AudioError);
  EXPECT_THROW(recognizer.finish(), std::logic_error);
}

TEST(Recognizer, SwitchingBackToAVocabularyIsCheap) {
  using Clock = std::chrono::steady_clock;
  Recognizer recognizer;
  const std::vector<std::string> tv = {"turn on the tv", "turn off the tv", "channel 5"};
  const std::vector<std::string> music = {"play music", "stop the music", "volume up"};
  auto t0 = Clock::now();
  recognizer.set_phrases(tv);
  const auto first = Clock::now() - t0;
  recognizer.set_phrases(music);
  EXPECT_EQ(recognizer.recognize(said("channel 5")).reason, "not a known phrase");
  t0 = Clock::now();
  recognizer.set_phrases(tv);
  const auto again = Clock::now() - t0;
  EXPECT_LT(again, first);
  const Recognition r = recognizer.recognize(said("channel 5"));
  EXPECT_TRUE(r.recognized) << r.reason;
  EXPECT_EQ(r.text, "channel 5");
}

TEST(Recognizer, MinConfidenceRejectsWhatIsNotSureEnough) {
  Recognizer recognizer(RecognizerOptions{.model_dir = {}, .min_confidence = 1.01});
  recognizer.set_phrases(kCommands);
  const Recognition r = recognizer.recognize(said("play music"));
  EXPECT_FALSE(r.recognized);
  EXPECT_EQ(r.text, "play music");  // what it would have been
  EXPECT_EQ(r.reason.rfind("low confidence ", 0), 0u) << r.reason;
}

TEST(Recognizer, AReverberationTimeItCannotUseIsAnErrorNamingIt) {
  for (const double rt60 : {-1.0, 0.01, 9.0}) {
    const std::string message = error_of([&] { Recognizer(RecognizerOptions{.model_dir = {}, .min_confidence = 0.3, .room_rt60 = rt60}); });
    EXPECT_NE(message.find("room_rt60"), std::string::npos) << message;
  }
  // A living room's reverberation suppressed before decoding: the commands said across it.
  Recognizer in_a_room(RecognizerOptions{.model_dir = {}, .min_confidence = 0.3, .room_rt60 = 0.4});
  in_a_room.set_phrases(kCommands);
  int right = 0;
  for (const auto& command : kCommands) {
    const Recognition r = in_a_room.recognize(said_across_the_room(command, "en-us", 11));
    if (r.recognized) {
      EXPECT_EQ(r.text, command);
    }
    right += r.recognized && r.text == command ? 1 : 0;
  }
  EXPECT_GE(right, static_cast<int>(kCommands.size()) - 2);
}

TEST(Recognizer, AMissingModelIsAnErrorNamingIt) {
  const std::string message =
      error_of([] { Recognizer(RecognizerOptions{.model_dir = "/nonexistent/model"}); });
  EXPECT_NE(message.find("/nonexistent/model/en-us/mdef"), std::string::npos) << message;
  EXPECT_NE(message.find("pocketsphinx-en-us"), std::string::npos) << message;
}

}  // namespace
}  // namespace icars::audio
