// Speech synthesis with espeak-ng (its C library): a sentence in a named voice as a 16 kHz mono
// signal, what the simulated users' voices are made of. espeak-ng keeps global state, so every
// Synthesizer of a process shares one engine behind a lock; results are cached by voice and
// text (a simulated user says the same few sentences every day). espeak-ng's wave generator
// keeps state from one sentence to the next, so a sentence synthesized afresh differs from an
// earlier synthesis by a few samples; the cache hands out the first one every time after.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "icars/audio/pcm.h"

namespace icars::audio {

struct Voice {
  std::string name = "en-us";  // an espeak-ng voice, optionally with a variant: "en-us+f3", "en"
  int words_per_minute = 160;
  int pitch = 50;  // 0..99
  bool operator==(const Voice&) const = default;
};

class Synthesizer {
 public:
  Synthesizer();
  ~Synthesizer();
  Synthesizer(const Synthesizer&) = delete;
  Synthesizer& operator=(const Synthesizer&) = delete;

  // `text` spoken by `voice`, at kSpeechRate, peak-normalised to -3 dBFS, without leading or
  // trailing silence (10 ms are kept). AudioError for an unknown voice or variant, empty text,
  // a pitch outside 0..99 or a rate outside 80..450 words per minute. Thread-safe.
  Signal speak(const std::string& text, const Voice& voice = {});
  // The voices espeak-ng offers for `language` ("en": en, en-us, en-gb-x-rp, ...), sorted;
  // each is a Voice::name. MBROLA voices (not installed with espeak-ng) and variants (added to
  // a name: "en-us+f3") are not listed.
  static std::vector<std::string> voices(const std::string& language = "en");
};

}  // namespace icars::audio
