// Stream channels: a stream passed as a result or an argument is pulled by its receiver within
// the credit it grants; end of stream, cancellation by either side, a peer dying mid-stream and
// a writer that ignores its credit are all reported; 100 MB pass to a deliberately slow reader
// with bounded memory on both sides.
#include <gtest/gtest.h>

#include <signal.h>

#include <asio/use_future.hpp>
#include <thread>

#include "child_process.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "icars/planet/rmi_message.h"
#include "icars/planet/stream.h"
#include "stream_table.h"
#include "test_interfaces.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;
using planet_test::Checksum;
using planet_test::Streams;

Checksum expected_checksum(std::uint64_t bytes) {
  Checksum sum;
  std::vector<std::byte> block;
  for (std::uint64_t at = 0; at < bytes;) {
    block.resize(std::min<std::uint64_t>(bytes - at, 1u << 16));
    planet_test::fill_pattern(at, block);
    at += block.size();
    sum.add(block);
  }
  return sum;
}

std::vector<std::byte> pattern(std::uint64_t from, std::size_t n) {
  std::vector<std::byte> block(n);
  planet_test::fill_pattern(from, block);
  return block;
}

CommunicatorOptions named(std::string name) {
  CommunicatorOptions options;
  options.name = std::move(name);
  return options;
}
StreamOptions window(std::size_t bytes) {
  StreamOptions options;
  options.window = bytes;
  return options;
}
StreamOptions bind_timeout(std::chrono::milliseconds timeout) {
  StreamOptions options;
  options.bind_timeout = timeout;
  return options;
}

// Reads `in` to its end; returns the checksum.
Checksum read_all(InputStream& in) {
  Checksum sum;
  for (auto chunk = in.read(); !chunk.empty(); chunk = in.read()) sum.add(chunk);
  return sum;
}

// Both ends in this process, over a real loopback connection.
class StreamChannel : public ::testing::Test {
 protected:
  void SetUp() override {
    server_.adapter().add("/streams", planet_test::make_streams_servant(server_));
    peer_ = client_.connect("127.0.0.1", server_.listen("127.0.0.1", 0));
    ASSERT_TRUE(peer_->wait_connected(20s)) << peer_->last_error();
  }
  Proxy streams() { return Proxy(client_, peer_, "/streams"); }
  std::string last_write() { return streams().call(Streams::last_write); }

  Communicator server_{named("server")};
  Communicator client_{named("client")};
  std::shared_ptr<Peer> peer_;
};

TEST_F(StreamChannel, AStreamResultIsReadToItsEnd) {
  const std::int64_t bytes = (3 << 20) + 123;
  auto in = InputStream::open(client_, peer_, streams().call(Streams::produce, bytes, 10000));
  const Checksum got = read_all(*in);
  const Checksum want = expected_checksum(bytes);
  EXPECT_EQ(got.bytes, want.bytes);
  EXPECT_EQ(got.value, want.value);
  EXPECT_TRUE(in->read().empty()) << "reads after the end keep reporting the end";
  EXPECT_TRUE(planet_test::wait_until([&] { return last_write() == "ok"; }));
}

TEST_F(StreamChannel, AStreamArgumentIsPulledByTheCallee) {
  auto out = OutputStream::create(client_);
  const std::uint64_t bytes = 5u << 20;
  std::thread writer([&] {
    for (std::uint64_t at = 0; at < bytes; at += 100000) {
      out->write(pattern(at, static_cast<std::size_t>(std::min<std::uint64_t>(100000, bytes - at))));
    }
    out->close();
  });
  const auto result = streams().call(Streams::consume, out->ref(), 0);
  writer.join();
  ASSERT_EQ(result.size(), 2u);
  EXPECT_EQ(static_cast<std::uint64_t>(result[0]), bytes);
  EXPECT_EQ(static_cast<std::uint64_t>(result[1]), expected_checksum(bytes).value);
}

TEST_F(StreamChannel, TheReaderCancelsAndTheWriterIsTold) {
  auto in = InputStream::open(client_, peer_, streams().call(Streams::produce, 1ll << 30, 65536));
  EXPECT_FALSE(in->read().empty());
  EXPECT_FALSE(in->read().empty());
  in->cancel("seen enough");
  try {
    in->read();
    FAIL() << "a read after cancel succeeded";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::failed);
    EXPECT_NE(std::string(e.what()).find("seen enough"), std::string::npos) << e.what();
  }
  ASSERT_TRUE(planet_test::wait_until([&] { return !last_write().empty(); }));
  const std::string outcome = last_write();
  EXPECT_NE(outcome.find("cancelled by the reader: seen enough"), std::string::npos) << outcome;
}

TEST_F(StreamChannel, TheWriterAbortsAndTheReaderIsTold) {
  auto out = OutputStream::create(client_);
  auto result = streams().async_call(Streams::consume, {out->ref(), 0}, asio::use_future);
  out->write(pattern(0, 200000));
  out->abort("microphone unplugged");
  try {
    result.get();
    FAIL() << "the reader did not notice the abort";
  } catch (const RemoteException& e) {
    EXPECT_EQ(e.type_id(), "test::StreamFailed");
    EXPECT_NE(e.remote_message().find("aborted by the writer: microphone unplugged"),
              std::string::npos)
        << e.remote_message();
  }
}

TEST_F(StreamChannel, DroppingAReaderCancelsTheStream) {
  {
    auto in = InputStream::open(client_, peer_, streams().call(Streams::produce, 1ll << 30, 65536));
    EXPECT_FALSE(in->read().empty());
  }
  ASSERT_TRUE(planet_test::wait_until([&] { return !last_write().empty(); }));
  EXPECT_NE(last_write().find("the reader dropped the stream"), std::string::npos) << last_write();
}

TEST_F(StreamChannel, AStreamNobodyOpensTimesOut) {
  auto out = OutputStream::create(client_, bind_timeout(200ms));
  try {
    out->write(pattern(0, 10));
    FAIL() << "a write to a stream nobody opened succeeded";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::timeout) << e.what();
  }
}

TEST_F(StreamChannel, AWriterThatIgnoresItsCreditIsCutOff) {
  // The server owns a stream; the client opens it with a 64 KiB window, then the server's side
  // sends 100 KiB in one DATA message, as a broken writer would.
  auto out = OutputStream::create(server_);
  auto in = InputStream::open(client_, peer_, out->ref(), window(64u << 10));
  std::shared_ptr<Connection> to_client;
  ASSERT_TRUE(planet_test::wait_until([&] {
    auto all = server_.connections().connections();
    if (all.empty()) return false;
    to_client = all.front();
    return true;
  }));
  std::vector<std::byte> message;
  Writer w(message);
  w.u8(static_cast<std::uint8_t>(RmiCode::stream));
  w.u32(out->ref().id);
  w.u8(static_cast<std::uint8_t>(StreamOp::data));
  w.length(100u << 10);
  w.raw(pattern(0, 100u << 10));
  to_client->send(std::move(message));
  try {
    while (!in->read().empty()) {
    }
    FAIL() << "the reader accepted data beyond its credit";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_data) << e.what();
    EXPECT_NE(std::string(e.what()).find("credit"), std::string::npos) << e.what();
  }
  // The writer was told to stop (its stream leaves the server's table once the CANCEL
  // arrived), and the connection still serves calls.
  ASSERT_TRUE(planet_test::wait_until([&] { return server_.stream_table().size() == 0; }));
  EXPECT_THROW(out->write(pattern(0, 10)), Error);
  EXPECT_EQ(last_write(), "");
}

TEST_F(StreamChannel, MalformedStreamMessagesAreDroppedAndTheLinkStaysUp) {
  auto connection = peer_->connection();
  ASSERT_TRUE(connection);
  const std::vector<std::vector<std::byte>> bad = {
      {std::byte{5}},                                                       // no stream id
      {std::byte{5}, std::byte{0}, std::byte{0}, std::byte{0}, std::byte{9}, std::byte{42}},
      {std::byte{5}, std::byte{0}, std::byte{0}, std::byte{0}, std::byte{1}, std::byte{1},
       std::byte{0xFF}, std::byte{0xFF}, std::byte{0xFF}, std::byte{0xFF}},  // huge DATA length
      {std::byte{5}, std::byte{0}, std::byte{0}, std::byte{9}, std::byte{9}, std::byte{2}},
  };
  for (auto message : bad) connection->send(std::move(message));
  EXPECT_EQ(last_write(), "");
  EXPECT_TRUE(connection->is_open());
}

// --- Across processes ------------------------------------------------------------------------

class StreamProcess : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = planet_test::start_test_server({"--heartbeat-timeout-ms", "20000"});
    peer_ = client_.connect("127.0.0.1", server_.port,
                            ReconnectPolicy{});
    ASSERT_TRUE(peer_->wait_connected(20s)) << peer_->last_error();
  }
  Proxy streams() { return Proxy(client_, peer_, "/streams").with_timeout(120s); }

  planet_test::TestServer server_;
  Communicator client_{named("client")};
  std::shared_ptr<Peer> peer_;
};

TEST_F(StreamProcess, TheWriterDyingMidStreamFailsTheReader) {
  auto in = InputStream::open(client_, peer_, streams().call(Streams::produce, 1ll << 40, 65536));
  std::uint64_t read = 0;
  for (int i = 0; i < 4; ++i) read += in->read().size();
  server_.process->signal(SIGKILL);
  try {
    for (;;) {
      auto chunk = in->read();
      ASSERT_FALSE(chunk.empty()) << "an endless stream reported its end";
      read += chunk.size();
    }
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::disconnected) << e.what();
  }
  EXPECT_LT(read, 1ull << 40);
}

TEST_F(StreamProcess, TheReaderDyingMidStreamFailsTheWriter) {
  auto out = OutputStream::create(client_);
  auto result = streams().async_call(Streams::consume, {out->ref(), 1000}, asio::use_future);
  out->write(pattern(0, 1u << 20));
  server_.process->signal(SIGKILL);
  try {
    for (std::uint64_t at = 1u << 20;; at += 65536) out->write(pattern(at, 65536));
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::disconnected) << e.what();
  }
  EXPECT_THROW(result.get(), Error);
}

TEST_F(StreamProcess, HundredMegabytesReachASlowReaderWithBoundedMemoryOnBothSides) {
  constexpr std::uint64_t kBytes = 100ull << 20;
  constexpr std::size_t kWindow = 1u << 20;
  constexpr std::int64_t kAllowedGrowthKb = 48 << 10;  // far below the 100 MB that passes
  streams().call(Streams::memory);  // resets the writer's peaks
  const auto writer_before = streams().call(Streams::memory);
  const auto reader_before = planet_test::memory_kb(true);

  auto in = InputStream::open(client_, peer_,
                              streams().call(Streams::produce, std::int64_t{kBytes}, 256 << 10),
                              window(kWindow));
  Checksum sum;
  std::size_t most_buffered = 0;
  std::uint64_t next_pause = 0;
  for (auto chunk = in->read(); !chunk.empty(); chunk = in->read()) {
    sum.add(chunk);
    most_buffered = std::max(most_buffered, in->buffered());
    // The deliberately slow reader: it pauses 1 ms per 128 KiB read (at most 128 MB/s, a fifth
    // of what the writer manages), so the writer would run far ahead without the credit.
    while (sum.bytes >= next_pause) {
      std::this_thread::sleep_for(1ms);
      next_pause += 128u << 10;
    }
  }
  const auto reader_after = planet_test::memory_kb(false);
  const auto writer_after = streams().call(Streams::memory);

  EXPECT_EQ(sum.bytes, kBytes);
  EXPECT_EQ(sum.value, expected_checksum(kBytes).value);
  EXPECT_EQ(streams().call(Streams::last_write), "ok");
  // Logical bounds: the reader never holds more than its window; the writer's connection never
  // queues more than the credit plus one DATA message.
  EXPECT_LE(most_buffered, kWindow);
  EXPECT_LE(static_cast<std::size_t>(writer_after[0]), kWindow + kMaxFramePayload);
  // Process bounds: neither side's peak resident memory grew by anything like 100 MB.
  const std::int64_t reader_growth = reader_after[0] - reader_before[1];
  const std::int64_t writer_growth = writer_after[1] - writer_before[2];
  std::cout << "100 MB stream: reader peak growth " << reader_growth << " kB, writer peak growth "
            << writer_growth << " kB, writer's largest send queue " << writer_after[0]
            << " bytes, reader's largest buffer " << most_buffered << " bytes\n";
  EXPECT_LT(reader_growth, kAllowedGrowthKb);
  EXPECT_LT(writer_growth, kAllowedGrowthKb);
}

}  // namespace
}  // namespace icars::planet
