#include "icars/audio/wav.h"

#include <algorithm>
#include <array>
#include <fstream>
#include <limits>
#include <optional>
#include <string>
#include <vector>

namespace icars::audio {
namespace {

constexpr std::uint16_t kFormatPcm = 1;
constexpr std::uint16_t kFormatExtensible = 0xFFFE;  // sox writes it for more than two channels

std::uint16_t u16(const unsigned char* p) { return static_cast<std::uint16_t>(p[0] | (p[1] << 8)); }
std::uint32_t u32(const unsigned char* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}

std::string format_name(std::uint16_t tag) {
  switch (tag) {
    case 1:
      return "PCM";
    case 2:
      return "ADPCM";
    case 3:
      return "IEEE float";
    case 6:
      return "A-law";
    case 7:
      return "mu-law";
    case 0x55:
      return "MP3";
    default:
      return "format tag " + std::to_string(tag);
  }
}

struct FmtChunk {
  std::uint16_t tag = 0;
  std::uint16_t channels = 0;
  std::uint32_t sample_rate = 0;
  std::uint16_t block_align = 0;
  std::uint16_t bits = 0;
};

FmtChunk parse_fmt(const std::string& path, const std::vector<unsigned char>& body) {
  if (body.size() < 16) {
    throw AudioError(path + ": fmt chunk of " + std::to_string(body.size()) +
                     " bytes, a WAV file's has at least 16");
  }
  FmtChunk f;
  f.tag = u16(&body[0]);
  f.channels = u16(&body[2]);
  f.sample_rate = u32(&body[4]);
  f.block_align = u16(&body[12]);
  f.bits = u16(&body[14]);
  if (f.tag == kFormatExtensible && body.size() >= 26) f.tag = u16(&body[24]);  // the sub-format
  if (f.tag != kFormatPcm) {
    throw AudioError(path + ": " + format_name(f.tag) + " audio, only 16-bit PCM WAV is read");
  }
  if (f.bits != 16) {
    throw AudioError(
        path + ": " + std::to_string(f.bits) +
        "-bit PCM, only 16-bit PCM WAV is read (convert with `sox in.wav -b 16 out.wav`)");
  }
  if (f.channels == 0 || f.sample_rate == 0 ||
      f.sample_rate > static_cast<std::uint32_t>(std::numeric_limits<int>::max())) {
    throw AudioError(path + ": " + std::to_string(f.channels) + " channels at " +
                     std::to_string(f.sample_rate) + " Hz is not audio");
  }
  if (f.block_align != f.channels * 2) {
    throw AudioError(path + ": block align " + std::to_string(f.block_align) + " for " +
                     std::to_string(f.channels) + " channels of 16-bit PCM (expected " +
                     std::to_string(f.channels * 2) + ")");
  }
  return f;
}

void put16(std::string& out, std::uint32_t v) {
  out.push_back(static_cast<char>(v & 0xFF));
  out.push_back(static_cast<char>((v >> 8) & 0xFF));
}
void put32(std::string& out, std::uint32_t v) {
  put16(out, v & 0xFFFF);
  put16(out, v >> 16);
}

}  // namespace

AudioBlock read_wav(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw AudioError(path + ": cannot open for reading");
  std::array<unsigned char, 12> riff{};
  if (!in.read(reinterpret_cast<char*>(riff.data()), riff.size())) {
    throw AudioError(path + ": shorter than a WAV header (12 bytes)");
  }
  const auto text = [&](std::size_t at) {
    std::string t(reinterpret_cast<const char*>(riff.data() + at), 4);
    for (char& c : t) c = (c >= 0x20 && c < 0x7F) ? c : '?';
    return t;
  };
  if (text(0) != "RIFF") {
    throw AudioError(path + ": not a RIFF WAVE file (it starts with \"" + text(0) + "\")");
  }
  if (text(8) != "WAVE") {
    throw AudioError(path + ": a RIFF file of type \"" + text(8) + "\", not WAVE");
  }

  std::optional<FmtChunk> fmt;
  while (true) {
    std::array<unsigned char, 8> header{};
    if (!in.read(reinterpret_cast<char*>(header.data()), header.size())) {
      throw AudioError(path + (fmt ? ": no data chunk" : ": no fmt chunk"));
    }
    const std::string id(reinterpret_cast<const char*>(header.data()), 4);
    const std::uint32_t size = u32(header.data() + 4);
    if (id == "fmt ") {
      if (size > 4096) throw AudioError(path + ": fmt chunk of " + std::to_string(size) + " bytes");
      std::vector<unsigned char> body(size);
      if (!in.read(reinterpret_cast<char*>(body.data()), static_cast<std::streamsize>(size))) {
        throw AudioError(path + ": truncated fmt chunk");
      }
      fmt = parse_fmt(path, body);
      if (size % 2 == 1) in.ignore(1);
    } else if (id == "data") {
      if (!fmt) throw AudioError(path + ": data chunk before the fmt chunk");
      // A truncated file (a recorder that was killed, a size of 0xFFFFFFFF from a streaming
      // writer) is read as far as it goes, in whole frames.
      AudioBlock audio;
      audio.format = {static_cast<int>(fmt->sample_rate), fmt->channels};
      std::vector<char> bytes;
      std::array<char, 65536> buffer{};
      std::uint64_t left = size;
      while (left > 0 && in) {
        const auto want =
            static_cast<std::streamsize>(std::min<std::uint64_t>(left, buffer.size()));
        in.read(buffer.data(), want);
        const auto got = static_cast<std::size_t>(in.gcount());
        bytes.insert(bytes.end(), buffer.data(), buffer.data() + got);
        left -= got;
      }
      const std::size_t whole = bytes.size() / fmt->block_align * fmt->block_align;
      audio.samples.resize(whole / 2);
      for (std::size_t i = 0; i < audio.samples.size(); ++i) {
        audio.samples[i] =
            static_cast<std::int16_t>(u16(reinterpret_cast<const unsigned char*>(&bytes[2 * i])));
      }
      return audio;
    } else {
      // LIST, fact, cue and the like: skipped, with the pad byte of an odd size.
      in.seekg(static_cast<std::streamoff>(size) + (size % 2), std::ios::cur);
    }
  }
}

void write_wav(const std::string& path, const AudioBlock& audio) {
  const int channels = audio.format.channels;
  if (channels <= 0 || channels > 0xFFFF || audio.format.sample_rate <= 0) {
    throw AudioError(path + ": cannot write " + std::to_string(channels) + " channels at " +
                     std::to_string(audio.format.sample_rate) + " Hz");
  }
  const std::size_t data_bytes = audio.frames() * static_cast<std::size_t>(channels) * 2;
  if (data_bytes > std::numeric_limits<std::uint32_t>::max() - 36) {
    throw AudioError(path + ": " + std::to_string(data_bytes) +
                     " bytes of audio is too long for WAV");
  }
  const auto u = [](auto v) { return static_cast<std::uint32_t>(v); };
  std::string out;
  out.reserve(44 + data_bytes);
  out += "RIFF";
  put32(out, u(36 + data_bytes));
  out += "WAVEfmt ";
  put32(out, 16);
  put16(out, kFormatPcm);
  put16(out, u(channels));
  put32(out, u(audio.format.sample_rate));
  put32(out, u(audio.format.sample_rate) * u(channels) * 2);
  put16(out, u(channels * 2));
  put16(out, 16);
  out += "data";
  put32(out, u(data_bytes));
  for (std::size_t i = 0; i < data_bytes / 2; ++i) {
    put16(out, static_cast<std::uint16_t>(audio.samples[i]));
  }
  std::ofstream file(path, std::ios::binary | std::ios::trunc);
  if (!file || !file.write(out.data(), static_cast<std::streamsize>(out.size())) || !file.flush()) {
    throw AudioError(path + ": cannot write");
  }
}

}  // namespace icars::audio
