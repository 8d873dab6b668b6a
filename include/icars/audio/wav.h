// WAV files: 16-bit PCM (any rate, any channel count) read and written, so tests and tools can
// hand ICARS recorded or synthesized speech. Reading refuses what is not 16-bit PCM with an
// AudioError naming the file and what it found.
#pragma once

#include <string>

#include "icars/audio/pcm.h"

namespace icars::audio {

AudioBlock read_wav(const std::string& path);
void write_wav(const std::string& path, const AudioBlock& audio);

}  // namespace icars::audio
