// The fault-injecting TCP proxy of the tests (testing/fault_proxy.h): each fault does what it
// says to plain sockets, and a PLANET client behind it notices every fault that breaks the
// link (disconnected, or a heartbeat timeout for a silent peer) and reconnects by itself once
// the fault is lifted. Every wait is bounded.
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <arpa/inet.h>
#include <asio/use_future.hpp>
#include <algorithm>
#include <cerrno>
#include <future>
#include <iostream>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "child_process.h"
#include "fault_proxy.h"
#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "test_interfaces.h"

namespace {

using namespace std::chrono_literals;
using planet_test::Direction;
using planet_test::FaultProxy;
using Clock = std::chrono::steady_clock;

// --- Plain sockets with bounded waits --------------------------------------------------------

class Fd {
 public:
  explicit Fd(int fd = -1) : fd_(fd) {}
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  Fd(Fd&& o) noexcept : fd_(o.fd_) { o.fd_ = -1; }
  Fd& operator=(Fd&& o) noexcept {
    std::swap(fd_, o.fd_);
    return *this;
  }
  int get() const { return fd_; }
  bool valid() const { return fd_ >= 0; }

 private:
  int fd_;
};

sockaddr_in loopback(std::uint16_t port) {
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(port);
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  return a;
}

// A listening socket on 127.0.0.1: the proxy's target.
class Listener {
 public:
  Listener() : fd_(::socket(AF_INET, SOCK_STREAM, 0)) {
    auto a = loopback(0);
    if (::bind(fd_.get(), reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || ::listen(fd_.get(), 16) != 0) {
      throw std::runtime_error("cannot listen");
    }
    socklen_t len = sizeof a;
    ::getsockname(fd_.get(), reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
  }
  std::uint16_t port() const { return port_; }
  // The next connection, or an invalid Fd when none arrives within `timeout`.
  Fd accept(std::chrono::milliseconds timeout = 10s) {
    pollfd p{fd_.get(), POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(timeout.count())) <= 0) return Fd();
    return Fd(::accept(fd_.get(), nullptr, nullptr));
  }

 private:
  Fd fd_;
  std::uint16_t port_ = 0;
};

Fd connect_to(std::uint16_t port) {
  Fd fd(::socket(AF_INET, SOCK_STREAM, 0));
  auto a = loopback(port);
  if (::connect(fd.get(), reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) throw std::runtime_error("connect failed");
  const int one = 1;
  ::setsockopt(fd.get(), IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  return fd;
}

void send_all(const Fd& fd, const std::string& bytes) {
  std::size_t done = 0;
  while (done < bytes.size()) {
    const auto n = ::send(fd.get(), bytes.data() + done, bytes.size() - done, MSG_NOSIGNAL);
    if (n <= 0) throw std::runtime_error("send failed");
    done += static_cast<std::size_t>(n);
  }
}

struct Received {
  std::string bytes;
  bool closed = false;  // EOF or reset seen
  int error = 0;        // errno of a failed read (ECONNRESET for an RST)
};

// Reads until `want` bytes arrived, the peer closed, or `timeout` passed.
Received read_some(const Fd& fd, std::size_t want, std::chrono::milliseconds timeout) {
  Received r;
  const auto deadline = Clock::now() + timeout;
  while (r.bytes.size() < want) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) break;
    pollfd p{fd.get(), POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
    char chunk[4096];
    const auto n = ::recv(fd.get(), chunk, std::min(sizeof chunk, want - r.bytes.size()), 0);
    if (n <= 0) {
      r.closed = true;
      r.error = n < 0 ? errno : 0;
      break;
    }
    r.bytes.append(chunk, static_cast<std::size_t>(n));
  }
  return r;
}

// Waits for the peer to close: true on EOF or reset within `timeout`.
bool sees_close(const Fd& fd, std::chrono::milliseconds timeout, int* error = nullptr) {
  const auto r = read_some(fd, 1u << 20, timeout);
  if (error) *error = r.error;
  return r.closed;
}

struct Pair {
  Fd client;
  Fd server;
};

Pair open_pair(FaultProxy& proxy, Listener& target) {
  Pair p;
  p.client = connect_to(proxy.port());
  p.server = target.accept();
  if (!p.server.valid()) throw std::runtime_error("the proxy did not connect to the target");
  return p;
}

// --- Plain sockets ---------------------------------------------------------------------------

TEST(FaultProxySockets, PassForwardsBothWaysAndCountsBytes) {
  Listener target;
  FaultProxy proxy("127.0.0.1", target.port());
  auto p = open_pair(proxy, target);
  send_all(p.client, "hello");
  EXPECT_EQ(read_some(p.server, 5, 10s).bytes, "hello");
  send_all(p.server, "world!");
  EXPECT_EQ(read_some(p.client, 6, 10s).bytes, "world!");
  EXPECT_EQ(proxy.connections_accepted(), 1u);
  EXPECT_EQ(proxy.open_connections(), 1u);
  // The proxy counts a chunk once its write completed, which may be just after the peer read it.
  EXPECT_TRUE(planet_test::wait_until(
      [&] { return proxy.bytes_forwarded(Direction::both) == 11u; }, 10s));
  EXPECT_EQ(proxy.bytes_forwarded(Direction::client_to_server), 5u);
  EXPECT_EQ(proxy.bytes_forwarded(Direction::server_to_client), 6u);
  // The client's FIN is passed on; the server's answer to it closes the proxied connection.
  p.client = Fd();
  EXPECT_TRUE(sees_close(p.server, 10s));
  p.server = Fd();
  EXPECT_TRUE(planet_test::wait_until([&] { return proxy.open_connections() == 0; }, 10s));
}

TEST(FaultProxySockets, DelayAddsLatencyInOneDirectionAndKeepsOrder) {
  Listener target;
  FaultProxy proxy("127.0.0.1", target.port());
  auto p = open_pair(proxy, target);
  proxy.delay(300ms, Direction::client_to_server);
  EXPECT_EQ(proxy.fault(Direction::client_to_server), planet_test::FaultKind::delay);
  EXPECT_EQ(proxy.fault(Direction::server_to_client), planet_test::FaultKind::pass);
  std::string sent;
  const auto start = Clock::now();
  for (int i = 0; i < 50; ++i) {
    const auto piece = std::to_string(i) + ",";
    send_all(p.client, piece);
    sent += piece;
    std::this_thread::sleep_for(2ms);  // many separate reads, each with its own due time
  }
  const auto first = read_some(p.server, 1, 10s);
  EXPECT_GE(Clock::now() - start, 300ms) << "delayed bytes arrived early";
  EXPECT_EQ(first.bytes + read_some(p.server, sent.size() - first.bytes.size(), 10s).bytes, sent);
  // The other direction is not delayed.
  const auto back = Clock::now();
  send_all(p.server, "pong");
  EXPECT_EQ(read_some(p.client, 4, 10s).bytes, "pong");
  EXPECT_LT(Clock::now() - back, 250ms);
}

TEST(FaultProxySockets, DropDiscardsWhatIsReadWhileItLasts) {
  Listener target;
  FaultProxy proxy("127.0.0.1", target.port());
  auto p = open_pair(proxy, target);
  proxy.drop(Direction::client_to_server);
  send_all(p.client, "lost bytes");
  ASSERT_TRUE(planet_test::wait_until([&] { return proxy.bytes_dropped(Direction::client_to_server) == 10; }, 10s));
  proxy.pass();
  send_all(p.client, "kept");
  const auto r = read_some(p.server, 100, 500ms);
  EXPECT_EQ(r.bytes, "kept");
  EXPECT_FALSE(r.closed);
  EXPECT_TRUE(planet_test::wait_until(
      [&] { return proxy.bytes_forwarded(Direction::client_to_server) == 4u; }, 10s));
}

TEST(FaultProxySockets, TruncateForwardsNBytesThenClosesBothSides) {
  Listener target;
  FaultProxy proxy("127.0.0.1", target.port());
  auto p = open_pair(proxy, target);
  send_all(p.client, "before,");
  EXPECT_EQ(read_some(p.server, 7, 10s).bytes, "before,");
  proxy.truncate(10, Direction::client_to_server);
  send_all(p.client, std::string(100, 'x'));
  const auto r = read_some(p.server, 1000, 10s);
  EXPECT_EQ(r.bytes, std::string(10, 'x'));
  EXPECT_TRUE(r.closed);
  EXPECT_TRUE(sees_close(p.client, 10s));
  EXPECT_TRUE(planet_test::wait_until([&] { return proxy.open_connections() == 0; }, 10s));
  // A connection accepted while the fault lasts gets its own budget.
  auto q = open_pair(proxy, target);
  send_all(q.client, "0123456789abcdef");
  const auto second = read_some(q.server, 1000, 10s);
  EXPECT_EQ(second.bytes, "0123456789");
  EXPECT_TRUE(second.closed);
}

TEST(FaultProxySockets, CutClosesEveryConnectionWithFinOrReset) {
  Listener target;
  FaultProxy proxy("127.0.0.1", target.port());
  auto a = open_pair(proxy, target);
  auto b = open_pair(proxy, target);
  ASSERT_EQ(proxy.open_connections(), 2u);
  proxy.cut();
  EXPECT_EQ(proxy.open_connections(), 0u);
  int error = -1;
  EXPECT_TRUE(sees_close(a.client, 10s, &error));
  EXPECT_EQ(error, 0) << "a FIN is a clean end of stream";
  EXPECT_TRUE(sees_close(a.server, 10s));
  EXPECT_TRUE(sees_close(b.client, 10s));
  EXPECT_TRUE(sees_close(b.server, 10s));
  // New connections work again; a reset is seen as ECONNRESET.
  auto c = open_pair(proxy, target);
  send_all(c.client, "x");
  EXPECT_EQ(read_some(c.server, 1, 10s).bytes, "x");
  proxy.cut(true);
  EXPECT_TRUE(sees_close(c.client, 10s, &error));
  EXPECT_EQ(error, ECONNRESET);
}

TEST(FaultProxySockets, RefuseClosesNewConnectionsBeforeTheTargetSeesThem) {
  Listener target;
  FaultProxy proxy("127.0.0.1", target.port());
  proxy.refuse();
  auto refused = connect_to(proxy.port());
  EXPECT_TRUE(sees_close(refused, 10s));
  EXPECT_FALSE(target.accept(300ms).valid()) << "a refused connection reached the target";
  EXPECT_EQ(proxy.connections_accepted(), 1u);
  proxy.refuse(false);
  auto p = open_pair(proxy, target);
  send_all(p.client, "in");
  EXPECT_EQ(read_some(p.server, 2, 10s).bytes, "in");
}

TEST(FaultProxySockets, BlackholeHoldsEverythingAndKeepsTheSocketsOpen) {
  Listener target;
  FaultProxy proxy("127.0.0.1", target.port());
  auto p = open_pair(proxy, target);
  proxy.blackhole();
  send_all(p.client, "held");
  send_all(p.server, "back");
  const auto quiet_server = read_some(p.server, 4, 400ms);
  const auto quiet_client = read_some(p.client, 4, 100ms);
  EXPECT_TRUE(quiet_server.bytes.empty());
  EXPECT_FALSE(quiet_server.closed);
  EXPECT_TRUE(quiet_client.bytes.empty());
  EXPECT_FALSE(quiet_client.closed);
  EXPECT_EQ(proxy.open_connections(), 1u);
  proxy.pass();  // the silent peer wakes up: what it held goes through, in order
  EXPECT_EQ(read_some(p.server, 4, 10s).bytes, "held");
  EXPECT_EQ(read_some(p.client, 4, 10s).bytes, "back");
}

TEST(FaultProxySockets, DestructorClosesEverything) {
  Listener target;
  Pair p;
  {
    FaultProxy proxy("127.0.0.1", target.port());
    p = open_pair(proxy, target);
    proxy.delay(10s);
    send_all(p.client, "never");
  }
  EXPECT_TRUE(sees_close(p.client, 10s));
  EXPECT_TRUE(sees_close(p.server, 10s));
}

// --- A PLANET Communicator pair through the proxy ---------------------------------------------

namespace p = icars::planet;
using planet_test::Echo;

struct EventLog {
  std::mutex mutex;
  std::vector<p::LinkEventKind> kinds;
  std::vector<std::string> reasons;
  void record(const p::ConnectionEvent& e) {
    std::lock_guard lock(mutex);
    kinds.push_back(e.kind);
    reasons.push_back(e.reason);
  }
  std::size_t disconnects() {
    std::lock_guard lock(mutex);
    return static_cast<std::size_t>(std::count(kinds.begin(), kinds.end(), p::LinkEventKind::disconnected));
  }
  std::string all_reasons() {
    std::lock_guard lock(mutex);
    std::string out;
    for (const auto& r : reasons) out += r + "; ";
    return out;
  }
};

p::CommunicatorOptions fast_heartbeats(const char* name) {
  p::CommunicatorOptions o;
  o.name = name;
  o.connection.heartbeat_interval = 100ms;
  o.connection.heartbeat_timeout = 800ms;
  o.connection.handshake_timeout = 1000ms;
  o.call_timeout = 20s;
  return o;
}

class FaultProxyPlanet : public ::testing::Test {
 protected:
  void SetUp() override {
    server_.adapter().add("/echo", planet_test::make_echo_servant(server_));
    proxy_ = std::make_unique<FaultProxy>("127.0.0.1", server_.listen("127.0.0.1", 0));
    client_.connections().add_listener([this](const p::ConnectionEvent& e) { events_.record(e); });
    p::ReconnectPolicy policy;
    policy.initial_delay = 10ms;
    policy.max_delay = 200ms;
    policy.connect_timeout = 1000ms;
    peer_ = client_.connect("127.0.0.1", proxy_->port(), policy);
    ASSERT_TRUE(peer_->wait_connected(20s)) << peer_->last_error();
  }
  void TearDown() override { peer_->stop(); }

  p::Proxy echo() { return p::Proxy(client_, peer_, "/echo"); }

  // The client noticed the broken link, then (once the proxy passes again) reconnected by
  // itself, and calls work again.
  void expect_disconnect_then_recovery(std::uint64_t connects_before) {
    ASSERT_TRUE(planet_test::wait_until([&] { return events_.disconnects() >= 1; }, 20s))
        << "the client did not notice the fault";
    proxy_->pass();
    ASSERT_TRUE(planet_test::wait_until(
        [&] { return peer_->is_connected() && peer_->connect_count() > connects_before; }, 20s))
        << peer_->last_error();
    EXPECT_EQ(echo().call(Echo::echo_string, std::string("again")), "again");
  }

  EventLog events_;  // outlives the client: its io thread reports the last disconnect
  p::Communicator server_{fast_heartbeats("server")};
  std::unique_ptr<FaultProxy> proxy_;
  p::Communicator client_{fast_heartbeats("client")};
  std::shared_ptr<p::Peer> peer_;
};

TEST_F(FaultProxyPlanet, CallsThroughPassWork) {
  EXPECT_EQ(echo().call(Echo::echo_int, 42), 42);
  EXPECT_EQ(proxy_->connections_accepted(), 1u);
  EXPECT_GT(proxy_->bytes_forwarded(Direction::client_to_server), 0u);
  EXPECT_GT(proxy_->bytes_forwarded(Direction::server_to_client), 0u);
}

TEST_F(FaultProxyPlanet, DelayAddsLatencyButCallsSucceed) {
  const auto quick_start = Clock::now();
  EXPECT_EQ(echo().call(Echo::echo_int, 1), 1);
  const auto quick = Clock::now() - quick_start;
  proxy_->delay(150ms);
  const auto start = Clock::now();
  EXPECT_EQ(echo().call(Echo::echo_string, std::string("slow")), "slow");
  EXPECT_GE(Clock::now() - start, 300ms) << "one delay each way";
  EXPECT_LT(quick, 300ms);
  proxy_->pass();
  EXPECT_EQ(echo().call(Echo::echo_int, 2), 2);
  EXPECT_EQ(peer_->connect_count(), 1u) << "a delay shorter than the heartbeat timeout keeps the link";
  EXPECT_EQ(events_.disconnects(), 0u);
}

TEST_F(FaultProxyPlanet, CutFailsTheCallInFlightAndTheClientReconnects) {
  // The reply is held back (less than the heartbeat timeout), so the call is still in flight
  // when the link is cut.
  proxy_->delay(500ms, Direction::server_to_client);
  auto in_flight = echo().async_call(Echo::echo_int, {7}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until([&] { return client_.pending_calls() == 1; }, 10s));
  proxy_->cut(true);
  ASSERT_EQ(in_flight.wait_for(10s), std::future_status::ready);
  try {
    in_flight.get();
    FAIL() << "the call in flight must fail";
  } catch (const p::Error& e) {
    EXPECT_EQ(e.kind(), p::ErrorKind::disconnected) << e.what();
  }
  expect_disconnect_then_recovery(1);
}

TEST_F(FaultProxyPlanet, TruncatedRequestClosesTheLinkAndTheClientReconnects) {
  proxy_->truncate(100, Direction::client_to_server);
  p::Binary big;
  big.bytes.resize(64 * 1024, std::byte{0x5a});
  auto call = echo().async_call(Echo::echo_binary, {big}, asio::use_future);
  ASSERT_EQ(call.wait_for(20s), std::future_status::ready);
  try {
    call.get();
    FAIL() << "a request cut short cannot be answered";
  } catch (const p::Error& e) {
    EXPECT_EQ(e.kind(), p::ErrorKind::disconnected) << e.what();
  }
  expect_disconnect_then_recovery(1);
  EXPECT_EQ(echo().call(Echo::echo_binary, big), big);
}

TEST_F(FaultProxyPlanet, DroppedBytesAreNoticedAndTheClientReconnects) {
  // Everything the client sends is lost: the server hears nothing and times the link out, or
  // reads the bytes after the gap as a broken frame; either way the client learns of it.
  proxy_->drop(Direction::client_to_server);
  auto call = echo().async_call(Echo::echo_int, {3}, asio::use_future);
  ASSERT_EQ(call.wait_for(20s), std::future_status::ready);
  EXPECT_THROW(call.get(), p::Error);
  EXPECT_GT(proxy_->bytes_dropped(Direction::client_to_server), 0u);
  expect_disconnect_then_recovery(1);
}

TEST_F(FaultProxyPlanet, BytesDroppedMidMessageCorruptTheStreamAndTheLinkRecovers) {
  // A gap in the middle of a large message: the receiver finds the next frame header inside
  // a payload (bad data) or never gets the rest; the link is closed either way.
  p::Binary big;
  big.bytes.resize(4u << 20, std::byte{0x11});
  auto call = echo().with_timeout(30s).async_call(Echo::echo_binary, {big}, asio::use_future);
  ASSERT_TRUE(planet_test::wait_until(
      [&] { return proxy_->bytes_forwarded(Direction::client_to_server) > (256u << 10); }, 20s));
  proxy_->drop(Direction::client_to_server);
  ASSERT_TRUE(planet_test::wait_until([&] { return proxy_->bytes_dropped(Direction::client_to_server) > 0; }, 20s));
  proxy_->pass();
  // When the hole leaves the receiver without a whole frame to acknowledge, only the 30 s
  // timeouts (the call's, the message's progress) end it: wait well beyond them.
  ASSERT_EQ(call.wait_for(90s), std::future_status::ready);
  p::ErrorKind kind{};
  try {
    call.get();
    FAIL() << "a message with a hole cannot be answered";
  } catch (const p::Error& e) {
    kind = e.kind();
    EXPECT_TRUE(kind == p::ErrorKind::disconnected || kind == p::ErrorKind::bad_data ||
                kind == p::ErrorKind::timeout)
        << e.what();
  }
  std::cout << "link events: " << events_.all_reasons() << "\n";
  if (kind == p::ErrorKind::timeout) {
    // The drop swallowed whole frames up to the end of the message's flow-control window: no
    // frame header is broken, the receiver waits for frames that never come and so never grants
    // more. The call's deadline reports the failure, and the link carries calls again: at once,
    // or, when the message's own 30 s progress deadline closes the link at the same moment as
    // the call's, once the peer has reconnected.
    int answer = 0;
    EXPECT_TRUE(planet_test::wait_until([&] {
      try {
        answer = echo().call(Echo::echo_int, 4);
        return true;
      } catch (const p::Error& e) {
        return e.kind() != p::ErrorKind::disconnected && e.kind() != p::ErrorKind::timeout;  // another error: give up
      }
    }, 30s));
    EXPECT_EQ(answer, 4);
    return;
  }
  expect_disconnect_then_recovery(1);
}

TEST_F(FaultProxyPlanet, BlackholeIsDetectedByTheHeartbeatTimeout) {
  EXPECT_EQ(echo().call(Echo::echo_int, 1), 1);
  proxy_->blackhole();
  auto stuck = echo().async_call(Echo::echo_int, {2}, asio::use_future);
  const auto start = Clock::now();
  ASSERT_TRUE(planet_test::wait_until([&] { return !peer_->is_connected(); }, 20s));
  const auto detected_after = Clock::now() - start;
  // The peer marks itself down before it tells its listeners.
  ASSERT_TRUE(planet_test::wait_until([&] { return events_.disconnects() >= 1; }, 20s));
  EXPECT_NE(events_.all_reasons().find("heartbeat timeout"), std::string::npos) << events_.all_reasons();
  EXPECT_LT(detected_after, 5s);
  // The call waiting on the silent peer fails long before its 20 s deadline.
  ASSERT_EQ(stuck.wait_for(10s), std::future_status::ready);
  try {
    stuck.get();
    FAIL() << "the call to the silent peer must fail";
  } catch (const p::Error& e) {
    EXPECT_EQ(e.kind(), p::ErrorKind::disconnected) << e.what();
  }
  EXPECT_GE(proxy_->open_connections(), 1u) << "the proxy keeps a silent peer's sockets open";
  expect_disconnect_then_recovery(1);
}

TEST_F(FaultProxyPlanet, RefusedReconnectionsAreRetriedUntilTheProxyAccepts) {
  proxy_->refuse();
  proxy_->cut();
  ASSERT_TRUE(planet_test::wait_until([&] { return events_.disconnects() >= 1; }, 20s));
  const auto accepted = proxy_->connections_accepted();
  ASSERT_TRUE(planet_test::wait_until([&] { return proxy_->connections_accepted() >= accepted + 2; }, 20s))
      << "the client did not keep trying";
  EXPECT_FALSE(peer_->is_connected());
  proxy_->refuse(false);
  expect_disconnect_then_recovery(1);
}

}  // namespace
