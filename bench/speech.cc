// The house's voice commands as a user meets them: spoken by espeak-ng voices at a distance from
// one microphone in a reverberant room with background noise, cut by the voice-activity detector
// and decoded by the recognizer against the house's vocabulary (a plain program printing a
// markdown table).
//
//   speech_bench [--runs 3] [--voices en-us,en-us+f3,en] [--distances 1,2,4,6] [--noise 30,50]
//                [--rt60 0.4] [--min-confidence 0.3] [--vad-threshold-db 9] [--hangover-ms 400]
//                [--model-dir DIR]
//                [--array 4 [--array-radius 0.08] [--bearing 30] [--steer]] [--quick] [--details]
//
// The vocabulary is what the paper policy's voice behaviors act on (VoiceTVControl and
// VoiceAudioControl in src/home/behaviors.cc); the sentences are what the simulated user says in
// houses/paper_house.xml and a few more of the vocabulary, plus sentences outside it that must
// come out not recognized. One trial, per voice, distance, noise level, sentence and run:
//   synthesize   Synthesizer::speak(sentence, voice);
//   render       render() on one path {distance d, level 60 - 20 log10(d) dB SPL} in a room of
//                --rt60 (0.4 s), critical distance 1 m and --noise dB SPL of noise, with 0.5 s of
//                lead and 0.8 s of tail, after 1 s of the room's noise (the detector learns its
//                noise floor) and before 1 s more (it hears the end as a microphone does);
//   detect       the capture fed to a VoiceActivityDetector in 20 ms blocks, as a microphone
//                delivers it; flushed at the end;
//   recognize    Recognizer::recognize of every utterance it cut.
// With --array N the talker stands at --bearing from the centre of N microphones on a circle
// (one path to each, each with its own reverberation and noise); the detector gets every
// channel, and each utterance is recognized mixed down (its channels averaged) or, with
// --steer, beamformed: delay-and-sum (steer_towards) towards the direction estimate_direction
// finds in it, as the robot's four microphones can.
// Every run uses other noise and reverberation seeds. Measured per (voice, distance, noise), the
// trials pooled over the runs:
//   detected          trials where the detector cut at least one utterance;
//   command accuracy  trials where exactly one utterance was recognized and its phrase has the
//                     effect of the spoken one (house_effects); the range is that of the runs;
//   wrong command     trials where a phrase was recognized but the devices would not do what was
//                     said (another effect, or more than one utterance recognized); the rest of
//                     the trials came out not recognized, which does nothing;
//   WER               word-level edit distance between the sentence and the recognized phrases,
//                     both in spoken form ("channel five"), over all words said;
//   OOV accepted      out-of-vocabulary sentences for which a phrase was recognized;
// and per run, printed as the median over the runs (the machine's other work disturbs them):
//   latency           from the end of the voice at the microphone to the recognition: audio time
//                     until the 20 ms block after which the detector returned the utterance
//                     (its hangover), plus the wall time of Recognizer::recognize; median, p95;
//   RTF               wall time of recognize() / seconds of the utterance, median;
//   CPU               process CPU time of detection and recognition per second of audio fed to
//                     the detector, in percent of one core.
#include <fmt/format.h>
#include <time.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <map>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.h"
#include "icars/audio/acoustics.h"
#include "icars/audio/direction.h"
#include "icars/audio/recognizer.h"
#include "icars/audio/synthesizer.h"
#include "icars/audio/vad.h"

namespace {

namespace a = icars::audio;
using Clock = std::chrono::steady_clock;

// What each phrase of the house's vocabulary makes the devices do. Phrases with the same effect
// are interchangeable: "tv on" heard for "turn on the TV" is a correct command. "volume up" moves
// the TV's and the music's volume (both behaviors act on it); "tv volume up" only the TV's.
std::map<std::string, std::string> house_effects() {
  std::map<std::string, std::string> effects = {
      {"turn on the tv", "tv.power(on)"},
      {"tv on", "tv.power(on)"},
      {"turn off the tv", "tv.power(off)"},
      {"tv off", "tv.power(off)"},
      {"volume up", "tv+music.volume(up)"},
      {"volume down", "tv+music.volume(down)"},
      {"tv volume up", "tv.volume(up)"},
      {"tv volume down", "tv.volume(down)"},
      {"music volume up", "music.volume(up)"},
      {"music volume down", "music.volume(down)"},
      {"play music", "music.play"},
      {"play some music", "music.play"},
      {"play a song", "music.play"},
      {"stop", "music.stop"},
      {"stop the music", "music.stop"},
      {"stop music", "music.stop"},
  };
  for (int n = 1; n <= 30; ++n)
    effects.emplace(fmt::format("channel {}", n), fmt::format("tv.channel({})", n));
  return effects;
}

// What the simulated user says in houses/paper_house.xml, then more of the vocabulary.
const std::vector<std::string> kCommands = {
    "turn on the TV",  "channel 5",  "volume up",   "play music",     "stop",
    "turn off the TV", "channel 12", "volume down", "stop the music", "channel 23"};
// None of the vocabulary: these must come out not recognized. Some are near a command (a phrase
// inside a longer sentence, a word that sounds like a short command, a device the house does
// not have), as a person talking in the room would be.
const std::vector<std::string> kOutOfVocabulary = {
    "what time is it", "open the window", "good night",       "stop by the shop later",
    "turn on the oven", "so",             "all right",        "I saw it on TV",
    "thank you",        "what channel is this", "call mom",   "the music was nice"};

constexpr double kLeadNoise = 1.0;   // s of the room before the utterance's render
constexpr double kTrailNoise = 1.0;  // s after it
constexpr double kRenderLead = 0.5;
constexpr double kRenderTail = 0.8;
constexpr double kLevelAt1m = 60.0;                        // dB SPL of the voice at 1 m
constexpr std::size_t kBlockFrames = a::kSpeechRate / 50;  // 20 ms, as a microphone delivers it

std::string lower(std::string s) {
  for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

std::vector<std::string> words(const std::string& text) {
  std::vector<std::string> out;
  std::size_t at = 0;
  while (at < text.size()) {
    const auto end = std::min(text.find(' ', at), text.size());
    if (end > at) out.push_back(text.substr(at, end - at));
    at = end + 1;
  }
  return out;
}

// Word-level Levenshtein distance.
std::size_t edit_distance(const std::vector<std::string>& ref,
                          const std::vector<std::string>& hyp) {
  std::vector<std::size_t> row(hyp.size() + 1);
  for (std::size_t j = 0; j <= hyp.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= ref.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= hyp.size(); ++j) {
      const std::size_t up = row[j];
      row[j] =
          std::min({row[j] + 1, row[j - 1] + 1, diagonal + (ref[i - 1] == hyp[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[hyp.size()];
}

double process_cpu_seconds() {
  timespec t{};
  ::clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_nsec) * 1e-9;
}

// Nearest-rank percentile of a non-empty sample.
double percentile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  const auto rank = static_cast<std::size_t>(std::ceil(p * static_cast<double>(v.size())));
  return v[std::clamp<std::size_t>(rank, 1, v.size()) - 1];
}

struct TrialResult {
  bool detected = false;
  std::vector<std::string> recognized;  // phrases, one per utterance recognized
  std::string outcome;                  // what came out, for --details
  std::optional<double> latency_s;
  std::vector<double> rtf;  // per utterance
  double cpu_s = 0;         // detection and recognition
  double vad_cpu_s = 0;     // detection alone
  double audio_s = 0;       // fed to the detector
  double utterance_s = 0;   // in the utterances it cut
};

// With an array: its microphones, and whether the utterances are beamformed (delay-and-sum
// towards the direction estimate_direction finds) or mixed down before recognition.
struct ArraySetup {
  std::vector<a::MicPosition> mics;  // empty: one microphone
  bool steer = false;
  double bearing_deg = 30;  // where the talker is, seen from the array
};

struct Pipeline {
  a::Synthesizer synthesizer;
  a::Recognizer recognizer;
  a::VadOptions vad;
  double rt60 = 0.4;
  ArraySetup array;

  // One sentence through the pipeline (see the file comment).
  TrialResult trial(const std::string& sentence, const a::Voice& voice, double distance,
                    double noise_db, std::uint64_t seed) {
    const a::Signal spoken = synthesizer.speak(sentence, voice);
    a::RoomSound room{.rt60 = rt60, .critical_distance = 1.0, .noise_db = noise_db, .seed = seed};
    // The talker `distance` from the array's centre at array.bearing_deg; a path to each microphone.
    std::vector<a::Path> paths;
    const double theta = array.bearing_deg * std::numbers::pi / 180.0;
    const double tx = distance * std::cos(theta), ty = distance * std::sin(theta);
    for (const auto& m : array.mics.empty() ? std::vector<a::MicPosition>{{0, 0}} : array.mics) {
      const double d = std::hypot(tx - m.x, ty - m.y);
      paths.push_back({.distance = d, .level_db = kLevelAt1m - 20 * std::log10(d)});
    }
    const int channels = static_cast<int>(paths.size());
    const a::AudioBlock voice_at_mic = a::render(spoken, paths, room, kRenderLead, kRenderTail);
    room.seed = seed + 1;
    const a::AudioBlock before = a::room_noise(kLeadNoise, channels, room);
    room.seed = seed + 2;
    const a::AudioBlock after = a::room_noise(kTrailNoise, channels, room);
    std::vector<std::int16_t> capture = before.samples;
    capture.insert(capture.end(), voice_at_mic.samples.begin(), voice_at_mic.samples.end());
    capture.insert(capture.end(), after.samples.begin(), after.samples.end());
    // Where the voice (its direct sound, not the reverberation) ends at the microphone.
    const double speech_end =
        static_cast<double>(before.frames()) + std::round(kRenderLead * a::kSpeechRate) +
        static_cast<double>(spoken.samples.size()) + distance / a::kSpeedOfSound * a::kSpeechRate;

    TrialResult result;
    const auto frames = capture.size() / static_cast<std::size_t>(channels);
    result.audio_s = static_cast<double>(frames) / a::kSpeechRate;
    const double cpu_start = process_cpu_seconds();
    a::VoiceActivityDetector detector(vad);
    std::string outcome;
    std::optional<double> latency;
    const auto decode = [&](const a::Utterance& u, std::uint64_t delivered_at) {
      const auto begin = Clock::now();
      a::Recognition r;
      if (array.steer && u.audio.format.channels > 1) {
        const auto where = a::estimate_direction(u.audio, array.mics);
        r = recognizer.recognize(a::to_block(a::steer_towards(u.audio, array.mics, where.bearing)));
      } else {
        r = recognizer.recognize(u.audio);
      }
      const double wall = std::chrono::duration<double>(Clock::now() - begin).count();
      result.detected = true;
      result.rtf.push_back(wall / u.audio.seconds());
      result.utterance_s += u.audio.seconds();
      if (r.recognized) result.recognized.push_back(r.text);
      outcome += fmt::format("{}[{}]", outcome.empty() ? "" : " + ",
                             r.recognized ? r.text : fmt::format("{}: \"{}\"", r.reason, r.heard));
      // The utterance holding the end of the voice is the one the user waits for.
      if (static_cast<double>(u.audio.start) < speech_end) {
        latency = (static_cast<double>(delivered_at) - speech_end) / a::kSpeechRate + wall;
      }
    };
    a::AudioBlock block;
    block.format = {a::kSpeechRate, channels};
    const auto width = static_cast<std::size_t>(channels);
    for (std::size_t at = 0; at < frames; at += kBlockFrames) {
      const std::size_t n = std::min(kBlockFrames, frames - at);
      block.start = at;
      block.samples.assign(capture.begin() + static_cast<std::ptrdiff_t>(at * width),
                           capture.begin() + static_cast<std::ptrdiff_t>((at + n) * width));
      const double feed_start = process_cpu_seconds();
      const auto utterances = detector.feed(block);
      result.vad_cpu_s += process_cpu_seconds() - feed_start;
      for (const auto& u : utterances) decode(u, block.end());
    }
    if (const auto u = detector.flush()) decode(*u, frames);
    result.cpu_s = process_cpu_seconds() - cpu_start;
    result.latency_s = latency;
    result.outcome = result.detected ? outcome : "not detected";
    return result;
  }
};

// What one run of one (voice, distance, noise) measured.
struct RunFigures {
  int correct = 0;
  std::vector<double> latency_s, rtf;
  double cpu_s = 0, vad_cpu_s = 0, audio_s = 0, utterance_s = 0;

  void add(const TrialResult& t) {
    if (t.latency_s) latency_s.push_back(*t.latency_s);
    rtf.insert(rtf.end(), t.rtf.begin(), t.rtf.end());
    cpu_s += t.cpu_s;
    vad_cpu_s += t.vad_cpu_s;
    audio_s += t.audio_s;
    utterance_s += t.utterance_s;
  }
  void add_totals(const RunFigures& other) {
    cpu_s += other.cpu_s;
    vad_cpu_s += other.vad_cpu_s;
    audio_s += other.audio_s;
    utterance_s += other.utterance_s;
  }
};

// One line of the table: trials pooled over the runs, time and CPU figures per run.
struct Row {
  std::string voice;
  double distance = 0, noise_db = 0;
  int trials = 0, detected = 0, correct = 0, wrong = 0;
  std::size_t word_errors = 0, words_said = 0;
  int oov_trials = 0, oov_accepted = 0;
  std::vector<RunFigures> runs;
  std::map<std::string, int> failures;  // "said → outcome" → count
};

// The median over the runs of `figure` (a run without a value for it is left out); nullopt when
// no run has one.
template <typename F>
std::optional<double> median_of_runs(const Row& row, F figure) {
  std::vector<double> values;
  for (const auto& run : row.runs) {
    if (const std::optional<double> v = figure(run)) values.push_back(*v);
  }
  if (values.empty()) return std::nullopt;
  return icars::bench::stats(values).median;
}

// The room's seed for one trial: the same row gets the same noise whatever else is measured.
std::uint64_t seed_of(const std::string& voice, double distance, double noise_db, int run,
                      const std::string& sentence) {
  std::uint64_t hash = 14695981039346656037ull;  // FNV-1a
  for (const char c : fmt::format("{}|{}|{}|{}|{}", voice, distance, noise_db, run, sentence)) {
    hash = (hash ^ static_cast<unsigned char>(c)) * 1099511628211ull;
  }
  return hash;
}

std::string noise_label(double noise_db) {
  return noise_db < 0 ? std::string("none") : fmt::format("{} dB", noise_db);
}

std::string machine() {
  std::ifstream cpuinfo("/proc/cpuinfo");
  std::string model = "unknown CPU";
  for (std::string line; std::getline(cpuinfo, line);) {
    if (line.starts_with("model name")) {
      model = line.substr(line.find(':') + 2);
      break;
    }
  }
  double load[1] = {0};
  ::getloadavg(load, 1);
  return fmt::format("{}, nproc {}, load average {:.2f} at start", model,
                     std::thread::hardware_concurrency(), load[0]);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "The house's voice commands at a distance and in noise: accuracy, latency and cost of "
      "recognition"};
  int runs = 3;
  std::vector<std::string> voices{"en-us", "en-us+f3", "en"};
  std::vector<double> distances{1, 2, 4, 6};
  std::vector<double> noise{30, 50};
  bool quick = false;
  bool details = false;
  a::RecognizerOptions recognizer_options;
  a::VadOptions vad;
  double rt60 = 0.4;
  app.add_option("--runs", runs,
                 "repetitions, each with other noise seeds (trials are pooled over them)")
      ->check(CLI::Range(1, 100));
  app.add_option("--voices", voices, "espeak-ng voices")->delimiter(',');
  app.add_option("--distances", distances, "metres from the talker to the microphone")
      ->delimiter(',')
      ->check(CLI::Range(0.1, 50.0));
  app.add_option("--noise", noise, "background noise, dB SPL")
      ->delimiter(',')
      ->check(CLI::Range(-1.0, 90.0));
  app.add_option("--rt60", rt60, "the room's reverberation time, s (0: anechoic)")
      ->check(CLI::Range(0.0, 2.0));
  app.add_flag("--quick", quick, "the first voice, the first two distances, one run (a smoke run)");
  app.add_option("--min-confidence", recognizer_options.min_confidence,
                 "RecognizerOptions::min_confidence")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--model-dir", recognizer_options.model_dir, "RecognizerOptions::model_dir");
  app.add_option("--room-rt60", recognizer_options.room_rt60,
                 "RecognizerOptions::room_rt60: the reverberation the recognizer suppresses, s (0: none)")
      ->check(CLI::Range(0.0, 5.0));
  app.add_option("--vad-threshold-db", vad.threshold_db, "VadOptions::threshold_db")
      ->check(CLI::Range(0.0, 40.0));
  app.add_option("--hangover-ms", vad.hangover_ms, "VadOptions::hangover_ms")
      ->check(CLI::Range(20, 5000));
  app.add_flag("--details", details, "list every trial that failed");
  int array_mics = 0;
  double array_radius = 0.08;
  ArraySetup array;
  app.add_option("--array", array_mics,
                 "a circular array of this many microphones instead of one (the robot's: 4)")
      ->check(CLI::Range(2, 16));
  app.add_option("--array-radius", array_radius, "the array's radius, m")->check(CLI::Range(0.01, 1.0));
  app.add_option("--bearing", array.bearing_deg, "where the talker is, seen from the array, degrees");
  app.add_flag("--steer", array.steer,
               "with --array: beamform each utterance towards its estimated direction (delay-and-sum) "
               "instead of mixing the channels down");
  CLI11_PARSE(app, argc, argv);
  if (quick) {
    runs = 1;
    voices.resize(std::min<std::size_t>(voices.size(), 1));
    distances.resize(std::min<std::size_t>(distances.size(), 2));
  }

  try {
    if (array_mics > 0) array.mics = a::circular_array(array_mics, array_radius);
    Pipeline pipeline{{}, a::Recognizer(recognizer_options), vad, rt60, array};
    const auto effects = house_effects();
    std::vector<std::string> vocabulary;
    for (const auto& [phrase, effect] : effects) vocabulary.push_back(phrase);
    pipeline.recognizer.set_phrases(vocabulary);
    for (const auto& sentence : kCommands) {
      if (!effects.contains(lower(sentence)))
        throw std::logic_error("not in the vocabulary: " + sentence);
    }

    fmt::print("Machine: {}.\n", machine());
    fmt::print(
        "{} phrases in the vocabulary; {} commands and {} out-of-vocabulary sentences per voice, "
        "distance and noise level, {} run{} (each with other noise seeds); room RT60 {} s, "
        "critical distance 1 m; voice {:.0f} dB SPL at 1 m; min_confidence {}, VAD threshold {} "
        "dB, hangover {} ms.\n\n",
        vocabulary.size(), kCommands.size(), kOutOfVocabulary.size(), runs, runs == 1 ? "" : "s",
        rt60, kLevelAt1m, recognizer_options.min_confidence, vad.threshold_db, vad.hangover_ms);
    if (!array.mics.empty()) {
      fmt::print("A circular array of {} microphones, radius {} m, the talker at {} degrees; utterances {}.\n\n",
                 array.mics.size(), array_radius, array.bearing_deg,
                 array.steer ? "beamformed towards their estimated direction (delay-and-sum)" : "mixed down");
    }
    std::fflush(stdout);

    std::vector<Row> rows;
    for (const auto& voice_name : voices) {
      const a::Voice voice{.name = voice_name};
      for (const double distance : distances) {
        for (const double noise_db : noise) {
          Row row;
          row.voice = voice_name;
          row.distance = distance;
          row.noise_db = noise_db;
          for (int r = 0; r < runs; ++r) {
            RunFigures run;
            for (const auto& sentence : kCommands) {
              const auto result =
                  pipeline.trial(sentence, voice, distance, noise_db,
                                 seed_of(voice_name, distance, noise_db, r, sentence));
              const std::string said = lower(sentence);
              std::string heard;
              for (const auto& phrase : result.recognized) {
                heard += (heard.empty() ? "" : " ") + phrase;
              }
              const bool correct = result.recognized.size() == 1 &&
                                   effects.at(result.recognized.front()) == effects.at(said);
              ++row.trials;
              row.detected += result.detected ? 1 : 0;
              row.correct += correct ? 1 : 0;
              row.wrong += !correct && !result.recognized.empty() ? 1 : 0;
              run.correct += correct ? 1 : 0;
              const auto reference = words(a::spoken_form(said));
              row.word_errors += edit_distance(reference, words(a::spoken_form(heard)));
              row.words_said += reference.size();
              run.add(result);
              if (!correct) ++row.failures[fmt::format("\"{}\" → {}", said, result.outcome)];
            }
            for (const auto& sentence : kOutOfVocabulary) {
              const auto result =
                  pipeline.trial(sentence, voice, distance, noise_db,
                                 seed_of(voice_name, distance, noise_db, r, sentence));
              ++row.oov_trials;
              if (!result.recognized.empty()) {
                ++row.oov_accepted;
                ++row.failures[fmt::format("\"{}\" (out of vocabulary) → {}", lower(sentence),
                                           result.outcome)];
              }
              run.add(result);
            }
            row.runs.push_back(std::move(run));
          }
          rows.push_back(std::move(row));
        }
      }
    }

    fmt::print(
        "| voice | distance | noise | trials | detected | command accuracy{} | wrong command | WER "
        "| latency median | latency p95 | RTF median | CPU | OOV accepted |\n",
        runs > 1 ? " (runs' range)" : "");
    fmt::print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    const auto percent = [](double part, double whole) { return 100.0 * part / whole; };
    const auto or_dash = [](std::optional<double> v, const char* format) {
      return v ? fmt::format(fmt::runtime(format), *v) : std::string("–");
    };
    int oov_trials = 0, oov_accepted = 0;
    RunFigures all;
    for (const auto& row : rows) {
      std::vector<double> run_accuracy;
      for (const auto& run : row.runs) {
        run_accuracy.push_back(percent(run.correct, static_cast<double>(kCommands.size())));
      }
      const auto range = icars::bench::stats(run_accuracy);
      std::string accuracy = fmt::format("{:.0f}%", percent(row.correct, row.trials));
      if (runs > 1) accuracy += fmt::format(" ({:.0f}–{:.0f})", range.min, range.max);
      const auto latency = [&](double p) {
        return median_of_runs(row, [p](const RunFigures& run) -> std::optional<double> {
          if (run.latency_s.empty()) return std::nullopt;
          return 1000 * percentile(run.latency_s, p);
        });
      };
      const auto rtf = median_of_runs(row, [](const RunFigures& run) -> std::optional<double> {
        if (run.rtf.empty()) return std::nullopt;
        return percentile(run.rtf, 0.5);
      });
      const auto cpu = median_of_runs(row, [&](const RunFigures& run) -> std::optional<double> {
        return percent(run.cpu_s, run.audio_s);
      });
      fmt::print(
          "| {} | {} m | {} | {} | {:.0f}% | {} | {:.0f}% | {:.0f}% | {} | {} | {} | {} | {}/{} "
          "|\n",
          row.voice, row.distance, noise_label(row.noise_db), row.trials,
          percent(row.detected, row.trials), accuracy, percent(row.wrong, row.trials),
          percent(static_cast<double>(row.word_errors), static_cast<double>(row.words_said)),
          or_dash(latency(0.5), "{:.0f} ms"), or_dash(latency(0.95), "{:.0f} ms"),
          or_dash(rtf, "{:.3f}"), or_dash(cpu, "{:.1f}%"), row.oov_accepted, row.oov_trials);
      oov_trials += row.oov_trials;
      oov_accepted += row.oov_accepted;
      for (const auto& run : row.runs) all.add_totals(run);
    }
    fmt::print("\nOut-of-vocabulary false accepts: {} of {} ({:.1f}%).\n", oov_accepted, oov_trials,
               percent(oov_accepted, std::max(1, oov_trials)));
    fmt::print(
        "CPU over all trials: detection alone {:.2f}% of one core per second of audio; detection "
        "and recognition {:.1f}%, {:.0f}% of the audio being in utterances the detector cut.\n",
        percent(all.vad_cpu_s, all.audio_s), percent(all.cpu_s, all.audio_s),
        percent(all.utterance_s, all.audio_s));
    for (const auto& row : rows) {
      if (row.distance == 2 && row.noise_db == 30) {
        const double accuracy = percent(row.correct, row.trials);
        fmt::print("Target, >= 95% command accuracy at 2 m in a quiet room: {} {:.0f}%, {}.\n",
                   row.voice, accuracy, accuracy >= 95 ? "met" : "missed");
      }
    }
    if (details) {
      for (const auto& row : rows) {
        if (row.failures.empty()) continue;
        fmt::print("\n{} at {} m, {}:\n", row.voice, row.distance, noise_label(row.noise_db));
        for (const auto& [what, count] : row.failures) fmt::print("  {} x{}\n", what, count);
      }
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "speech_bench: {}\n", e.what());
    return 1;
  }
  return 0;
}
