#include "icars/audio/recognizer.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <pocketsphinx.h>
#include <sphinxbase/ckd_alloc.h>
#include <sphinxbase/fsg_model.h>
#include <sphinxbase/logmath.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <chrono>
#include <cmath>
#include <deque>
#include <filesystem>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>

#include "icars/audio/acoustics.h"
#include "icars/audio/resample.h"

namespace icars::audio {
namespace {

using Clock = std::chrono::steady_clock;

// The out-of-grammar alternative: frequent short English words, all in cmudict. Speech that is
// none of the phrases fits a loop of them better than any phrase and comes out as "not a known
// phrase". A dictionary without some of them (another model_dir) just has a smaller loop.
constexpr std::array kFillerWords = {
    "a",     "about",  "after", "again", "air",   "all",    "also",  "always", "am",    "an",
    "and",   "any",    "are",   "as",    "ask",   "at",     "away",  "back",   "bad",   "be",
    "been",  "before", "best",  "big",   "boy",   "but",    "by",    "call",   "came",  "can",
    "carry", "change", "cold",  "come",  "could", "cut",    "day",   "did",    "do",    "does",
    "done",  "down",   "each",  "end",   "even",  "every",  "few",   "find",   "first", "food",
    "for",   "from",   "get",   "give",  "go",    "good",   "got",   "great",  "had",   "hand",
    "has",   "have",   "he",    "her",   "here",  "him",    "his",   "how",    "i",     "if",
    "in",    "into",   "is",    "it",    "its",   "just",   "keep",  "knew",   "know",  "large",
    "last",  "late",   "left",  "less",  "let",   "light",  "like",  "line",   "live",  "long",
    "look",  "low",    "made",  "make",  "man",   "many",   "may",   "me",     "mean",  "men",
    "might", "more",   "most",  "move",  "much",  "must",   "my",    "name",   "near",  "need",
    "new",   "next",   "night", "no",    "not",   "now",    "of",    "off",    "old",   "on",
    "once",  "only",   "open",  "or",    "our",   "out",    "over",  "own",    "part",  "play",
    "point", "put",    "read",  "real",  "red",   "right",  "room",  "run",    "said",  "same",
    "saw",   "say",    "see",   "set",   "she",   "should", "small", "so",     "some",  "soon",
    "start", "still",  "such",  "sun",   "take",  "talk",   "tell",  "than",   "that",  "the",
    "their", "them",   "then",  "there", "these", "they",   "thing", "think",  "this",  "those",
    "three", "time",   "to",    "told",  "too",   "took",   "try",   "turn",   "two",   "up",
    "us",    "use",    "very",  "want",  "was",   "way",    "we",    "well",   "went",  "were",
    "what",  "when",   "where", "which", "while", "who",    "why",   "will",   "with",  "word",
    "work",  "would",  "write", "year",  "yes",   "you",    "your",
};

// How the grammar weighs its two alternatives: a phrase costs log((1 - kFillerPrior) / phrases),
// the first filler word log(kFillerPrior / words) and every further one log(kFillerGoOn /
// words), all times the language weight (-lw). Measured with six espeak-ng voices: a prior of
// 0.02 keeps short commands ("stop") from losing to a filler word while sentences that are no
// command still fall into the loop (1 of 66 accepted, "turn on the oven" as "turn on the tv").
constexpr double kFillerPrior = 0.02;
// Words of courtesy a phrase may be wrapped in ("please turn on the tv", "lights on please"):
// each side has one with this probability. They are left out of what is reported.
constexpr double kCourtesyPrior = 0.1;
const std::vector<std::string> kCourtesyBefore = {"please", "hey", "now", "okay"};
const std::vector<std::string> kCourtesyAfter = {"please", "now", "thanks"};
constexpr double kFillerGoOn = 0.5;
// Confidence of a phrase = 1 / (1 + exp(-margin / kConfidenceScale)), the margin being how much
// better the phrase explains the audio than the best sequence of filler words: path scores
// (PocketSphinx's scaled log likelihoods, grammar costs included) per frame of the phrase's
// words. 0.5 is a tie; the phrase can win with less when the search pruned the filler paths.
constexpr double kConfidenceScale = 2.0;
// Wider than PocketSphinx's defaults (1e-48, 7e-29): the filler loop must survive next to a
// phrase until the end of the utterance, or a sentence that begins like a phrase cannot reach
// the grammar's end at all (false accepts measured: 5 of 66 with the defaults, 1 with these).
constexpr const char* kBeam = "1e-60";
constexpr const char* kWordBeam = "1e-40";
// See add_noise_floor: 50 dB under the loudest 20 ms. Raw espeak-ng commands (six voices):
// 37 of 48 recognized without a floor, 45 with it.
constexpr double kNoiseFloorDb = 50.0;
// No speech: the loudest 20 ms quieter than kSilenceDbfs (digital silence, a dead line), or
// less than kSpeechRangeDb above the quietest 20 ms (steady noise: a fan, a quiet room's hiss;
// speech rises 20 dB and more above its own pauses). A level alone would refuse a voice far
// away or behind a wall, which the voice-activity detector upstream has already found.
constexpr double kSilenceDbfs = -90.0;
constexpr double kSpeechRangeDb = 10.0;
// Longest utterance decoded: the decoder keeps all of it (batch cepstral mean normalisation).
constexpr double kMaxUtteranceSeconds = 60.0;
constexpr std::size_t kCachedGrammars = 16;
constexpr const char* kDictationSearch = "dictation";
constexpr const char* kFillerSearch = "fillers";

std::string normalise(const std::string& text) {
  std::string out;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    const auto word_char = [&](std::size_t at) {
      return at < text.size() && std::isalnum(static_cast<unsigned char>(text[at]));
    };
    // Letters, digits, UTF-8 and an apostrophe inside a word ("what's") stay; the rest parts words.
    if (std::isalnum(c) || c >= 0x80 ||
        (c == '\'' && i > 0 && word_char(i - 1) && word_char(i + 1))) {
      out.push_back(static_cast<char>(std::tolower(c)));
    } else if (!out.empty() && out.back() != ' ') {
      out.push_back(' ');
    }
  }
  if (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

std::string number_words(int n) {
  static constexpr std::array<const char*, 20> kOnes = {
      "zero",     "one",     "two",     "three",     "four",     "five",    "six",
      "seven",    "eight",   "nine",    "ten",       "eleven",   "twelve",  "thirteen",
      "fourteen", "fifteen", "sixteen", "seventeen", "eighteen", "nineteen"};
  static constexpr std::array<const char*, 10> kTens = {
      "", "", "twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety"};
  const auto at = [](int i) { return static_cast<std::size_t>(i); };
  if (n < 20) return kOnes[at(n)];
  if (n < 100) {
    return std::string(kTens[at(n / 10)]) +
           (n % 10 != 0 ? std::string(" ") + kOnes[at(n % 10)] : "");
  }
  return std::string(kOnes[at(n / 100)]) + " hundred" +
         (n % 100 != 0 ? " " + number_words(n % 100) : "");
}

std::vector<std::string> split(const std::string& text) {
  std::vector<std::string> words;
  std::istringstream in(text);
  for (std::string w; in >> w;) words.push_back(w);
  return words;
}

std::string join(const std::vector<std::string>& words) { return fmt::format("{}", fmt::join(words, " ")); }

// Ways of saying a word the American dictionary (cmudict) leaves out, for the words of the
// phrases (a short phrase said otherwise than the dictionary says loses to the filler loop):
// the LOT vowel rounded, as British English and many voices say it, each AA also as AO ("stop"
// S T AA P as S T AO P). (A final plosive released into a vowel, S T AA P AH, was tried too:
// its last vowel stretched over the rest of "stop by the shop later".) Returns those not among
// `known` (phone strings, as the dictionary has them).
std::vector<std::string> pronunciation_variants(const std::vector<std::string>& known) {
  std::vector<std::string> out;
  for (const auto& pron : known) {
    auto phones = split(pron);
    if (std::find(phones.begin(), phones.end(), "AA") == phones.end()) continue;
    std::replace(phones.begin(), phones.end(), std::string("AA"), std::string("AO"));
    auto text = join(phones);
    if (std::find(known.begin(), known.end(), text) == known.end() &&
        std::find(out.begin(), out.end(), text) == out.end()) {
      out.push_back(std::move(text));
    }
  }
  return out;
}

// "<sil>", "[NOISE]", "<s>": what the decoder puts between words.
bool is_filler_token(const char* word) { return word[0] == '<' || word[0] == '['; }

struct ConfigDeleter {
  void operator()(cmd_ln_t* c) const { cmd_ln_free_r(c); }
};
struct DecoderDeleter {
  void operator()(ps_decoder_t* d) const { ps_free(d); }
};

// One pass of the decoder over an utterance.
struct Pass {
  std::string words;          // the hypothesis, or "" if there is none
  bool complete = false;      // the path reached the grammar's end (else `words` is partial)
  std::int32_t score = 0;     // its path score
  int speech_frames = 0;      // frames of its words (silence and noise tokens left out)
  double word_posterior = 0;  // the mean of its words' lattice posteriors
};

}  // namespace

std::string spoken_form(const std::string& phrase) {
  std::string out;
  for (const auto& word : split(normalise(phrase))) {
    const bool number = word.size() <= 3 && std::all_of(word.begin(), word.end(), [](char c) {
                          return c >= '0' && c <= '9';
                        });
    out += (out.empty() ? "" : " ") + (number ? number_words(std::stoi(word)) : word);
  }
  return out;
}

// `heard` without a word of courtesy before or after the phrase.
static std::string without_courtesy(const std::string& heard) {
  auto words = split(heard);
  const auto is = [](const std::vector<std::string>& set, const std::string& w) {
    return std::find(set.begin(), set.end(), w) != set.end();
  };
  if (words.size() > 1 && is(kCourtesyBefore, words.front())) words.erase(words.begin());
  if (words.size() > 1 && is(kCourtesyAfter, words.back())) words.pop_back();
  return join(words);
}

struct Recognizer::Impl {
  RecognizerOptions options;
  std::unique_ptr<cmd_ln_t, ConfigDeleter> config;
  std::unique_ptr<ps_decoder_t, DecoderDeleter> decoder;  // after `config`: freed before it
  std::vector<std::string> fillers;                       // kFillerWords in the dictionary
  std::set<std::string> varied;                           // words add_variants has seen
  std::map<std::string, std::string> rivals;              // grammar search → its filler search
  std::map<std::string, std::string> filler_searches;     // filler words, joined → search name
  int next_filler_search = 0;

  std::vector<std::string> phrases;
  std::map<std::string, std::string> phrase_of;  // spoken form → the phrase as given
  std::map<std::string, std::string> grammars;   // spoken forms, one a line → search name
  std::deque<std::string> grammar_order;         // keys of `grammars`, oldest first
  std::string search;                            // the search of the current vocabulary
  int next_grammar = 0;

  // The utterance in progress: `pending` is audio of `format` not yet resampled, `utterance`
  // what the decoder gets (kSpeechRate, mono).
  bool started = false;
  AudioFormat format{};
  std::vector<float> pending;
  std::vector<std::int16_t> utterance;
  double fed_seconds = 0;
  Clock::duration spent{};

  bool in_dictionary(const std::string& word) {
    char* phones = ps_lookup_word(decoder.get(), word.c_str());
    if (phones == nullptr) return false;
    ckd_free(phones);
    return true;
  }

  // The pronunciations the dictionary holds for `word`: "word", "word(2)", ...
  std::vector<std::string> pronunciations(const std::string& word) {
    std::vector<std::string> out;
    for (int n = 1;; ++n) {
      const std::string key = n == 1 ? word : fmt::format("{}({})", word, n);
      char* phones = ps_lookup_word(decoder.get(), key.c_str());
      if (phones == nullptr) break;
      out.emplace_back(phones);
      ckd_free(phones);
    }
    return out;
  }

  // Gives a phrase's word the pronunciation_variants of its dictionary pronunciations, as
  // alternatives the grammar search uses (-fsgusealtpron); the result names the word either way.
  void add_variants(const std::string& word) {
    if (!varied.insert(word).second) return;
    auto known = pronunciations(word);
    for (const auto& variant : pronunciation_variants(known)) {
      const auto key = fmt::format("{}({})", word, known.size() + 1);
      if (ps_add_word(decoder.get(), key.c_str(), variant.c_str(), FALSE) < 0) {
        throw AudioError("PocketSphinx did not accept the pronunciation " + variant + " of \"" + word + "\"");
      }
      known.push_back(variant);
    }
  }

  // Transition log probability in the FSG's units (log base of the decoder, times -lw).
  std::int32_t fsg_logp(double p) const {
    const float lw = cmd_ln_float32_r(config.get(), "-lw");
    return static_cast<std::int32_t>(
        static_cast<double>(logmath_log(ps_get_logmath(decoder.get()), p)) * lw);
  }

  // The filler loop from `from` into `loop` (which then loops on itself).
  void add_filler_loop(fsg_model_t* fsg, int from, int loop, const std::vector<std::string>& words) const {
    const double n = static_cast<double>(words.size());
    for (const auto& word : words) {
      const int wid = fsg_model_word_add(fsg, word.c_str());
      fsg_model_trans_add(fsg, from, loop, fsg_logp(kFillerPrior / n), wid);
      fsg_model_trans_add(fsg, loop, loop, fsg_logp(kFillerGoOn / n), wid);
    }
  }

  void add_search(fsg_model_t* fsg, const std::string& name, const std::string& what) {
    glist_free(fsg_model_null_trans_closure(fsg, nullptr));
    const int added = ps_set_fsg(decoder.get(), name.c_str(), fsg);
    fsg_model_free(fsg);  // the search holds its own reference
    if (added != 0) throw AudioError("PocketSphinx did not accept the grammar of " + what);
  }

  // The vocabulary as a finite-state grammar, the equivalent of the JSGF
  //   public <utterance> = <phrase> | <filler>+;
  // built with sphinxbase's FSG calls rather than its JSGF compiler: in 0.8+5prealpha that gives
  // every alternative probability 1, ignores /weights/ and links a repetition back to the
  // grammar's start, so a 200-word loop costs no more than a phrase and wins nearly always.
  // States: 0 start, 1 end, 2 inside the filler loop (a null transition leads on to the end),
  // then the states inside the phrases.
  void use_grammar(const std::vector<std::string>& spoken) {
    std::string key;
    for (const auto& form : spoken) key += form + '\n';
    if (const auto hit = grammars.find(key); hit != grammars.end()) {
      search = hit->second;
      return;
    }
    // Beside the phrases, a word of courtesy may come before and after one ("lights on please"):
    // states kBefore (a phrase starts) and kAfter (a phrase ended).
    constexpr int kStart = 0, kEnd = 1, kLoop = 2, kBefore = 3, kAfter = 4;
    int states = 5;
    for (const auto& form : spoken) states += static_cast<int>(split(form).size()) - 1;
    const std::string name = "grammar" + std::to_string(next_grammar++);
    fsg_model_t* fsg = fsg_model_init(name.c_str(), ps_get_logmath(decoder.get()),
                                      cmd_ln_float32_r(config.get(), "-lw"), states);
    fsg->start_state = kStart;
    fsg->final_state = kEnd;
    int next_state = 5;
    const std::int32_t phrase_logp =
        fsg_logp((1 - kFillerPrior) / static_cast<double>(spoken.size()));
    for (const auto& form : spoken) {
      const auto words = split(form);
      int from = kBefore;
      for (std::size_t i = 0; i < words.size(); ++i) {
        const int to = i + 1 == words.size() ? kAfter : next_state++;
        fsg_model_trans_add(fsg, from, to, i == 0 ? phrase_logp : 0,
                            fsg_model_word_add(fsg, words[i].c_str()));
        from = to;
      }
    }
    const auto courtesy = [&](int from, int to, const std::vector<std::string>& words) {
      fsg_model_null_trans_add(fsg, from, to, fsg_logp(1 - kCourtesyPrior));
      for (const auto& word : words) {
        if (!in_dictionary(word)) continue;
        fsg_model_trans_add(fsg, from, to, fsg_logp(kCourtesyPrior / static_cast<double>(words.size())),
                            fsg_model_word_add(fsg, word.c_str()));
      }
    };
    courtesy(kStart, kBefore, kCourtesyBefore);
    courtesy(kAfter, kEnd, kCourtesyAfter);
    const auto loop_words = fillers_beside(spoken);
    add_filler_loop(fsg, kStart, kLoop, loop_words);
    fsg_model_null_trans_add(fsg, kLoop, kEnd, 0);
    add_search(fsg, name, "phrases " + key);
    rivals[name] = filler_search(loop_words);

    if (grammar_order.size() >= kCachedGrammars) {
      const auto oldest = grammars.at(grammar_order.front());
      ps_unset_search(decoder.get(), oldest.c_str());
      grammars.erase(grammar_order.front());
      grammar_order.pop_front();
      // Its filler search goes too when no other grammar is measured against it.
      const auto rival = rivals.at(oldest);
      rivals.erase(oldest);
      if (std::none_of(rivals.begin(), rivals.end(), [&](const auto& r) { return r.second == rival; })) {
        ps_unset_search(decoder.get(), rival.c_str());
        std::erase_if(filler_searches, [&](const auto& f) { return f.second == rival; });
      }
    }
    grammars.emplace(key, name);
    grammar_order.push_back(key);
    search = name;
  }

  // The filler words of the loop beside `spoken`: all of them but those a one-word phrase could
  // be taken for when its sounds are blurred. A filler word whose phones are a subsequence of
  // the phrase's (one of its pronunciations, with its variants) loses only what a room blurs
  // first, a plosive's closure or release: in a reverberant room "stop" (S T AA P) was heard as
  // "saw" (S AO) in 3 to 5 of 10 trials. Longer phrases keep every filler word: one word cannot
  // stand for them, and dropping a word from a sequence only moves the loop to another.
  std::vector<std::string> fillers_beside(const std::vector<std::string>& spoken) {
    std::vector<std::vector<std::string>> single;  // the one-word phrases' pronunciations
    for (const auto& form : spoken) {
      if (split(form).size() != 1) continue;
      for (const auto& pron : pronunciations(form)) single.push_back(split(pron));
    }
    if (single.empty()) return fillers;
    const auto within = [](const std::vector<std::string>& part, const std::vector<std::string>& whole) {
      std::size_t at = 0;
      for (const auto& phone : whole) {
        if (at < part.size() && part[at] == phone) ++at;
      }
      return at == part.size();
    };
    std::vector<std::string> out;
    for (const auto& word : fillers) {
      bool blurred = false;
      for (const auto& pron : pronunciations(word)) {
        const auto phones = split(pron);
        // One phone ("a", AH) is inside nearly every word and stands for none of them.
        for (const auto& phrase : single) {
          blurred = blurred || (phones.size() >= 2 && phones.size() < phrase.size() && within(phones, phrase));
        }
      }
      if (!blurred) out.push_back(word);
    }
    return out;
  }

  // The filler loop alone, of `words`: what the confidence of a phrase is measured against (the
  // same words as the loop beside the phrases). One search per set of words.
  std::string filler_search(const std::vector<std::string>& words) {
    const auto key = join(words);
    if (const auto hit = filler_searches.find(key); hit != filler_searches.end()) return hit->second;
    const std::string name = std::string(kFillerSearch) + std::to_string(next_filler_search++);
    constexpr int kStart = 0, kEnd = 1, kLoop = 2;
    fsg_model_t* fsg = fsg_model_init(name.c_str(), ps_get_logmath(decoder.get()),
                                      cmd_ln_float32_r(config.get(), "-lw"), 3);
    fsg->start_state = kStart;
    fsg->final_state = kEnd;
    add_filler_loop(fsg, kStart, kLoop, words);
    fsg_model_null_trans_add(fsg, kLoop, kEnd, 0);
    add_search(fsg, name, "the filler words");
    filler_searches.emplace(key, name);
    return name;
  }

  void use_language_model() {
    if (ps_get_lm(decoder.get(), kDictationSearch) == nullptr) {
      const std::string lm = options.model_dir + "/en-us.lm.bin";
      if (ps_set_lm_file(decoder.get(), kDictationSearch, lm.c_str()) != 0) {
        throw AudioError("PocketSphinx could not load the language model " + lm +
                         " (apt install pocketsphinx-en-us)");
      }
    }
    search = kDictationSearch;
  }

  void append(const AudioBlock& piece) {
    if (piece.format.channels <= 0) {
      throw AudioError("audio with " + std::to_string(piece.format.channels) +
                       " channels: the recognizer needs at least one");
    }
    if (piece.format.sample_rate < kMinSampleRate || piece.format.sample_rate > kMaxSampleRate) {
      throw AudioError("audio at " + std::to_string(piece.format.sample_rate) +
                       " Hz: the recognizer takes " + std::to_string(kMinSampleRate) + ".." +
                       std::to_string(kMaxSampleRate) + " Hz");
    }
    if (!pending.empty() && piece.format != format) flush_pending();
    format = piece.format;
    fed_seconds += piece.seconds();
    if (fed_seconds > kMaxUtteranceSeconds) {
      throw AudioError(
          fmt::format("an utterance of more than {:g} s: cut long captures into "
                      "utterances first (VoiceActivityDetector)",
                      kMaxUtteranceSeconds));
    }
    const Signal mono = mix_down(piece);
    pending.insert(pending.end(), mono.samples.begin(), mono.samples.end());
  }

  // Audio is resampled in one go when its format changes or the utterance ends: pieces
  // resampled one by one would each have the filter's edge effects.
  void flush_pending() {
    if (pending.empty()) return;
    const Signal at_rate = resample(Signal{format.sample_rate, std::move(pending)}, kSpeechRate);
    pending.clear();
    for (const float v : at_rate.samples) utterance.push_back(to_pcm16(v));
  }

  void reset() {
    started = false;
    pending.clear();
    utterance.clear();
    fed_seconds = 0;
    spent = {};
  }


  // The quietest and loudest whole 20 ms frames (dBFS RMS); a shorter utterance counts whole.
  std::pair<double, double> frame_levels() const {
    double quietest = 0, loudest = -120;
    const std::size_t frame = kSpeechRate / 50;
    for (std::size_t i = 0; i < utterance.size(); i += frame) {
      const std::size_t n = std::min(frame, utterance.size() - i);
      if (n < frame && i > 0) break;
      const double level = rms_dbfs(std::span(utterance).subspan(i, n));
      loudest = std::max(loudest, level);
      quietest = std::min(quietest, level);
    }
    return {quietest, loudest};
  }

  // Audio cleaner than any microphone delivers (a synthesized voice, digital silence where a
  // capture had a gap) is given a noise floor kNoiseFloorDb under its loudest 20 ms. The
  // en-us model was trained on recordings, whose pauses are never silent: without a floor a
  // pause's log spectrum sits at the floor value and drags the utterance's cepstral mean away
  // from the speech. A recording's own noise is louder than this floor, so it barely changes.
  // Seeded per utterance: a decode is repeatable.
  void add_noise_floor(double loudest) {
    const double rms = 32768.0 * std::pow(10.0, (loudest - kNoiseFloorDb) / 20.0);
    std::minstd_rand random(1);
    std::normal_distribution<double> noise(0.0, std::max(rms, 0.5));
    for (std::int16_t& v : utterance) {
      const double noisy = std::round(v + noise(random));
      v = static_cast<std::int16_t>(std::clamp(noisy, -32768.0, 32767.0));
    }
  }

  // The room's late reverberation out of `utterance` (RecognizerOptions::room_rt60): in a room
  // the tail of each phone covers the next (a plosive's closure, a fricative after a vowel).
  void dereverberate() {
    const AudioBlock heard{AudioFormat{kSpeechRate, 1}, 0, std::move(utterance)};
    utterance = to_block(suppress_late_reverberation(mix_down(heard), Dereverberation{.rt60 = options.room_rt60})).samples;
  }

  // Decodes `utterance` with the search `name`, the whole utterance at once (so that the
  // cepstral mean is the utterance's own, as the en-us model was trained: -cmn batch).
  Pass run(const std::string& name) {
    ps_decoder_t* ps = decoder.get();
    if (ps_set_search(ps, name.c_str()) != 0)
      throw AudioError("PocketSphinx has no search " + name);
    // A new stream each time: the front end's noise estimate is not carried over from the
    // utterance before, so an utterance is decoded the same whatever came first.
    if (ps_start_stream(ps) != 0 || ps_start_utt(ps) != 0) {
      throw AudioError("PocketSphinx did not start an utterance");
    }
    if (ps_process_raw(ps, utterance.data(), utterance.size(), FALSE, TRUE) < 0) {
      ps_end_utt(ps);
      throw AudioError("PocketSphinx failed to decode an utterance");
    }
    // Before the end: the best path wherever it is in the grammar. After the end a grammar
    // search only reports paths that reached the grammar's end, and none may have (a sentence
    // that began like a phrase and went on otherwise).
    const char* partial = ps_get_hyp(ps, nullptr);
    Pass pass;
    pass.words = partial != nullptr ? partial : "";
    ps_end_utt(ps);
    // ps_get_prob before ps_get_hyp: the lattice's posteriors (the utterance's and its words')
    // are computed only if the best path has not been searched yet.
    ps_get_prob(ps);
    if (const char* final_hyp = ps_get_hyp(ps, &pass.score); final_hyp != nullptr) {
      pass.words = final_hyp;
      pass.complete = true;
      double posteriors = 0;
      int words = 0;
      for (ps_seg_t* seg = ps_seg_iter(ps); seg != nullptr; seg = ps_seg_next(seg)) {
        int first = 0, last = 0;
        ps_seg_frames(seg, &first, &last);
        if (!is_filler_token(ps_seg_word(seg))) {
          pass.speech_frames += last - first + 1;
          std::int32_t ascr = 0, lscr = 0, lback = 0;
          posteriors += logmath_exp(ps_get_logmath(ps), ps_seg_prob(seg, &ascr, &lscr, &lback));
          ++words;
        }
      }
      if (words > 0) pass.word_posterior = posteriors / words;
    }
    return pass;
  }

  Recognition decode() {
    const auto begin = Clock::now();
    const auto elapsed = [&] {
      return std::chrono::duration<double>(spent + (Clock::now() - begin)).count();
    };
    flush_pending();
    Recognition r;
    r.speech_seconds = fed_seconds;
    const auto [quietest, loudest] = utterance.empty() ? std::pair{-120.0, -120.0} : frame_levels();
    if (loudest < kSilenceDbfs || loudest - quietest < kSpeechRangeDb) {
      r.reason = "no speech";
      r.decode_seconds = elapsed();
      return r;
    }
    if (options.room_rt60 > 0) dereverberate();
    add_noise_floor(loudest);
    const Pass pass = run(search);
    r.heard = pass.words;
    const bool dictation = search == kDictationSearch;
    if (dictation) {
      r.text = r.heard;
      // With a language model, the mean of the words' lattice posteriors. The utterance's own
      // (ps_get_prob) is tiny for any sentence among a 130,000-word model's alternatives:
      // 0.004 to 0.05 for correctly decoded sentences.
      r.confidence = pass.word_posterior;
    } else if (const auto hit = phrase_of.contains(r.heard) ? phrase_of.find(r.heard) : phrase_of.find(without_courtesy(r.heard));
               pass.complete && hit != phrase_of.end()) {
      r.text = hit->second;
      // With a grammar the lattice posterior is always 1 (5prealpha's FSG lattices hold little
      // but the best path). The confidence is the margin of the phrase over the best sequence
      // of filler words on the same audio, per frame of the phrase's words.
      const Pass rival = run(rivals.at(search));
      const double margin = !rival.complete ? kConfidenceScale * 10  // no other words fit at all
                                            : static_cast<double>(pass.score - rival.score) /
                                                  std::max(1, pass.speech_frames);
      r.confidence = 1 / (1 + std::exp(-margin / kConfidenceScale));
    }
    r.decode_seconds = elapsed();
    if (r.heard.empty()) {
      r.reason = dictation ? "no words heard" : "not a known phrase";
    } else if (!dictation && r.text.empty()) {
      r.reason = "not a known phrase";
    } else if (r.confidence < options.min_confidence) {
      r.reason = fmt::format("low confidence {:.2f}", r.confidence);
    } else {
      r.recognized = true;
    }
    return r;
  }
};

Recognizer::Recognizer(RecognizerOptions options) : impl_(std::make_unique<Impl>()) {
  if (options.model_dir.empty()) options.model_dir = ICARS_POCKETSPHINX_MODEL_DIR;
  const std::string hmm = options.model_dir + "/en-us";
  const std::string dict = options.model_dir + "/cmudict-en-us.dict";
  for (const auto& path : {hmm + "/mdef", dict}) {
    if (!std::filesystem::exists(path)) {
      throw AudioError("PocketSphinx model missing: " + path +
                       " (apt install pocketsphinx-en-us, or set RecognizerOptions::model_dir)");
    }
  }
  if (options.room_rt60 != 0 && !(options.room_rt60 >= kMinDereverberationRt60 && options.room_rt60 <= kMaxRt60)) {
    throw AudioError(fmt::format("RecognizerOptions::room_rt60 {} s: 0 (no dereverberation) or {} to {} s",
                                 options.room_rt60, kMinDereverberationRt60, kMaxRt60));
  }
  impl_->options = std::move(options);
  std::vector<std::string> args = {"icars",  "-hmm",      hmm,      "-dict", dict,
                                   "-logfn", "/dev/null", "-beam",  kBeam,   "-pbeam",
                                   kBeam,    "-wbeam",    kWordBeam};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  impl_->config.reset(cmd_ln_parse_r(nullptr, ps_args(), static_cast<std::int32_t>(argv.size()),
                                     argv.data(), TRUE));
  if (!impl_->config) throw AudioError("PocketSphinx rejected its configuration for " + hmm);
  impl_->decoder.reset(ps_init(impl_->config.get()));
  if (!impl_->decoder) throw AudioError("PocketSphinx could not load the model in " + hmm);
  for (const char* word : kFillerWords) {
    if (impl_->in_dictionary(word)) impl_->fillers.emplace_back(word);
  }
}

Recognizer::~Recognizer() = default;

void Recognizer::set_phrases(const std::vector<std::string>& phrases) {
  std::map<std::string, std::string> phrase_of;
  std::vector<std::string> spoken;
  for (const auto& phrase : phrases) {
    const std::string form = spoken_form(phrase);
    if (form.empty()) throw AudioError("phrase \"" + phrase + "\" has no words");
    for (const auto& word : split(form)) {
      if (!impl_->in_dictionary(word)) {
        throw AudioError("phrase \"" + phrase + "\": the word \"" + word +
                         "\" is not in the recognizer's dictionary; say it with other words");
      }
    }
    if (phrase_of.emplace(form, phrase).second) spoken.push_back(form);
  }
  for (const auto& form : spoken) {
    for (const auto& word : split(form)) impl_->add_variants(word);
  }
  if (spoken.empty()) {
    impl_->use_language_model();
  } else {
    impl_->use_grammar(spoken);
  }
  impl_->phrases = phrases;
  impl_->phrase_of = std::move(phrase_of);
}

const std::vector<std::string>& Recognizer::phrases() const { return impl_->phrases; }

Recognition Recognizer::recognize(const AudioBlock& utterance) {
  start();
  feed(utterance);
  return finish();
}

void Recognizer::start() {
  impl_->reset();
  if (impl_->search.empty()) impl_->use_language_model();
  impl_->started = true;
}

void Recognizer::feed(const AudioBlock& piece) {
  if (!impl_->started) throw std::logic_error("Recognizer::feed() without start()");
  const auto begin = Clock::now();
  try {
    impl_->append(piece);
  } catch (...) {
    impl_->reset();
    throw;
  }
  impl_->spent += Clock::now() - begin;
}

Recognition Recognizer::finish() {
  if (!impl_->started) throw std::logic_error("Recognizer::finish() without start()");
  try {
    Recognition r = impl_->decode();
    impl_->reset();
    return r;
  } catch (...) {
    impl_->reset();
    throw;
  }
}

void Recognizer::cancel() { impl_->reset(); }

}  // namespace icars::audio
