#include "icars/audio/synthesizer.h"

#include <espeak-ng/speak_lib.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <deque>
#include <map>
#include <mutex>
#include <string_view>
#include <tuple>

#include "icars/audio/resample.h"

namespace icars::audio {
namespace {

constexpr double kPeakDbfs = -3.0;
constexpr int kMinWordsPerMinute = 80;  // espeak-ng's range
constexpr int kMaxWordsPerMinute = 450;
// Sentences kept: at 64 kB a second of speech, a few tens of MB for sentences of seconds.
constexpr std::size_t kCacheEntries = 256;

// espeak-ng is one engine per process: its voice, parameters and synthesis callback are global
// variables of the library. So is this object, the only place that touches them: a
// function-local static (made on first use, terminated at exit) behind one mutex, shared by
// every Synthesizer. It is the one singleton of the layer, and only because the library is one.
class EspeakEngine {
 public:
  static EspeakEngine& instance() {
    static EspeakEngine engine;
    return engine;
  }

  Signal speak(const std::string& text, const Voice& voice) {
    std::lock_guard lock(mutex_);
    const auto key = std::make_tuple(voice.name, voice.words_per_minute, voice.pitch, text);
    if (const auto hit = cache_.find(key); hit != cache_.end()) return hit->second;
    Signal spoken = finish(synthesize(text, voice));
    if (cache_.size() >= kCacheEntries) {
      cache_.erase(order_.front());
      order_.pop_front();
    }
    cache_.emplace(key, spoken);
    order_.push_back(key);
    return spoken;
  }

  std::vector<std::string> voices(const std::string& language) {
    std::lock_guard lock(mutex_);
    espeak_VOICE spec{};
    spec.languages = language.c_str();
    std::vector<std::string> names;
    for (const espeak_VOICE** v = espeak_ListVoices(&spec); v != nullptr && *v != nullptr; ++v) {
      const std::string_view identifier = (*v)->identifier;
      // MBROLA voices need MBROLA; variants ("!v/f3") are added to a voice as "en-us+f3".
      if (identifier.starts_with("mb/") || identifier.starts_with("!v/")) continue;
      // `languages` is a list of (priority byte, name, NUL) ending in an empty name.
      bool speaks = false;
      for (const char* entry = (*v)->languages; entry != nullptr && entry[0] != '\0';) {
        const std::string name(entry + 1);
        speaks = speaks || name == language || name.starts_with(language + "-");
        entry += 1 + name.size() + 1;
      }
      if (!speaks) continue;
      // The voice file's name ("gmw/en-GB-x-rp") is what espeak_SetVoiceByName selects it by,
      // in any case.
      std::string name(identifier.substr(identifier.rfind('/') + 1));
      for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
      names.push_back(std::move(name));
    }
    std::sort(names.begin(), names.end());
    names.erase(std::unique(names.begin(), names.end()), names.end());
    return names;
  }

  EspeakEngine(const EspeakEngine&) = delete;
  EspeakEngine& operator=(const EspeakEngine&) = delete;

 private:
  EspeakEngine() {
    rate_ = espeak_Initialize(AUDIO_OUTPUT_SYNCHRONOUS, 0, nullptr, espeakINITIALIZE_DONT_EXIT);
    if (rate_ <= 0) {
      throw AudioError(
          "espeak-ng did not start: is espeak-ng-data installed (apt install espeak-ng-data)?");
    }
    espeak_SetSynthCallback(&EspeakEngine::on_samples);
  }
  ~EspeakEngine() { espeak_Terminate(); }

  // espeak-ng quietly ignores a variant it does not know ("en-us+nosuch" speaks as en-us).
  static bool has_variant(const std::string& name) {
    const auto plus = name.find('+');
    if (plus == std::string::npos) return true;
    espeak_VOICE spec{};
    spec.languages = "variant";
    for (const espeak_VOICE** v = espeak_ListVoices(&spec); v != nullptr && *v != nullptr; ++v) {
      if (std::string_view((*v)->identifier) == "!v/" + name.substr(plus + 1)) return true;
    }
    return false;
  }

  // Called by espeak_Synth on this thread, with the vector passed as its user data.
  static int on_samples(short* wav, int count, espeak_EVENT* events) {
    if (wav != nullptr && count > 0 && events != nullptr && events->user_data != nullptr) {
      auto* out = static_cast<std::vector<float>*>(events->user_data);
      for (int i = 0; i < count; ++i) out->push_back(static_cast<float>(wav[i]) / 32767.0f);
    }
    return 0;  // go on
  }

  Signal synthesize(const std::string& text, const Voice& voice) {
    if (text.find_first_not_of(" \t\r\n") == std::string::npos) {
      throw AudioError("nothing to say: the text is empty");
    }
    if (voice.pitch < 0 || voice.pitch > 99) {
      throw AudioError("voice " + voice.name + ": pitch " + std::to_string(voice.pitch) +
                       " is outside 0..99");
    }
    if (voice.words_per_minute < kMinWordsPerMinute ||
        voice.words_per_minute > kMaxWordsPerMinute) {
      throw AudioError("voice " + voice.name + ": " + std::to_string(voice.words_per_minute) +
                       " words per minute is outside " + std::to_string(kMinWordsPerMinute) + ".." +
                       std::to_string(kMaxWordsPerMinute));
    }
    if (voice.name.empty() || !has_variant(voice.name) ||
        espeak_SetVoiceByName(voice.name.c_str()) != EE_OK) {
      throw AudioError(
          "espeak-ng has no voice \"" + voice.name +
          "\" (`espeak-ng --voices=en` lists them; a variant is added as \"en-us+f3\")");
    }
    espeak_SetParameter(espeakRATE, voice.words_per_minute, 0);
    espeak_SetParameter(espeakPITCH, voice.pitch, 0);
    Signal raw{rate_, {}};
    const espeak_ERROR error = espeak_Synth(text.c_str(), text.size() + 1, 0, POS_CHARACTER, 0,
                                            espeakCHARS_UTF8, nullptr, &raw.samples);
    if (error != EE_OK) {
      throw AudioError("espeak-ng failed (error " + std::to_string(static_cast<int>(error)) +
                       ") to say \"" + text + "\" in voice " + voice.name);
    }
    return raw;
  }

  // At kSpeechRate, without the silence espeak-ng puts around a sentence, peak at kPeakDbfs.
  static Signal finish(const Signal& raw) {
    Signal out = resample(raw, kSpeechRate);
    float peak = 0;
    for (const float v : out.samples) peak = std::max(peak, std::abs(v));
    if (peak <= 0) return Signal{kSpeechRate, {}};
    // Silence is what stays 50 dB under the peak; 10 ms of it is kept on either side so that
    // a word's onset and release are not cut.
    const float floor = peak * 0.00316f;
    const auto loud = [floor](float v) { return std::abs(v) > floor; };
    const auto first = std::find_if(out.samples.begin(), out.samples.end(), loud);
    const auto last = std::find_if(out.samples.rbegin(), out.samples.rend(), loud).base();
    const std::ptrdiff_t margin = kSpeechRate / 100;
    const auto begin = first - std::min(margin, first - out.samples.begin());
    const auto end = last + std::min(margin, out.samples.end() - last);
    std::vector<float> trimmed(begin, end);
    const auto gain = static_cast<float>(std::pow(10.0, kPeakDbfs / 20.0) / peak);
    for (float& v : trimmed) v *= gain;
    out.samples = std::move(trimmed);
    return out;
  }

  std::mutex mutex_;
  int rate_ = 0;
  using Key = std::tuple<std::string, int, int, std::string>;  // voice, rate, pitch, text
  std::map<Key, Signal> cache_;
  std::deque<Key> order_;  // oldest first: the first to go when the cache is full
};

}  // namespace

Synthesizer::Synthesizer() { EspeakEngine::instance(); }
Synthesizer::~Synthesizer() = default;

Signal Synthesizer::speak(const std::string& text, const Voice& voice) {
  return EspeakEngine::instance().speak(text, voice);
}

std::vector<std::string> Synthesizer::voices(const std::string& language) {
  return EspeakEngine::instance().voices(language);
}

}  // namespace icars::audio
