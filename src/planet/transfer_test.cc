// Large messages: frames of concurrent messages interleave on one connection, and flow control
// bounds the memory of a sender whose receiver stops reading.
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <asio/use_future.hpp>
#include <atomic>
#include <cstring>
#include <future>
#include <semaphore>

#include "child_process.h"
#include "icars/planet/communicator.h"
#include "buffer_pool.h"
#include "icars/planet/detail/byte_order.h"
#include "icars/planet/proxy.h"
#include "test_interfaces.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;
using planet_test::Echo;

TEST(Transfer, SmallCallsCompleteWhileA50MiBBinaryIsInFlight) {
  auto server = planet_test::start_test_server();
  Communicator client;
  auto peer = client.connect("127.0.0.1", server.port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy echo(client, peer, "/echo");
  echo = echo.with_timeout(120s);

  Binary big;
  big.bytes.resize(50u << 20, std::byte{0x5A});
  auto big_call = echo.async_call(Echo::size_of, {std::move(big)}, asio::use_future);

  int completed_during_transfer = 0;
  std::chrono::steady_clock::duration slowest{};
  while (big_call.wait_for(0s) != std::future_status::ready) {
    const auto start = std::chrono::steady_clock::now();
    ASSERT_EQ(echo.call(Echo::echo_int, completed_during_transfer), completed_during_transfer);
    slowest = std::max(slowest, std::chrono::steady_clock::now() - start);
    if (big_call.wait_for(0s) != std::future_status::ready) ++completed_during_transfer;
  }
  EXPECT_EQ(big_call.get(), std::int64_t{50} << 20);
  // Without interleaving the first small call would wait for all 3200 frames of the binary.
  EXPECT_GE(completed_during_transfer, 5) << "small calls were stuck behind the large message";
  std::cout << "small calls completed during the 50 MiB transfer: " << completed_during_transfer
            << ", slowest " << std::chrono::duration_cast<std::chrono::microseconds>(slowest).count()
            << " us\n";
}

Binary pattern_of(std::size_t size, unsigned step) {
  Binary b;
  b.bytes.resize(size);
  for (std::size_t i = 0; i < size; ++i) b.bytes[i] = std::byte(static_cast<unsigned>(i) * step);
  return b;
}

// A large message is read where the connection assembled it (in 1 MiB blocks, never joined):
// values that straddle blocks arrive whole, and a decoded Binary owns its bytes, so it stays
// intact after the blocks it was read from went back to the pool and carried other messages.
TEST(Transfer, LargeValuesReadFromTheirBlocksOutliveTheMessage) {
  auto server = planet_test::start_test_server();
  Communicator client;
  auto peer = client.connect("127.0.0.1", server.port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy echo = Proxy(client, peer, "/echo").with_timeout(120s);

  const Binary first = pattern_of((5u << 20) + 3, 13);
  const Binary kept = echo.call(Echo::echo_binary, first);
  // Several binaries in one message, each crossing block boundaries at other offsets.
  const std::vector<Binary> several{pattern_of((3u << 19) + 1, 7), pattern_of(5, 3),
                                    pattern_of((1u << 20) + 17, 11)};
  EXPECT_EQ(echo.call(Echo::echo_binaries, several), several);
  // A sequence of bytes, read element by element across the blocks.
  std::vector<std::uint8_t> bytes((2u << 20) + 9);
  for (std::size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<std::uint8_t>(i * 5);
  EXPECT_EQ(echo.call(Echo::echo_bytes, bytes), bytes);
  const Binary second = pattern_of(5u << 20, 29);
  EXPECT_EQ(echo.call(Echo::echo_binary, second), second);
  EXPECT_EQ(kept, first) << "a Binary changed after its message's memory was reused";
}

// A servant still working on a call with a large argument (here: held until released) does not
// hold up small calls on the same connection: large messages are dispatched on the bulk thread.
struct Holder {
  static constexpr std::string_view type_id = "test::Holder";
  static constexpr Operation<std::int64_t(Binary)> hold{"hold"};
  static constexpr Operation<std::int32_t(std::int32_t)> ping{"ping"};
};

TEST(Transfer, SmallCallsAreAnsweredWhileAServantWorksOnALargeArgument) {
  Communicator server;
  std::atomic<bool> holding{false};
  std::binary_semaphore release{0};
  auto servant = std::make_shared<Servant>(std::string(Holder::type_id));
  servant->implement(Holder::hold, [&](const Binary& b) {
    holding = true;
    // Bounded, so a broken bulk path fails the test instead of hanging it.
    const bool released = release.try_acquire_for(30s);
    return released ? static_cast<std::int64_t>(b.bytes.size()) : std::int64_t{-1};
  });
  servant->implement(Holder::ping, [](std::int32_t x) { return x; });
  server.adapter().add("/holder", servant);
  const std::uint16_t port = server.listen("127.0.0.1", 0);

  Communicator client;
  auto peer = client.connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(20s));
  const Proxy holder = Proxy(client, peer, "/holder").with_timeout(60s);
  Binary big;
  big.bytes.assign(3u << 20, std::byte{0x5A});  // three reassembly blocks
  auto held = holder.async_call(Holder::hold, {std::move(big)}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return holding.load(); }, 30s));

  // Dispatched on the io thread, the held servant would leave these unanswered until released.
  const Proxy quick = holder.with_timeout(5s);
  for (std::int32_t i = 0; i < 100; ++i) ASSERT_EQ(quick.call(Holder::ping, i), i);
  EXPECT_EQ(held.wait_for(0s), std::future_status::timeout);
  release.release();
  EXPECT_EQ(held.get(), std::int64_t{3} << 20);
}

TEST(BufferPool, RecyclesLargeBuffersAndGivesBackIdleOnes) {
  detail::trim_buffers(0s);
  ASSERT_EQ(detail::pooled_bytes(), 0u);
  std::vector<std::byte> small(1000);
  detail::give_buffer(std::move(small));
  EXPECT_EQ(detail::pooled_bytes(), 0u) << "buffers below 1 MiB are not pooled";

  std::vector<std::byte> large = detail::take_buffer(2u << 20);
  ASSERT_GE(large.capacity(), 2u << 20);
  large.assign(2u << 20, std::byte{1});
  const std::byte* memory = large.data();
  detail::give_buffer(std::move(large));
  EXPECT_GE(detail::pooled_bytes(), 2u << 20);

  std::vector<std::byte> again = detail::take_buffer(1u << 20);
  EXPECT_EQ(again.data(), memory) << "the pooled buffer is handed out again";
  EXPECT_TRUE(again.empty());
  EXPECT_EQ(detail::pooled_bytes(), 0u);
  EXPECT_GT(detail::take_buffer(4u << 20).capacity(), 0u) << "too large for the pool: allocated";

  detail::give_buffer(std::move(again));
  detail::trim_buffers(1h);
  EXPECT_GT(detail::pooled_bytes(), 0u) << "recently used buffers stay";
  detail::trim_buffers(0s);
  EXPECT_EQ(detail::pooled_bytes(), 0u) << "idle buffers go back to the allocator";
}

TEST(Transfer, SenderMemoryIsBoundedWhenTheReceiverStopsReadingAndNothingIsLost) {
  // The receiver is a separate process that we freeze: its socket buffers fill, then our
  // send queue, and further sends fail with `overloaded` instead of growing memory.
  auto server = planet_test::start_test_server({"--heartbeat-timeout-ms", "600000"});
  CommunicatorOptions options;
  options.connection.send_queue_limit = 4u << 20;
  options.connection.max_message_size = 1u << 20;
  options.connection.receive_budget = 4u << 20;
  options.connection.heartbeat_timeout = 600s;
  Communicator client(options);
  auto peer = client.connect("127.0.0.1", server.port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy echo(client, peer, "/echo");

  server.process->freeze();
  Binary chunk;
  chunk.bytes.resize(256u << 10, std::byte{1});
  std::int64_t accepted = 0;
  bool overloaded = false;
  std::size_t max_queued = 0;
  for (int i = 0; i < 100000 && !overloaded; ++i) {  // 25 GB if nothing pushed back
    try {
      echo.notify(Echo::absorb, chunk);
      ++accepted;
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::overloaded) << e.what();
      EXPECT_NE(std::string(e.what()).find("send queue"), std::string::npos) << e.what();
      overloaded = true;
    }
    max_queued = std::max(max_queued, peer->connection()->queued_bytes());
  }
  EXPECT_TRUE(overloaded);
  EXPECT_LE(max_queued, options.connection.send_queue_limit);
  EXPECT_LT(accepted, 200) << "the sender kept accepting far more than its queue limit";

  // Resume the receiver: everything accepted is delivered, then new sends work again.
  server.process->thaw();
  ASSERT_TRUE(planet_test::wait_until([&] { return peer->connection()->queued_bytes() == 0; }, 60s));
  EXPECT_NO_THROW(echo.notify(Echo::absorb, chunk));
  ++accepted;
  // Small calls may overtake the last large message (frames interleave), so poll.
  std::vector<std::int64_t> absorbed;
  EXPECT_TRUE(planet_test::wait_until([&] {
    absorbed = echo.with_timeout(60s).call(Echo::absorbed);
    return absorbed.at(1) == accepted;
  }, 60s));
  EXPECT_EQ(absorbed.at(1), accepted);
  EXPECT_EQ(absorbed.at(0), accepted * static_cast<std::int64_t>(chunk.bytes.size()));
}

// --- A raw receiver that never grants credit -----------------------------------------------

class RawListener {
 public:
  RawListener() {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr);
    ::listen(fd_, 4);
    socklen_t len = sizeof addr;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&addr), &len);
    port_ = ntohs(addr.sin_port);
  }
  ~RawListener() {
    if (conn_ >= 0) ::close(conn_);
    ::close(fd_);
  }
  std::uint16_t port() const { return port_; }
  void accept() { conn_ = ::accept(fd_, nullptr, nullptr); }
  // Reads one whole frame; false on timeout or EOF.
  bool read_frame(FrameHeader& h, std::vector<std::byte>& payload, std::chrono::milliseconds t) {
    std::byte header[kFrameHeaderSize];
    if (!read_exact(header, kFrameHeaderSize, t)) return false;
    auto parsed = parse_header(std::span<const std::byte>(header, kFrameHeaderSize));
    if (!parsed.header) return false;
    h = *parsed.header;
    payload.resize(h.payload_size());
    return payload.empty() || read_exact(payload.data(), payload.size(), t);
  }
  void send_frame(FrameCode code, const std::vector<std::byte>& payload, std::uint32_t msg = 0) {
    FrameHeader h;
    h.code = code;
    h.msg_no = msg;
    h.length = static_cast<std::uint32_t>(kFrameHeaderSize + payload.size());
    auto header = encode_header(h);
    ASSERT_EQ(::send(conn_, header.data(), header.size(), MSG_NOSIGNAL),
              static_cast<ssize_t>(header.size()));
    if (!payload.empty()) {
      ASSERT_EQ(::send(conn_, payload.data(), payload.size(), MSG_NOSIGNAL),
                static_cast<ssize_t>(payload.size()));
    }
  }

 private:
  bool read_exact(std::byte* p, std::size_t n, std::chrono::milliseconds t) {
    while (n > 0) {
      pollfd pfd{conn_, POLLIN, 0};
      if (::poll(&pfd, 1, static_cast<int>(t.count())) <= 0) return false;
      const ssize_t got = ::recv(conn_, p, n, 0);
      if (got <= 0) return false;
      p += got;
      n -= static_cast<std::size_t>(got);
    }
    return true;
  }
  int fd_ = -1;
  int conn_ = -1;
  std::uint16_t port_ = 0;
};

TEST(Transfer, SenderStopsAtTheWindowUntilTheReceiverAcksAndSmallMessagesStillPass) {
  RawListener raw;
  CommunicatorOptions options;
  options.connection.heartbeat_interval = 60s;
  options.connection.heartbeat_timeout = 600s;
  Communicator client(options);
  auto peer = client.connect("127.0.0.1", raw.port());
  raw.accept();
  FrameHeader h;
  std::vector<std::byte> payload;
  ASSERT_TRUE(raw.read_frame(h, payload, 10s));
  ASSERT_EQ(h.code, FrameCode::connect);
  std::vector<std::byte> ack;
  Writer w(ack);
  w.u8(kConnectAccept);
  w.str("raw-receiver");
  raw.send_frame(FrameCode::connect_ack, ack);
  ASSERT_TRUE(peer->wait_connected(10s));
  Proxy sink(client, peer, "/sink");

  Binary big;
  big.bytes.resize(1u << 20);
  sink.notify(Echo::absorb, big);  // 65 frames

  std::uint32_t big_msg = 0;
  std::uint32_t big_frames = 0;
  for (std::uint32_t i = 0; i < kWindowFrames; ++i) {
    ASSERT_TRUE(raw.read_frame(h, payload, 10s)) << "frame " << i << " of the window";
    big_msg = h.msg_no;
    EXPECT_EQ(h.frame_no, i);
    ++big_frames;
  }
  // The window is used up: the next frame to arrive is a new small message, not frame 8.
  sink.notify(Echo::count, 1);
  ASSERT_TRUE(raw.read_frame(h, payload, 10s));
  EXPECT_NE(h.msg_no, big_msg);
  EXPECT_TRUE(h.final);
  EXPECT_EQ(h.frame_no, 0u);

  // One DATA_ACK(more) grants exactly kAckEvery more frames.
  std::vector<std::byte> more;
  Writer mw(more);
  mw.u32(big_msg);
  mw.u32(static_cast<std::uint32_t>(AckCode::more));
  raw.send_frame(FrameCode::data_ack, more, big_msg);
  for (std::uint32_t i = 0; i < kAckEvery; ++i) {
    ASSERT_TRUE(raw.read_frame(h, payload, 10s));
    EXPECT_EQ(h.msg_no, big_msg);
    EXPECT_EQ(h.frame_no, kWindowFrames + i);
  }
  // A heartbeat-free quiet period shows no further frame was sent without credit.
  EXPECT_FALSE(raw.read_frame(h, payload, 300ms)) << "frame sent beyond the window";

  // DATA_ACK(no more) makes the sender end the message with an empty final frame.
  std::vector<std::byte> stop;
  Writer sw(stop);
  sw.u32(big_msg);
  sw.u32(static_cast<std::uint32_t>(AckCode::no_more));
  raw.send_frame(FrameCode::data_ack, stop, big_msg);
  ASSERT_TRUE(raw.read_frame(h, payload, 10s));
  EXPECT_EQ(h.msg_no, big_msg);
  EXPECT_TRUE(h.final);
  EXPECT_TRUE(payload.empty());
  EXPECT_TRUE(planet_test::wait_until([&] { return peer->connection()->queued_bytes() == 0; }));
}

TEST(Transfer, OversizedCallIsRefusedWithAnErrorAndTheLinkStaysUp) {
  auto server = planet_test::start_test_server({"--max-message", "1048576"});
  Communicator client;
  auto peer = client.connect("127.0.0.1", server.port);
  ASSERT_TRUE(peer->wait_connected(20s));
  Proxy echo(client, peer, "/echo");
  Binary big;
  big.bytes.resize(3u << 20);
  try {
    echo.call(Echo::size_of, big);
    FAIL() << "a 3 MiB call to a server with a 1 MiB limit must fail";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::overloaded) << e.what();
    EXPECT_NE(std::string(e.what()).find("max_message_size"), std::string::npos) << e.what();
  }
  EXPECT_EQ(echo.call(Echo::echo_int, 9), 9);
  // Repeated refusals do not use up the receiver's interleaving slots.
  for (int i = 0; i < 40; ++i) EXPECT_THROW(echo.call(Echo::size_of, big), Error);
  EXPECT_EQ(echo.call(Echo::echo_int, 10), 10);
  EXPECT_EQ(peer->connect_count(), 1u);
}

}  // namespace
}  // namespace icars::planet
