// Audio sources: raw PCM from files and from a real named pipe with a writer thread, WAV files,
// real-time pacing and stopping, and ALSA on a machine without a sound card.
#include "icars/audio/source.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

#include "icars/audio/wav.h"

namespace icars::audio {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

class SourceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("icars_source_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  fs::path dir_;
};

// Frames that say where they are: sample = frame index * 2 + channel, wrapping.
AudioBlock numbered(std::size_t frames, int channels, int rate = kSpeechRate) {
  AudioBlock block;
  block.format = {rate, channels};
  for (std::size_t i = 0; i < frames; ++i) {
    for (int c = 0; c < channels; ++c) {
      block.samples.push_back(
          static_cast<std::int16_t>((i * 2 + static_cast<std::size_t>(c)) % 30000));
    }
  }
  return block;
}

std::string le_bytes(const std::vector<std::int16_t>& samples) {
  std::string out;
  for (auto s : samples) {
    const auto u = static_cast<std::uint16_t>(s);
    out.push_back(static_cast<char>(u & 0xff));
    out.push_back(static_cast<char>(u >> 8));
  }
  return out;
}

void write_file(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary)
      .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::vector<AudioBlock> read_all(AudioSource& source, std::size_t limit = 100000) {
  std::vector<AudioBlock> out;
  while (out.size() < limit) {
    auto block = source.read();
    if (!block) break;
    out.push_back(std::move(*block));
  }
  return out;
}

std::vector<std::int16_t> joined(const std::vector<AudioBlock>& blocks) {
  std::vector<std::int16_t> out;
  std::uint64_t next = 0;
  for (const auto& b : blocks) {
    EXPECT_EQ(b.start, next);
    next = b.end();
    out.insert(out.end(), b.samples.begin(), b.samples.end());
  }
  return out;
}

std::string open_error(const std::string& spec, SourceOptions options = {}) {
  try {
    open_source(spec, options);
  } catch (const AudioError& e) {
    return e.what();
  }
  return "";
}

TEST_F(SourceTest, AMalformedOrMissingSourceIsAnErrorNamingIt) {
  for (const std::string spec : {"mp3:/tmp/x.mp3", "no-scheme", "raw:", "wav:"}) {
    const std::string error = open_error(spec);
    EXPECT_NE(error.find("\"" + spec + "\""), std::string::npos) << error;
  }
  EXPECT_NE(open_error("mp3:/tmp/x.mp3").find("alsa:NAME, wav:PATH or raw:PATH"),
            std::string::npos);
  const std::string raw = "raw:" + path("missing.pcm");
  EXPECT_NE(open_error(raw).find(raw), std::string::npos) << open_error(raw);
  EXPECT_NE(open_error(raw).find("No such file"), std::string::npos) << open_error(raw);
  const std::string wav = "wav:" + path("missing.wav");
  EXPECT_NE(open_error(wav).find(wav), std::string::npos) << open_error(wav);
  SourceOptions bad;
  bad.format.channels = 0;
  EXPECT_NE(open_error("raw:" + path("x"), bad).find("0 channels"), std::string::npos);
}

TEST_F(SourceTest, AlsaWithoutASoundCardFailsNamingTheDevice) {
  // This machine has no sound card: opening must fail cleanly, saying which device.
  for (const std::string device : {"icars_no_such_device", "hw:7,0"}) {
    const std::string error = open_error("alsa:" + device);
    EXPECT_NE(error.find("\"alsa:" + device + "\""), std::string::npos) << error;
    EXPECT_NE(error.find("ALSA capture device \"" + device + "\""), std::string::npos) << error;
  }
}

TEST_F(SourceTest, RawFileComesInPeriodsOnOneTimeline) {
  const AudioBlock audio = numbered(16000 + 160, 2);  // 1 s and half a period of stereo
  write_file(path("a.pcm"), le_bytes(audio.samples));
  SourceOptions options;
  options.format = {kSpeechRate, 2};
  options.real_time = false;
  auto source = open_source("raw:" + path("a.pcm"), options);
  EXPECT_EQ(source->format(), options.format);
  const auto blocks = read_all(*source);
  ASSERT_EQ(blocks.size(), 51u);
  for (std::size_t i = 0; i + 1 < blocks.size(); ++i) EXPECT_EQ(blocks[i].frames(), 320u);
  EXPECT_EQ(blocks.back().frames(), 160u);  // the partial last period, then the end
  EXPECT_EQ(joined(blocks), audio.samples);
  EXPECT_EQ(source->error(), "");
  EXPECT_FALSE(source->read());
  EXPECT_EQ(source->overruns(), 0u);
}

TEST_F(SourceTest, FilesLoopOnTheSameTimeline) {
  const AudioBlock audio = numbered(1000, 1);  // 3 periods and a bit
  write_file(path("a.pcm"), le_bytes(audio.samples));
  write_wav(path("a.wav"), audio);
  SourceOptions options;
  options.real_time = false;
  options.loop = true;
  for (const std::string& spec : {"raw:" + path("a.pcm"), "wav:" + path("a.wav")}) {
    auto source = open_source(spec, options);
    const auto blocks = read_all(*source, 10);
    ASSERT_EQ(blocks.size(), 10u) << spec;
    const auto samples = joined(blocks);
    for (std::size_t i = 0; i < samples.size(); ++i) {
      ASSERT_EQ(samples[i], audio.samples[i % audio.samples.size()]) << spec << " sample " << i;
    }
  }
}

TEST_F(SourceTest, ALoopDropsAPartialFrameAtTheEndOfTheFile) {
  const AudioBlock audio = numbered(500, 2);
  write_file(path("odd.pcm"), le_bytes(audio.samples) + "xyz");  // 3 bytes of a 4-byte frame
  SourceOptions options;
  options.format.channels = 2;
  options.real_time = false;
  options.loop = true;
  auto source = open_source("raw:" + path("odd.pcm"), options);
  const auto samples = joined(read_all(*source, 5));
  ASSERT_EQ(samples.size(), 5u * 320 * 2);
  for (std::size_t i = 0; i < samples.size(); ++i) {
    ASSERT_EQ(samples[i], audio.samples[i % audio.samples.size()]) << "sample " << i;
  }
}

TEST_F(SourceTest, WavFileHasItsOwnFormat) {
  const AudioBlock audio = numbered(22050 / 2, 2, 22050);
  write_wav(path("b.wav"), audio);
  SourceOptions options;
  options.real_time = false;
  auto source = open_source("wav:" + path("b.wav"), options);
  EXPECT_EQ(source->format(), audio.format);
  const auto blocks = read_all(*source);
  EXPECT_EQ(blocks.front().frames(), 441u);  // 20 ms at 22,050 Hz
  EXPECT_EQ(joined(blocks), audio.samples);
  EXPECT_EQ(source->error(), "");
}

TEST_F(SourceTest, RealTimeDeliversAtTheSampleRate) {
  write_file(path("c.pcm"), le_bytes(numbered(16000 * 3 / 10, 1).samples));  // 0.3 s
  auto source = open_source("raw:" + path("c.pcm"));
  const auto begin = Clock::now();
  ASSERT_TRUE(source->read());
  EXPECT_GE(Clock::now() - begin, 19ms);  // a period is there once it has been "captured"
  const auto blocks = read_all(*source);
  const auto took = Clock::now() - begin;
  EXPECT_EQ(blocks.size(), 14u);
  EXPECT_GE(took, 295ms);
  EXPECT_LT(took, 2s);
}

TEST_F(SourceTest, StopEndsARealTimeReadPromptly) {
  write_file(path("long.pcm"), le_bytes(numbered(16000 * 60, 1).samples));
  SourceOptions options;
  options.loop = true;
  auto source = open_source("raw:" + path("long.pcm"), options);
  std::thread stopper([&] {
    std::this_thread::sleep_for(200ms);
    source->stop();
  });
  const auto begin = Clock::now();
  const auto blocks = read_all(*source);
  const auto took = Clock::now() - begin;
  stopper.join();
  EXPECT_GE(blocks.size(), 5u);
  EXPECT_LT(took, 1s);
  EXPECT_EQ(source->error(), "");
}

// A writer process on the other end of a named pipe, played by a thread: it opens the pipe
// once the reader has, writes `data` in small pieces and closes.
std::thread pipe_writer(const std::string& fifo, std::string data,
                        std::chrono::milliseconds hold = 0ms) {
  return std::thread([fifo, data = std::move(data), hold] {
    int fd = -1;
    const auto deadline = Clock::now() + 5s;
    while ((fd = ::open(fifo.c_str(), O_WRONLY | O_NONBLOCK)) < 0 && Clock::now() < deadline) {
      std::this_thread::sleep_for(2ms);  // ENXIO until the reader has opened it
    }
    if (fd < 0) return;
    ::fcntl(fd, F_SETFL, 0);
    for (std::size_t at = 0; at < data.size(); at += 777) {
      const std::size_t n = std::min<std::size_t>(777, data.size() - at);
      if (::write(fd, data.data() + at, n) != static_cast<ssize_t>(n)) break;
      std::this_thread::sleep_for(1ms);
    }
    std::this_thread::sleep_for(hold);
    ::close(fd);
  });
}

TEST_F(SourceTest, ANamedPipeDeliversUntilItsWriterCloses) {
  const std::string fifo = path("mic.fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const AudioBlock audio = numbered(320 * 10 + 160, 2);  // the writer stops mid-period
  std::thread writer = pipe_writer(fifo, le_bytes(audio.samples));
  SourceOptions options;
  options.format = {kSpeechRate, 2};
  auto source = open_source("raw:" + fifo, options);  // does not wait for the writer
  const auto blocks = read_all(*source);
  writer.join();
  ASSERT_EQ(blocks.size(), 11u);
  EXPECT_EQ(blocks.back().frames(), 160u);
  EXPECT_EQ(joined(blocks), audio.samples);
  EXPECT_EQ(source->error(), "");
}

TEST_F(SourceTest, StopEndsAReadWaitingOnASilentPipe) {
  const std::string fifo = path("quiet.fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  // One writer sends a period and then nothing for a while; with no writer at all it is the same.
  std::thread writer = pipe_writer(fifo, le_bytes(numbered(320, 1).samples), 1500ms);
  auto source = open_source("raw:" + fifo);
  ASSERT_TRUE(source->read());
  std::thread stopper([&] {
    std::this_thread::sleep_for(150ms);
    source->stop();
  });
  const auto begin = Clock::now();
  EXPECT_FALSE(source->read());
  EXPECT_LT(Clock::now() - begin, 1s);
  stopper.join();
  writer.join();

  auto lonely = open_source("raw:" + fifo);
  std::thread stop_lonely([&] {
    std::this_thread::sleep_for(100ms);
    lonely->stop();
  });
  EXPECT_FALSE(lonely->read());
  stop_lonely.join();
}

}  // namespace
}  // namespace icars::audio
