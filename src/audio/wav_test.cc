// WAV files: a round trip of several formats, files as other programs write them (extra chunks
// of odd sizes, WAVE_FORMAT_EXTENSIBLE, a truncated data chunk) and the refusals of what is not
// 16-bit PCM, each naming the file and what it found.
#include "icars/audio/wav.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

namespace icars::audio {
namespace {

namespace fs = std::filesystem;
using namespace std::string_literals;

class WavTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("icars_wav_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  void write_bytes(const std::string& file, const std::string& bytes) const {
    std::ofstream(path(file), std::ios::binary) << bytes;
  }

  // The message of the AudioError reading `file` throws.
  std::string error_reading(const std::string& file) const {
    try {
      read_wav(path(file));
    } catch (const AudioError& e) {
      return e.what();
    }
    ADD_FAILURE() << "reading " << file << " did not fail";
    return {};
  }

  fs::path dir_;
};

std::string u16(std::uint32_t v) {
  return {static_cast<char>(v & 0xFF), static_cast<char>((v >> 8) & 0xFF)};
}
std::string u32(std::uint32_t v) { return u16(v & 0xFFFF) + u16(v >> 16); }

std::string chunk(const std::string& id, const std::string& body) {
  std::string out = id + u32(static_cast<std::uint32_t>(body.size())) + body;
  if (body.size() % 2 == 1) out.push_back('\0');  // RIFF pads odd chunks
  return out;
}

std::string fmt_body(std::uint16_t tag, std::uint16_t channels, std::uint32_t rate,
                     std::uint16_t bits) {
  const auto block_align = static_cast<std::uint16_t>(channels * bits / 8);
  return u16(tag) + u16(channels) + u32(rate) + u32(rate * block_align) + u16(block_align) +
         u16(bits);
}

std::string riff(const std::string& chunks) {
  return "RIFF" + u32(static_cast<std::uint32_t>(4 + chunks.size())) + "WAVE" + chunks;
}

std::string pcm(const std::vector<std::int16_t>& samples) {
  std::string out;
  for (const auto s : samples) out += u16(static_cast<std::uint16_t>(s));
  return out;
}

TEST_F(WavTest, RoundTripKeepsFormatAndSamples) {
  for (const AudioFormat format : {AudioFormat{16000, 1}, AudioFormat{44100, 2},
                                   AudioFormat{48000, 4}, AudioFormat{8000, 1}}) {
    AudioBlock audio;
    audio.format = format;
    for (int i = 0; i < 1000 * format.channels; ++i) {
      audio.samples.push_back(static_cast<std::int16_t>((i * 7919) % 65536 - 32768));
    }
    audio.samples.front() = -32768;
    audio.samples.back() = 32767;
    const std::string file = path("round.wav");
    write_wav(file, audio);
    EXPECT_EQ(fs::file_size(file), 44 + audio.samples.size() * 2);
    const AudioBlock back = read_wav(file);
    EXPECT_EQ(back.format, format);
    EXPECT_EQ(back.start, 0u);
    EXPECT_EQ(back.samples, audio.samples);
  }
}

TEST_F(WavTest, EmptyAudioRoundTrips) {
  AudioBlock audio;
  audio.format = {22050, 1};
  write_wav(path("empty.wav"), audio);
  const AudioBlock back = read_wav(path("empty.wav"));
  EXPECT_EQ(back.format, audio.format);
  EXPECT_TRUE(back.samples.empty());
}

TEST_F(WavTest, SkipsExtraChunksOfOddSizes) {
  // As sox and DAWs write them: a LIST chunk of odd size (with its pad byte) before the data,
  // a fact chunk between fmt and LIST, and a cue chunk after the data.
  const std::vector<std::int16_t> samples = {1, -2, 300, -32768, 32767, 0};
  write_bytes("extra.wav", riff(chunk("fmt ", fmt_body(1, 2, 44100, 16)) + chunk("fact", u32(3)) +
                                chunk("LIST", "INFOISFT\x07\0\0\0Lavf58."s) +
                                chunk("data", pcm(samples)) + chunk("cue ", u32(0))));
  const AudioBlock audio = read_wav(path("extra.wav"));
  EXPECT_EQ(audio.format, (AudioFormat{44100, 2}));
  EXPECT_EQ(audio.samples, samples);
}

TEST_F(WavTest, ReadsWaveFormatExtensibleWithPcm) {
  // 18-byte cbSize extension: valid bits, channel mask and the PCM sub-format GUID.
  const std::string ext =
      fmt_body(0xFFFE, 3, 16000, 16) + u16(22) + u16(16) + u32(7) + u16(1) +
      std::string("\x00\x00\x00\x00\x10\x00\x80\x00\x00\xAA\x00\x38\x9B\x71", 14);
  const std::vector<std::int16_t> samples = {10, 20, 30, 40, 50, 60};
  write_bytes("ext.wav", riff(chunk("fmt ", ext) + chunk("data", pcm(samples))));
  const AudioBlock audio = read_wav(path("ext.wav"));
  EXPECT_EQ(audio.format, (AudioFormat{16000, 3}));
  EXPECT_EQ(audio.samples, samples);
}

TEST_F(WavTest, ReadsATruncatedDataChunkAsFarAsItGoes) {
  // The data chunk claims 1000 bytes; 9 are there: 2 whole stereo frames and a partial one.
  std::string bytes = riff(chunk("fmt ", fmt_body(1, 2, 16000, 16)));
  bytes += "data" + u32(1000) + pcm({1, 2, 3, 4}) + "\x05\x00\x06"s;
  write_bytes("truncated.wav", bytes);
  const AudioBlock audio = read_wav(path("truncated.wav"));
  EXPECT_EQ(audio.format, (AudioFormat{16000, 2}));
  EXPECT_EQ(audio.samples, (std::vector<std::int16_t>{1, 2, 3, 4}));

  // A streaming writer that never went back to fill in the size.
  write_bytes("streamed.wav", riff(chunk("fmt ", fmt_body(1, 1, 8000, 16))) + "data" +
                                  u32(0xFFFFFFFF) + pcm({7, 8, 9}));
  EXPECT_EQ(read_wav(path("streamed.wav")).samples, (std::vector<std::int16_t>{7, 8, 9}));
}

TEST_F(WavTest, RefusesWhatIsNot16BitPcmNamingFileAndFormat) {
  write_bytes("float.wav", riff(chunk("fmt ", fmt_body(3, 1, 16000, 32)) + chunk("data", "")));
  std::string message = error_reading("float.wav");
  EXPECT_NE(message.find(path("float.wav")), std::string::npos) << message;
  EXPECT_NE(message.find("IEEE float"), std::string::npos) << message;

  write_bytes("24bit.wav", riff(chunk("fmt ", fmt_body(1, 2, 48000, 24)) + chunk("data", "")));
  message = error_reading("24bit.wav");
  EXPECT_NE(message.find(path("24bit.wav")), std::string::npos) << message;
  EXPECT_NE(message.find("24-bit PCM"), std::string::npos) << message;

  write_bytes("mulaw.wav", riff(chunk("fmt ", fmt_body(7, 1, 8000, 8)) + chunk("data", "")));
  EXPECT_NE(error_reading("mulaw.wav").find("mu-law"), std::string::npos);

  write_bytes("mp3.wav", "ID3\x04\0\0\0\0\0\0 and then an MP3 frame"s);
  message = error_reading("mp3.wav");
  EXPECT_NE(message.find(path("mp3.wav")), std::string::npos) << message;
  EXPECT_NE(message.find("not a RIFF WAVE file"), std::string::npos) << message;
  EXPECT_NE(message.find("ID3"), std::string::npos) << message;

  write_bytes("avi.wav", riff("").replace(8, 4, "AVI "));
  EXPECT_NE(error_reading("avi.wav").find("\"AVI \", not WAVE"), std::string::npos);
}

TEST_F(WavTest, RefusesMalformedFiles) {
  EXPECT_NE(error_reading("missing.wav").find("cannot open"), std::string::npos);

  write_bytes("short.wav", "RIFF");
  EXPECT_NE(error_reading("short.wav").find("shorter than a WAV header"), std::string::npos);

  write_bytes("nofmt.wav", riff(chunk("LIST", "abc")));
  EXPECT_NE(error_reading("nofmt.wav").find("no fmt chunk"), std::string::npos);

  write_bytes("nodata.wav", riff(chunk("fmt ", fmt_body(1, 1, 16000, 16))));
  EXPECT_NE(error_reading("nodata.wav").find("no data chunk"), std::string::npos);

  write_bytes("early.wav",
              riff(chunk("data", pcm({1, 2})) + chunk("fmt ", fmt_body(1, 1, 16000, 16))));
  EXPECT_NE(error_reading("early.wav").find("data chunk before the fmt chunk"), std::string::npos);

  write_bytes("nochannels.wav", riff(chunk("fmt ", fmt_body(1, 0, 16000, 16)) + chunk("data", "")));
  EXPECT_NE(error_reading("nochannels.wav").find("0 channels"), std::string::npos);

  write_bytes("smallfmt.wav", riff(chunk("fmt ", "\x01\x00\x01\x00"s) + chunk("data", "")));
  EXPECT_NE(error_reading("smallfmt.wav").find("fmt chunk of 4 bytes"), std::string::npos);
}

TEST_F(WavTest, WriteRefusesWhatWavCannotHold) {
  AudioBlock audio;
  audio.format = {16000, 0};
  EXPECT_THROW(write_wav(path("x.wav"), audio), AudioError);
  audio.format = {16000, 1};
  EXPECT_THROW(write_wav((dir_ / "no" / "such" / "dir.wav").string(), audio), AudioError);
}

}  // namespace
}  // namespace icars::audio
