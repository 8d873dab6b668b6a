// Resource exhaustion of the PLANET transport: a server must keep serving legitimate clients when
// others exhaust its file descriptors, hold all connection slots from one host, trickle bytes or
// leave messages half sent, or pin receive buffers over many connections; and it must not fill
// its log (or its CPU) while it defends itself. Real loopback sockets throughout: well-behaved
// clients are Communicators, hostile ones raw POSIX sockets (from 127.0.0.2 and others where the
// source address matters: all of 127/8 is loopback on Linux) or a forked flooding process.
//
// The PLANET headers come first: they include asio before any standard header, as the library's
// own .cc files do (see malformed_input_test.cc).
#include "icars/planet/communicator.h"
#include "icars/planet/connection_manager.h"
#include "icars/planet/proxy.h"
// (keep the lines above first)

#include <arpa/inet.h>
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

#include "child_process.h"
#include "tls_files.h"
#include "icars/planet/frame.h"
#include "test_interfaces.h"

namespace icars::planet {
namespace {

using namespace std::chrono_literals;
using Bytes = std::vector<std::byte>;
using Clock = std::chrono::steady_clock;
using planet_test::wait_until;

// --- Log capture -----------------------------------------------------------------------------

class CaptureSink final : public spdlog::sinks::base_sink<std::mutex> {
 public:
  // Lines at `level` or above that contain `text`.
  std::vector<std::string> lines(std::string_view text,
                                 spdlog::level::level_enum level = spdlog::level::info) const {
    std::lock_guard lock(lines_mutex_);
    std::vector<std::string> out;
    for (const auto& [l, line] : lines_) {
      if (l >= level && line.find(text) != std::string::npos) out.push_back(line);
    }
    return out;
  }
  std::size_t count(std::string_view text,
                    spdlog::level::level_enum level = spdlog::level::info) const {
    return lines(text, level).size();
  }

 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    std::lock_guard lock(lines_mutex_);
    lines_.emplace_back(msg.level, std::string(msg.payload.data(), msg.payload.size()));
  }
  void flush_() override {}

 private:
  mutable std::mutex lines_mutex_;
  std::vector<std::pair<spdlog::level::level_enum, std::string>> lines_;
};

std::shared_ptr<spdlog::logger> capturing_logger(const std::shared_ptr<CaptureSink>& sink) {
  auto logger = std::make_shared<spdlog::logger>("resource-limits", sink);
  logger->set_level(spdlog::level::debug);
  return logger;
}

// --- A transport-level server: a ConnectionManager on its own io thread --------------------

class TransportServer final : public MessageHandler {
 public:
  explicit TransportServer(ConnectionOptions options)
      : io_(std::make_shared<asio::io_context>()),
        work_(asio::make_work_guard(*io_)),
        manager_(io_, *this, options, capturing_logger(sink)) {
    port = manager_.listen("127.0.0.1", 0);
    thread_ = std::thread([this] { io_->run(); });
  }
  ~TransportServer() override {
    // Every connection closes and its handlers run (they hold the connection, which holds the
    // io_context): the io thread ends once nothing is left to do.
    manager_.shutdown();
    work_.reset();
    thread_.join();
  }

  ConnectionManager& manager() { return manager_; }

  // Bytes of incomplete messages held by all open connections now.
  std::size_t incomplete_bytes() const {
    std::size_t total = 0;
    for (const auto& c : manager_.connections()) total += c->incomplete_bytes();
    return total;
  }
  std::uint64_t bytes_received() const {
    std::uint64_t total = 0;
    for (const auto& c : manager_.connections()) total += c->stats().bytes_received;
    return total;
  }

  void on_message(const std::shared_ptr<Connection>&, std::span<const std::byte> m) override {
    ++messages;
    message_bytes += m.size();
  }
  void on_message_refused(const std::shared_ptr<Connection>&, std::span<const std::byte>,
                          const std::string&) override {
    ++refused;
  }
  void on_open(const std::shared_ptr<Connection>& c) override {
    if (opened) opened(c);
  }
  void on_close(const std::shared_ptr<Connection>&, const Error&) override {}

  std::shared_ptr<CaptureSink> sink = std::make_shared<CaptureSink>();
  std::uint16_t port = 0;
  std::atomic<int> messages{0};
  std::atomic<std::size_t> message_bytes{0};
  std::atomic<int> refused{0};
  std::function<void(const std::shared_ptr<Connection>&)> opened;  // set before clients connect

 private:
  std::shared_ptr<asio::io_context> io_;
  asio::executor_work_guard<asio::io_context::executor_type> work_;
  ConnectionManager manager_;
  std::thread thread_;
};

// --- Raw clients -----------------------------------------------------------------------------

sockaddr_in address_of(const char* ip, std::uint16_t port) {
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(port);
  if (::inet_pton(AF_INET, ip, &a.sin_addr) != 1) throw std::runtime_error("bad address");
  return a;
}

Bytes frame(FrameCode code, const Bytes& payload = {}, std::uint32_t msg_no = 0,
            std::uint32_t frame_no = 0, bool final = true) {
  FrameHeader h;
  h.length = static_cast<std::uint32_t>(kFrameHeaderSize + payload.size());
  h.msg_no = msg_no;
  h.frame_no = frame_no;
  h.final = final;
  h.code = code;
  const auto header = encode_header(h);
  Bytes out(header.begin(), header.end());
  out.insert(out.end(), payload.begin(), payload.end());
  return out;
}

std::uint32_t get_u32(const Bytes& b, std::size_t at) {
  std::uint32_t v = 0;
  for (std::size_t i = 0; i < 4; ++i) v = (v << 8) | std::to_integer<std::uint32_t>(b[at + i]);
  return v;
}

Bytes connect_payload(std::string_view pun) {
  Bytes p;
  for (int shift = 24; shift >= 0; shift -= 8) {
    p.push_back(static_cast<std::byte>((pun.size() >> shift) & 0xFFu));
  }
  for (char c : pun) p.push_back(static_cast<std::byte>(c));
  return p;
}

struct RawFrame {
  FrameHeader header;
  Bytes payload;
};

class RawClient {
 public:
  // Connects to 127.0.0.1:port from `source` (any 127/8 address).
  explicit RawClient(std::uint16_t port, const char* source = "127.0.0.1") {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd_ < 0) throw std::system_error(errno, std::generic_category(), "socket");
    const sockaddr_in from = address_of(source, 0);
    if (::bind(fd_, reinterpret_cast<const sockaddr*>(&from), sizeof from) != 0) {
      throw std::system_error(errno, std::generic_category(), "bind");
    }
    const sockaddr_in to = address_of("127.0.0.1", port);
    if (::connect(fd_, reinterpret_cast<const sockaddr*>(&to), sizeof to) != 0) {
      throw std::system_error(errno, std::generic_category(), "connect");
    }
    const int one = 1;
    ::setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  }
  RawClient(RawClient&& o) noexcept : fd_(std::exchange(o.fd_, -1)), buffer_(std::move(o.buffer_)) {}
  RawClient& operator=(RawClient&&) = delete;
  ~RawClient() {
    if (fd_ >= 0) ::close(fd_);
  }

  bool send(const Bytes& b) {
    std::size_t off = 0;
    while (off < b.size()) {
      const ssize_t n = ::send(fd_, b.data() + off, b.size() - off, MSG_NOSIGNAL);
      if (n < 0) {
        if (errno == EINTR) continue;
        return false;
      }
      off += static_cast<std::size_t>(n);
    }
    return true;
  }

  // The next frame, or nullopt on timeout or when the server closed the connection.
  std::optional<RawFrame> read_frame(std::chrono::milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (buffer_.size() >= kFrameHeaderSize) {
        const HeaderParse parsed = parse_header(buffer_);
        if (!parsed.error.empty()) throw std::runtime_error("bad frame from the server");
        if (parsed.header && buffer_.size() >= parsed.header->length) {
          RawFrame f{*parsed.header, Bytes(buffer_.begin() + kFrameHeaderSize,
                                           buffer_.begin() + parsed.header->length)};
          buffer_.erase(buffer_.begin(), buffer_.begin() + parsed.header->length);
          return f;
        }
      }
      if (!fill(deadline)) return std::nullopt;
    }
  }

  // CONNECT as `pun`; the CONNECT_ACK's status and text (nullopt: no answer).
  std::optional<std::pair<std::uint8_t, std::string>> handshake(std::string_view pun) {
    if (!send(frame(FrameCode::connect, connect_payload(pun)))) return std::nullopt;
    auto f = read_frame(10s);
    if (!f || f->header.code != FrameCode::connect_ack || f->payload.size() < 5) return std::nullopt;
    const std::uint32_t n = get_u32(f->payload, 1);
    return std::pair{std::to_integer<std::uint8_t>(f->payload[0]),
                     std::string(reinterpret_cast<const char*>(f->payload.data() + 5), n)};
  }

  // True once the server closed the connection within `timeout` (frames are discarded;
  // heartbeats are not answered).
  bool wait_closed(std::chrono::milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    while (fill(deadline)) buffer_.clear();
    return closed_;
  }
  bool closed() const { return closed_; }
  int fd() const { return fd_; }

 private:
  // Reads what arrives by `deadline`; false on timeout or close.
  bool fill(Clock::time_point deadline) {
    for (;;) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
      pollfd p{fd_, POLLIN, 0};
      const int ready = ::poll(&p, 1, static_cast<int>(std::max<std::int64_t>(0, left.count())));
      if (ready < 0 && errno == EINTR) continue;
      if (ready <= 0) return false;
      std::byte chunk[64 * 1024];
      const ssize_t n = ::recv(fd_, chunk, sizeof chunk, 0);
      if (n < 0 && (errno == EINTR || errno == EAGAIN)) continue;
      if (n <= 0) {
        closed_ = true;
        return false;
      }
      buffer_.insert(buffer_.end(), chunk, chunk + n);
      return true;
    }
  }

  int fd_ = -1;
  Bytes buffer_;
  bool closed_ = false;
};

// --- 1. Descriptor exhaustion ----------------------------------------------------------------

std::size_t open_descriptors() {
  std::size_t n = 0;
  for ([[maybe_unused]] const auto& e : std::filesystem::directory_iterator("/proc/self/fd")) ++n;
  return n;
}

// Lowers this process's soft descriptor limit for the test's duration.
class SoftDescriptorLimit {
 public:
  explicit SoftDescriptorLimit(rlim_t soft) {
    ::getrlimit(RLIMIT_NOFILE, &saved_);
    rlimit lowered = saved_;
    lowered.rlim_cur = soft;
    if (::setrlimit(RLIMIT_NOFILE, &lowered) != 0) throw std::runtime_error("setrlimit failed");
  }
  ~SoftDescriptorLimit() { ::setrlimit(RLIMIT_NOFILE, &saved_); }

 private:
  rlimit saved_{};
};

// A forked process holding `count` silent connections to the server until told to let go.
class Flood {
 public:
  Flood(std::uint16_t port, int count) {
    int up[2];
    int down[2];
    if (::pipe2(up, O_CLOEXEC) != 0 || ::pipe2(down, O_CLOEXEC) != 0) throw std::runtime_error("pipe");
    const sockaddr_in to = address_of("127.0.0.1", port);
    rlimit limit{};
    ::getrlimit(RLIMIT_NOFILE, &limit);
    limit.rlim_cur = limit.rlim_max;  // the parent's soft limit may be lowered: not the child's
    pid_ = ::fork();
    if (pid_ < 0) throw std::runtime_error("fork");
    if (pid_ == 0) {
      // The child only makes async-signal-safe calls (the parent has threads).
      ::close(up[0]);
      ::close(down[1]);
      ::setrlimit(RLIMIT_NOFILE, &limit);
      int opened = 0;
      for (int i = 0; i < count; ++i) {
        const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
        if (fd < 0) break;
        if (::connect(fd, reinterpret_cast<const sockaddr*>(&to), sizeof to) == 0) ++opened;
      }
      const char done = opened == count ? 'y' : 'n';
      (void)!::write(up[1], &done, 1);
      char ignored = 0;
      (void)!::read(down[0], &ignored, 1);  // until the parent writes or exits
      ::_exit(0);
    }
    ::close(up[1]);
    ::close(down[0]);
    up_ = up[0];
    down_ = down[1];
  }
  ~Flood() {
    release();
    if (up_ >= 0) ::close(up_);
  }
  // True once all connections are open (connect() returns when the kernel queued them).
  bool wait_connected() {
    pollfd p{up_, POLLIN, 0};
    if (::poll(&p, 1, 30000) != 1) return false;
    char c = 0;
    return ::read(up_, &c, 1) == 1 && c == 'y';
  }
  // Closes all the flood's connections (the process exits) and reaps it.
  void release() {
    if (down_ < 0) return;
    ::close(down_);
    down_ = -1;
    int status = 0;
    ::waitpid(pid_, &status, 0);
  }

 private:
  pid_t pid_ = -1;
  int up_ = -1;
  int down_ = -1;
};

TEST(DescriptorLimit, IsRaisedToTheHardLimit) {
  rlimit limit{};
  ASSERT_EQ(::getrlimit(RLIMIT_NOFILE, &limit), 0);
  if (limit.rlim_max == RLIM_INFINITY || limit.rlim_max < 512) GTEST_SKIP() << "hard limit too low";
  {
    SoftDescriptorLimit low(256);
    EXPECT_EQ(raise_descriptor_limit(), static_cast<std::size_t>(limit.rlim_max));
    rlimit now{};
    ::getrlimit(RLIMIT_NOFILE, &now);
    EXPECT_EQ(now.rlim_cur, limit.rlim_max);
  }
}

// A flood of silent connections larger than the descriptor limit: the server stops accepting at
// its descriptor cap (never running out), says so once a second, and serves again afterwards.
TEST(DescriptorLimit, FloodBeyondTheDescriptorLimitPausesAcceptingAndTheServerRecovers) {
  CommunicatorOptions so;
  auto sink = std::make_shared<CaptureSink>();
  so.logger = capturing_logger(sink);
  so.connection.handshake_timeout = 1s;  // the flood's silent connections are closed soon
  Communicator server(so);
  server.adapter().add("/echo", planet_test::make_echo_servant(server));
  Communicator client;  // its own descriptors are taken before the limit drops

  std::optional<Flood> flood;
  std::uint16_t port = 0;
  {
    // Room for 40 more descriptors than are open now: far fewer than the flood's connections.
    const std::size_t soft = open_descriptors() + 40;
    SoftDescriptorLimit low(soft);
    port = server.listen("127.0.0.1", 0);
    const std::size_t cap = server.connections().connection_cap();
    EXPECT_EQ(cap, soft > 2 * kDescriptorReserve ? soft - kDescriptorReserve : soft / 2);
    EXPECT_EQ(sink->count(fmt::format("max_connections lowered from 1024 to {}", cap),
                          spdlog::level::warn),
              1u);

    flood.emplace(port, 150);
    ASSERT_TRUE(flood->wait_connected());
    ASSERT_TRUE(wait_until([&] { return sink->count("not accepting connections") > 0; }, 20s));
    // The silent connections time out a batch at a time, and the flood drains within bounds.
    ASSERT_TRUE(wait_until([&] { return sink->count("timed out: no CONNECT", spdlog::level::debug) >= 150; }, 60s))
        << sink->count("timed out: no CONNECT", spdlog::level::debug);
    EXPECT_EQ(server.connections().accept_failures(), 0u) << "the process ran out of descriptors";
    EXPECT_LE(sink->count("not accepting connections", spdlog::level::warn), 15u);
    flood->release();
  }
  auto peer = client.connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(30s)) << peer->last_error();
  EXPECT_EQ(Proxy(client, peer, "/echo").call(planet_test::Echo::echo_int, 42), 42);
}

// Descriptors used up by something else: accept() fails with EMFILE for as long as that lasts.
// Before the fix the server retried at once, for ever (5 million log lines in 12 s at 75% CPU).
TEST(DescriptorLimit, AcceptBacksOffWhileDescriptorsAreExhaustedAndRecovers) {
#if defined(__SANITIZE_ADDRESS__)  // the sanitizer build, which also has UBSan's vptr check
  // UBSan checks an object's dynamic type before a member call on it, and when the type is not
  // in its small cache it probes memory through a pipe. With every descriptor taken the pipe
  // cannot be opened and a valid std::error_category (compared in asio's accept path) is
  // reported as an invalid vptr, failing the run whenever the cache misses.
  GTEST_SKIP() << "needs a build without UBSan's vptr check: it takes every descriptor";
#endif
  CommunicatorOptions so;
  auto sink = std::make_shared<CaptureSink>();
  so.logger = capturing_logger(sink);
  so.connection.handshake_timeout = 1s;
  Communicator server(so);
  server.adapter().add("/echo", planet_test::make_echo_servant(server));
  Communicator client;
  const std::uint16_t port = server.listen("127.0.0.1", 0);

  std::uint64_t failures = 0;
  double seconds = 0;
  {
    SoftDescriptorLimit low(open_descriptors() + 64);
    // Take every descriptor left but the four the flooding process's pipes need.
    std::vector<int> hogs;
    const auto fill = [&] {
      for (;;) {
        const int fd = ::dup(STDERR_FILENO);
        if (fd < 0) break;
        hogs.push_back(fd);
      }
    };
    fill();
    for (int i = 0; i < 4 && !hogs.empty(); ++i) {
      ::close(hogs.back());
      hogs.pop_back();
    }
    Flood flood(port, 10);  // pending connections the server cannot accept now
    fill();
    ASSERT_TRUE(flood.wait_connected());
    ASSERT_TRUE(wait_until([&] {
      fill();
      return server.connections().accept_failures() > 0;
    }, 20s)) << "accept never failed";
    const auto failures_before = server.connections().accept_failures();
    const auto start = Clock::now();
    // A fixed window in which the rate of failed accepts is what is measured.
    std::this_thread::sleep_for(3s);
    seconds = std::chrono::duration<double>(Clock::now() - start).count();
    failures = server.connections().accept_failures() - failures_before;
    for (int fd : hogs) ::close(fd);
  }
  std::cout << failures << " failed accepts in " << seconds << " s while descriptors were exhausted\n";
  // Backing off 50 ms doubling to 1 s: a handful of attempts, not a busy loop.
  EXPECT_LE(static_cast<double>(failures), seconds / 0.05 + 5)
      << failures << " failed accepts in " << seconds << " s: accept is not backing off";
  const auto lines = sink->lines("accept failed", spdlog::level::warn);
  ASSERT_GE(lines.size(), 1u);
  EXPECT_LE(static_cast<double>(lines.size()), seconds + 3) << "accept failures are not rate-limited";
  EXPECT_NE(lines.front().find("Too many open files"), std::string::npos) << lines.front();
  EXPECT_NE(lines.front().find("since the last report"), std::string::npos) << lines.front();

  auto peer = client.connect("127.0.0.1", port);
  ASSERT_TRUE(peer->wait_connected(30s)) << peer->last_error();
  EXPECT_EQ(Proxy(client, peer, "/echo").call(planet_test::Echo::echo_int, 42), 42);
}

// --- 2. Connection slots per address ---------------------------------------------------------

TEST(PerAddressLimit, OneHostCannotTakeEverySlot) {
  ConnectionOptions options;
  options.max_connections = 80;  // more than max_connections_per_address (64 by default)
  TransportServer server(options);
  std::vector<RawClient> flood;
  int admitted = 0;
  std::string refusal;
  for (int i = 0; i < 100; ++i) {
    RawClient c(server.port, "127.0.0.1");
    auto ack = c.handshake(fmt::format("flood-{}", i));
    ASSERT_TRUE(ack) << "no CONNECT_ACK for client " << i;
    if (ack->first == kConnectAccept) {
      ++admitted;
      flood.push_back(std::move(c));
    } else {
      EXPECT_EQ(ack->first, kConnectDeny);
      refusal = ack->second;
    }
  }
  EXPECT_EQ(admitted, 64);
  EXPECT_NE(refusal.find("127.0.0.1"), std::string::npos) << refusal;
  EXPECT_NE(refusal.find("max_connections_per_address"), std::string::npos) << refusal;
  // Denials repeat without end: the log says so once a second per address, not per attempt.
  EXPECT_LE(server.sink->count("denied", spdlog::level::warn), 2u);

  // Another host still gets in, and so does a well-behaved client once the flood has gone.
  RawClient other(server.port, "127.0.0.2");
  auto ack = other.handshake("device-manager");
  ASSERT_TRUE(ack);
  EXPECT_EQ(ack->first, kConnectAccept) << ack->second;
  flood.clear();
  ASSERT_TRUE(wait_until([&] { return server.manager().connections().size() == 1; }));
  RawClient again(server.port, "127.0.0.1");
  ack = again.handshake("back");
  ASSERT_TRUE(ack);
  EXPECT_EQ(ack->first, kConnectAccept) << ack->second;
}

// --- 3. Progress of messages in flight -------------------------------------------------------

ConnectionOptions fast_progress_options() {
  ConnectionOptions o;
  o.heartbeat_interval = 100ms;
  o.heartbeat_timeout = 5s;  // longer than the progress timeout: it must not be the reason
  o.message_progress_timeout = 500ms;
  return o;
}

TEST(ProgressTimeout, TricklingClientIsClosed) {
  TransportServer server(fast_progress_options());
  RawClient c(server.port);
  ASSERT_EQ(c.handshake("trickler").value_or(std::pair{std::uint8_t{9}, ""}).first, kConnectAccept);
  // One byte of a frame every 50 ms: bytes keep arriving, a frame never completes.
  const Bytes f = frame(FrameCode::data, Bytes(kMaxFramePayload), 1);
  const auto start = Clock::now();
  bool closed = false;
  for (std::size_t i = 0; i < f.size() && Clock::now() - start < 10s; ++i) {
    if (!c.send(Bytes{f[i]}) || c.wait_closed(50ms)) {
      closed = true;
      break;
    }
  }
  EXPECT_TRUE(closed) << "a trickling client held its connection for 10 s";
  EXPECT_LT(Clock::now() - start, 5s);
  EXPECT_TRUE(wait_until([&] { return server.sink->count("has been incomplete for") == 1; }, 10s));
}

TEST(ProgressTimeout, IncompleteIncomingMessageIsClosed) {
  TransportServer server(fast_progress_options());
  RawClient c(server.port);
  ASSERT_EQ(c.handshake("stall").value_or(std::pair{std::uint8_t{9}, ""}).first, kConnectAccept);
  // The first frame of a two-frame message, then only heartbeats: the link is alive, the message
  // never moves (as when a middlebox dropped the rest of its window).
  ASSERT_TRUE(c.send(frame(FrameCode::data, Bytes(kMaxFramePayload), 1, 0, false)));
  const auto start = Clock::now();
  bool closed = false;
  while (!closed && Clock::now() - start < 10s) {
    if (!c.send(frame(FrameCode::heartbeat))) break;
    closed = c.wait_closed(100ms);
  }
  EXPECT_TRUE(closed || c.closed()) << "a stalled message held its connection for 10 s";
  EXPECT_TRUE(wait_until(
      [&] { return server.sink->count("message #1 from stall") == 1; }, 10s));
  EXPECT_EQ(server.sink->count("has received no frame"), 1u);
}

TEST(ProgressTimeout, OutgoingMessageWithoutCreditIsClosed) {
  TransportServer server(fast_progress_options());
  server.opened = [](const std::shared_ptr<Connection>& c) {
    c->send(Bytes(1u << 20));  // 64 frames; only 8 go out without a DATA_ACK
  };
  RawClient c(server.port);
  ASSERT_EQ(c.handshake("no-acks").value_or(std::pair{std::uint8_t{9}, ""}).first, kConnectAccept);
  // Read everything and answer heartbeats, but never grant credit.
  int data_frames = 0;
  const auto start = Clock::now();
  bool closed = false;
  while (Clock::now() - start < 10s) {
    auto f = c.read_frame(200ms);
    if (!f) {
      if (c.closed()) {
        closed = true;
        break;
      }
      continue;
    }
    if (f->header.code == FrameCode::data) ++data_frames;
    if (f->header.code == FrameCode::heartbeat) c.send(frame(FrameCode::heartbeat_ack));
  }
  EXPECT_TRUE(closed) << "a message without credit held its connection for 10 s";
  EXPECT_EQ(data_frames, static_cast<int>(kWindowFrames));
  EXPECT_TRUE(wait_until(
      [&] { return server.sink->count("for flow-control credit (DATA_ACK)") == 1; }, 10s));
}

// --- 4. One receive budget for all connections ------------------------------------------------

// A raw client sending one multi-frame message as fast as the server's credit allows.
struct Sender {
  RawClient socket;
  std::uint32_t next_frame = 0;
  std::uint32_t credit = kWindowFrames;
  std::size_t sent = 0;
  std::uint64_t other_frames = 1;  // CONNECT, then heartbeat acks
  bool refused = false;
  bool ended = false;  // the final frame is sent

  // Reads what arrived (acks, heartbeats), then sends frames while there is credit, up to
  // `limit` payload bytes (the last one final when `finish`). True if it sent anything.
  bool pump(std::size_t limit, bool finish) {
    while (auto f = socket.read_frame(0ms)) {
      if (f->header.code == FrameCode::heartbeat) {
        socket.send(frame(FrameCode::heartbeat_ack));
        ++other_frames;
      }
      if (f->header.code != FrameCode::data_ack) continue;
      if (get_u32(f->payload, 4) == static_cast<std::uint32_t>(AckCode::no_more)) {
        refused = true;
      } else {
        credit += kAckEvery;
      }
    }
    if (ended) return false;
    if (refused) {  // a refused message still ends with an empty final frame
      socket.send(frame(FrameCode::data, {}, 1, next_frame++, true));
      ended = true;
      return true;
    }
    bool progress = false;
    while (credit > 0 && sent < limit) {
      const std::size_t n = std::min(kMaxFramePayload, limit - sent);
      const bool final = finish && sent + n == limit;
      socket.send(frame(FrameCode::data, Bytes(n, std::byte{0x42}), 1, next_frame++, final));
      sent += n;
      --credit;
      ended = final;
      progress = true;
    }
    return progress;
  }
  std::uint64_t frames_sent() const { return next_frame + other_frames; }
};

std::uint64_t frames_received(TransportServer& server) {
  std::uint64_t total = 0;
  for (const auto& c : server.manager().connections()) total += c->stats().frames_received;
  return total;
}

TEST(ReceiveBudget, HoldsAcrossConnections) {
  ConnectionOptions o;
  o.max_message_size = 1u << 20;
  o.receive_budget = 1u << 20;
  o.total_receive_budget = 2u << 20;
  TransportServer server(o);
  constexpr std::size_t kClients = 8;
  constexpr std::size_t kHalf = 768u << 10;  // each client's message is 1 MiB; it sends 768 KiB
  constexpr std::size_t kWhole = 1u << 20;
  std::vector<Sender> senders;
  for (std::size_t i = 0; i < kClients; ++i) {
    RawClient c(server.port);
    ASSERT_EQ(c.handshake(fmt::format("half-{}", i)).value_or(std::pair{std::uint8_t{9}, ""}).first,
              kConnectAccept);
    senders.push_back(Sender{std::move(c)});
  }
  // Phase 1: every client sends the first 768 KiB of its message as credit allows, until no one
  // can send more and the server has read all that was sent (8 x 768 KiB = 6 MiB if unbounded).
  std::size_t peak = 0;
  auto quiet_since = Clock::now();
  const auto start = Clock::now();
  while (Clock::now() - start < 30s) {
    bool progress = false;
    for (auto& s : senders) progress = s.pump(kHalf, false) || progress;
    peak = std::max(peak, server.incomplete_bytes());
    if (progress) quiet_since = Clock::now();
    std::uint64_t frames = 0;
    bool all_sent = true;
    for (const auto& s : senders) {
      frames += s.frames_sent();
      all_sent = all_sent && (s.sent >= kHalf || s.ended);
    }
    // Settled: the server read every frame sent, and no credit came back for a while.
    if (frames_received(server) >= frames && (all_sent || Clock::now() - quiet_since > 500ms)) break;
    std::this_thread::sleep_for(1ms);
  }
  peak = std::max(peak, server.incomplete_bytes());
  std::cout << "8 half-sent messages pinned at most " << peak << " bytes (total_receive_budget "
            << o.total_receive_budget << ")\n";
  EXPECT_LE(peak, o.total_receive_budget + o.max_message_size)
      << "incomplete messages pinned " << peak << " bytes over " << kClients << " connections";
  EXPECT_LE(server.manager().receive_reserved(), o.total_receive_budget + 2 * o.max_message_size);

  // Phase 2: the clients finish their messages. Each is delivered, or refused (NO_MORE) and
  // answered as such: none waits for ever, and the budget is free again afterwards.
  const auto start2 = Clock::now();
  while (Clock::now() - start2 < 30s) {
    for (auto& s : senders) s.pump(kWhole, true);
    peak = std::max(peak, server.incomplete_bytes());
    int refused = 0;
    for (const auto& s : senders) refused += s.refused ? 1 : 0;
    if (server.messages.load() + refused == static_cast<int>(kClients)) break;
    std::this_thread::sleep_for(1ms);
  }
  int refused = 0;
  for (const auto& s : senders) refused += s.refused ? 1 : 0;
  EXPECT_EQ(server.messages.load() + refused, static_cast<int>(kClients));
  EXPECT_GE(server.messages.load(), 1);
  EXPECT_EQ(server.refused.load(), refused);
  EXPECT_LE(peak, o.total_receive_budget + o.max_message_size);
  EXPECT_TRUE(wait_until([&] { return server.manager().receive_reserved() == 0; }, 10s))
      << server.manager().receive_reserved();
}

// --- 5. Refused clients: back-off and a bounded log ------------------------------------------

TEST(Refusal, DeniedClientBacksOffAndTheServerLogsDenialsOncePerSecond) {
  CommunicatorOptions so;
  auto sink = std::make_shared<CaptureSink>();
  so.logger = capturing_logger(sink);
  Communicator server(so);
  std::atomic<int> attempts{0};
  server.connections().set_acceptor([&](const ConnectRequest&) {
    ++attempts;
    Admission a;
    a.deny = "authentication failed: the token is not a known principal";
    return a;
  });
  const auto port = server.listen("127.0.0.1", 0);

  Communicator client;
  auto peer = client.connect("127.0.0.1", port);
  ASSERT_TRUE(wait_until([&] { return attempts.load() >= 1; }));
  const auto start = Clock::now();
  // A fixed window: the number of attempts in it is what is measured. Before the fix a denied
  // client retried after 10, 20, 40 ... ms up to every 2 s: 10 attempts in 5 s.
  std::this_thread::sleep_for(5s);
  const int seen = attempts.load();
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  peer->stop();
  EXPECT_LE(seen, 4) << seen << " CONNECTs in " << seconds << " s from a client that is denied";
  EXPECT_NE(peer->last_error().find("authentication failed"), std::string::npos)
      << peer->last_error();
  // At most one line a second (with a count of the ones held back) per address.
  EXPECT_LE(static_cast<double>(sink->count("denied", spdlog::level::warn)), seconds + 2);
}

TEST(Refusal, DenialLogIsRateLimitedPerAddress) {
  ConnectionOptions o;
  TransportServer server(o);
  server.manager().set_acceptor([](const ConnectRequest&) {
    Admission a;
    a.deny = "not today";
    return a;
  });
  for (int i = 0; i < 20; ++i) {
    RawClient c(server.port, "127.0.0.1");
    auto ack = c.handshake("pest");
    ASSERT_TRUE(ack);
    EXPECT_EQ(ack->first, kConnectDeny);
  }
  RawClient other(server.port, "127.0.0.3");
  ASSERT_TRUE(other.handshake("neighbour"));
  ASSERT_TRUE(wait_until([&] { return server.sink->count("neighbour") == 1; }));
  // 20 denials from 127.0.0.1 within a second: one line.
  EXPECT_LE(server.sink->count("(127.0.0.1:", spdlog::level::warn), 2u);
  // After a second the next denial from that address says how many were held back.
  std::this_thread::sleep_for(1100ms);
  RawClient late(server.port, "127.0.0.1");
  ASSERT_TRUE(late.handshake("pest"));
  ASSERT_TRUE(wait_until([&] { return server.sink->count("more since the last report") >= 1; }))
      << fmt::format("{}", fmt::join(server.sink->lines("denied"), "\n"));
  // Nothing else about the denied connections above debug level: one line per attempt adds up.
  EXPECT_LE(server.sink->count("connection from 127.0.0.1"), 0u);
}

TEST(Refusal, FailedTlsHandshakesAreLoggedWithTheReasonRateLimited) {
  // A TLS listener; clients that speak plaintext to it fail the TLS handshake.
  const auto dir = std::filesystem::temp_directory_path() / fmt::format("icars-rl-certs-{}", ::getpid());
  planet_test::make_certificates(dir);
  CommunicatorOptions so;
  auto sink = std::make_shared<CaptureSink>();
  so.logger = capturing_logger(sink);
  so.tls = planet_test::server_tls(dir);
  {
    Communicator server(so);
    const auto port = server.listen("127.0.0.1", 0);
    for (int i = 0; i < 10; ++i) {
      RawClient c(port);
      c.send(frame(FrameCode::connect, connect_payload("plaintext")));
      EXPECT_TRUE(c.wait_closed(10s));
    }
    ASSERT_TRUE(wait_until([&] { return sink->count("TLS handshake with", spdlog::level::warn) >= 1; }))
        << "a failed TLS handshake was not logged at warning level";
    const auto lines = sink->lines("TLS handshake with", spdlog::level::info);
    EXPECT_LE(lines.size(), 2u) << fmt::format("{}", fmt::join(lines, "\n"));
    EXPECT_NE(lines.front().find("127.0.0.1:"), std::string::npos) << lines.front();
    EXPECT_NE(lines.front().find("wrong version number"), std::string::npos) << lines.front();
  }
  std::error_code ignored;
  std::filesystem::remove_all(dir, ignored);
}

}  // namespace
}  // namespace icars::planet
