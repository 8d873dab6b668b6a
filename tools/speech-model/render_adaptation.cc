// icars-render-adaptation: the recordings the simulated house's speech model is adapted with
// (tools/speech-model/adapt.sh). Every sentence of SENTENCES is spoken by each espeak-ng voice and
// rendered as the simulated microphones and bench/speech.cc render a voice: one path from a
// talker 1 to 4 m away (drawn), 60 - 20 log10(d) dB SPL, RT60 0.4 s, critical distance 1 m,
// 30 dB SPL of room noise, 0.5 s of lead and 0.8 s of tail, reverberation and all: the simulated
// house's engine suppresses the late reverberation before decoding, but a model adapted on
// suppressed recordings was no better (docs/speech.md, "Round two"). Deterministic for a seed.
//
//   icars-render-adaptation SENTENCES OUTDIR SEED VOICE...
//
// Writes OUTDIR/wav/<voice>_<n>.wav (16 kHz mono), and the control and transcription files
// sphinxtrain's bw reads: OUTDIR/adapt.fileids (wav/<id>) and OUTDIR/adapt.transcription
// ("<s> words </s> (id)"). The sentences are not the house's commands: the model learns the
// voices and the room, not the test.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "icars/audio/acoustics.h"
#include "icars/audio/synthesizer.h"
#include "icars/audio/wav.h"

namespace a = icars::audio;

int main(int argc, char** argv) {
  if (argc < 5) {
    std::cerr << "usage: icars-render-adaptation SENTENCES OUTDIR SEED VOICE...\n";
    return 2;
  }
  try {
    std::vector<std::string> sentences;
    std::ifstream in(argv[1]);
    if (!in) throw std::runtime_error(std::string("cannot read ") + argv[1]);
    for (std::string line; std::getline(in, line);) {
      if (!line.empty()) sentences.push_back(line);
    }
    if (sentences.empty()) throw std::runtime_error(std::string(argv[1]) + " has no sentences");
    const std::filesystem::path out = argv[2];
    std::filesystem::create_directories(out / "wav");
    std::mt19937_64 random(std::stoull(argv[3]));
    std::uniform_real_distribution<double> distance_of(1.0, 4.0);
    std::ofstream fileids(out / "adapt.fileids");
    std::ofstream transcription(out / "adapt.transcription");
    a::Synthesizer synthesizer;
    double seconds = 0;
    for (int v = 4; v < argc; ++v) {
      const std::string voice = argv[v];
      std::string tag;
      for (const char c : voice) tag += std::isalnum(static_cast<unsigned char>(c)) ? c : '_';
      for (std::size_t i = 0; i < sentences.size(); ++i) {
        const double d = distance_of(random);
        const a::RoomSound room{.rt60 = 0.4, .critical_distance = 1.0, .noise_db = 30.0, .seed = random()};
        const a::Signal spoken = synthesizer.speak(sentences[i], a::Voice{.name = voice});
        const a::AudioBlock block =
            a::render(spoken, {{.distance = d, .level_db = 60.0 - 20 * std::log10(d)}}, room, 0.5, 0.8);
        const std::string id = tag + "_" + std::to_string(i + 1);
        a::write_wav((out / "wav" / (id + ".wav")).string(), block);
        fileids << "wav/" << id << "\n";
        transcription << "<s> " << sentences[i] << " </s> (" << id << ")\n";
        seconds += block.seconds();
      }
    }
    std::cout << "rendered " << seconds << " s of speech for adaptation\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "icars-render-adaptation: " << e.what() << "\n";
    return 1;
  }
}
