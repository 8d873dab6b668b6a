// Speech recognition with PocketSphinx (Debian's pocketsphinx and pocketsphinx-en-us, through
// its C API): an utterance (decoded as 16 kHz mono PCM) to text, confidence and timing.
//
// A recognizer decodes against a vocabulary of phrases (the commands a policy can act on): its
// grammar is `<phrase> | <filler word>+`, the phrases plus a loop of about 200 common English
// words, so that speech that is none of the phrases comes out as "not recognized" instead of
// the nearest phrase. Phrases are case-insensitive and punctuation is dropped; numbers in
// phrases are spoken as words ("channel 5" is heard as "channel five" and reported as
// "channel 5"). With no phrases it decodes free speech with the en-us language model. The
// acoustic model, dictionary and language model come from the Debian package; nothing is
// downloaded. One decoder per Recognizer, not thread-safe: use one per thread.
//
// Measured with espeak-ng voices (recognizer_test.cc): of the house's 8 commands said in 2
// voices, 15 recognized and none taken for another; sentences that are no command rejected. A
// sentence that differs from a command in its last word only ("turn on the oven") may pass as
// the command.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "icars/audio/pcm.h"

namespace icars::audio {

struct RecognizerOptions {
  std::string model_dir;        // empty: Debian's /usr/share/pocketsphinx/model/en-us
  double min_confidence = 0.3;  // below it a hypothesis counts as not recognized
  // With a reverberation time (0.05 to 5 s; 0.4 s is a furnished living room), the room's late
  // reverberation is suppressed before decoding (suppress_late_reverberation, acoustics.h). 0,
  // the default, decodes the audio as it came: in the simulated room the suppression gained a
  // few points of accuracy and took more near misses for commands (docs/speech.md).
  double room_rt60 = 0;
};

struct Recognition {
  bool recognized = false;  // one of the phrases (or, with no phrases, any words) was heard
  std::string text;         // the phrase as given to set_phrases ("channel 5"), or the words
  std::string heard;        // what the decoder produced ("channel five", "what these that")
  // 0 to 1. A phrase: how much better it explains the audio than the best sequence of filler
  // words, as 1 / (1 + exp(-margin / 2)) with the margin in PocketSphinx's log score per frame
  // of speech (0.5: a tie). Free speech: the mean of the words' lattice posteriors.
  double confidence = 0.0;
  // Why not recognized: "no speech" (empty, digital silence, or steady noise with nothing 10 dB above its quietest 20 ms), "not a known
  // phrase", "no words heard" (free speech), "low confidence 0.12".
  std::string reason;
  double speech_seconds = 0;  // length of the audio decoded
  double decode_seconds = 0;  // wall time (steady clock) spent in feed() and finish()
};

class Recognizer {
 public:
  explicit Recognizer(RecognizerOptions options = {});  // AudioError if the model is missing
  ~Recognizer();
  Recognizer(const Recognizer&) = delete;
  Recognizer& operator=(const Recognizer&) = delete;

  // The vocabulary; cheap to call again with the same phrases (grammars are cached by content,
  // the last 16). No phrases: free speech. AudioError naming a phrase whose word is not in the
  // dictionary (and the word); the vocabulary is then unchanged.
  void set_phrases(const std::vector<std::string>& phrases);
  const std::vector<std::string>& phrases() const;

  // Decodes one utterance (of at most 60 s). Audio of another rate is resampled, several
  // channels are mixed down; AudioError for a rate outside kMinSampleRate..kMaxSampleRate or
  // zero channels. Abandons an utterance begun with start().
  Recognition recognize(const AudioBlock& utterance);

  // Incremental form, for audio that arrives in pieces: start(), feed() each piece as it comes,
  // finish() when the utterance ended (or cancel() when the stream died). The result is the one
  // recognize() gives for the pieces joined: feed() only collects (and mixes down), the decoder
  // runs in finish() over the whole utterance, as its batch cepstral normalisation needs. A
  // piece AudioError rejects ends the utterance; feed() or finish() without start() is a
  // std::logic_error.
  void start();
  void feed(const AudioBlock& piece);
  Recognition finish();
  void cancel();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// "Channel 5!" → "channel five": the words a phrase is spoken as (lower case, punctuation
// dropped, numbers 0..999 spelled out, larger ones left as digits).
std::string spoken_form(const std::string& phrase);

}  // namespace icars::audio
