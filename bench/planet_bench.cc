// PLANET benchmarks: serializer throughput, and PLANET calls over loopback next to raw TCP
// doing the same exchange, so the middleware's overhead is a ratio taken from one run.
//
// Every network benchmark runs its server in this process (the raw TCP echo server on its own
// threads, the PLANET server in its own Communicator with its own io thread) and measures wall
// time (UseRealTime), so the raw and PLANET numbers are directly comparable. bench/README.md
// says what each benchmark measures; bench/run.sh runs them with repetitions and prints the
// PLANET-call / raw-TCP ratio.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>
#include <unistd.h>

#include <benchmark/benchmark.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <exception>
#include <memory>
#include <mutex>
#include <semaphore>
#include <stdexcept>
#include <string>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

#include "bench_util.h"
#include "icars/planet/communicator.h"
#include "icars/planet/event.h"
#include "icars/planet/proxy.h"
#include "icars/planet/stream.h"
#include "icars/planet/serializer.h"
#include "test_interfaces.h"

namespace {

namespace p = icars::planet;
using planet_test::Echo;

constexpr std::size_t kPingSize = 64;           // raw TCP ping-pong message
constexpr std::size_t kBulkSize = 1u << 20;     // 1 MiB transfers
constexpr int kInFlight = 32;                   // outstanding async calls
constexpr std::int64_t kNotifyBatch = 1000;     // NOTIFYs per iteration, then one `counted`

using icars::bench::read_exact;
using icars::bench::throw_errno;
using icars::bench::write_all;

// --- Raw TCP: blocking POSIX sockets --------------------------------------------------------

bool set_nodelay(int fd) {
  const int one = 1;
  return ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one) == 0;
}

sockaddr_in loopback(std::uint16_t port) {
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  if (::inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr) != 1) throw_errno("inet_pton");
  return addr;
}

// The first byte a client sends picks what the server does with the connection.
enum class RawMode : char {
  ping = 'p',  // echo kPingSize-byte messages
  bulk = 'b',  // read a u64 length and that many bytes, reply with the u64 length
};

// A blocking echo server: one thread accepts, one thread serves each connection.
class RawServer {
 public:
  RawServer() {
    listen_fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    if (listen_fd_ < 0) throw_errno("socket");
    const int one = 1;
    ::setsockopt(listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in addr = loopback(0);
    if (::bind(listen_fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
      throw_errno("bind");
    }
    if (::listen(listen_fd_, 16) != 0) throw_errno("listen");
    socklen_t len = sizeof addr;
    if (::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0) {
      throw_errno("getsockname");
    }
    port_ = ntohs(addr.sin_port);
    acceptor_ = std::thread([this] { accept_loop(); });
  }

  ~RawServer() {
    stopping_ = true;
    ::shutdown(listen_fd_, SHUT_RDWR);  // wakes the blocked accept()
    acceptor_.join();
    ::close(listen_fd_);
    std::vector<std::thread> workers;
    {
      std::lock_guard lock(mutex_);
      for (int fd : fds_) ::shutdown(fd, SHUT_RDWR);
      workers.swap(workers_);
    }
    for (auto& t : workers) t.join();
  }

  RawServer(const RawServer&) = delete;
  RawServer& operator=(const RawServer&) = delete;

  std::uint16_t port() const { return port_; }

 private:
  void accept_loop() {
    while (!stopping_) {
      const int fd = ::accept(listen_fd_, nullptr, nullptr);
      if (fd < 0) {
        if (errno == EINTR || errno == ECONNABORTED) continue;
        return;  // shut down
      }
      if (!set_nodelay(fd)) {
        ::close(fd);  // the client sees the connection drop and reports the failure
        continue;
      }
      std::lock_guard lock(mutex_);
      fds_.push_back(fd);
      workers_.emplace_back([this, fd] { serve(fd); });
    }
  }

  void serve(int fd) {
    char mode = 0;
    if (read_exact(fd, &mode, 1)) {
      if (mode == static_cast<char>(RawMode::ping)) {
        std::array<std::byte, kPingSize> msg{};
        while (read_exact(fd, msg.data(), msg.size()) && write_all(fd, msg.data(), msg.size())) {
        }
      } else if (mode == static_cast<char>(RawMode::bulk)) {
        std::vector<std::byte> body;
        std::uint64_t size = 0;
        while (read_exact(fd, &size, sizeof size)) {
          body.resize(static_cast<std::size_t>(size));
          if (!read_exact(fd, body.data(), body.size())) break;
          benchmark::DoNotOptimize(body.data());
          if (!write_all(fd, &size, sizeof size)) break;
        }
      }
    }
    // Closed under the lock so ~RawServer never shuts down a reused descriptor number.
    std::lock_guard lock(mutex_);
    std::erase(fds_, fd);
    ::close(fd);
  }

  int listen_fd_ = -1;
  std::uint16_t port_ = 0;
  std::atomic<bool> stopping_{false};
  std::thread acceptor_;
  std::mutex mutex_;
  std::vector<int> fds_;
  std::vector<std::thread> workers_;
};

// A client connection to the RawServer, in the given mode.
class RawClient {
 public:
  RawClient(std::uint16_t port, RawMode mode) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    if (fd_ < 0) throw_errno("socket");
    const sockaddr_in addr = loopback(port);
    if (::connect(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
      const int saved = errno;
      ::close(fd_);
      errno = saved;
      throw_errno("connect");
    }
    if (!set_nodelay(fd_)) {
      const int saved = errno;
      ::close(fd_);
      errno = saved;
      throw_errno("setsockopt(TCP_NODELAY)");
    }
    const char m = static_cast<char>(mode);
    if (!write_all(fd_, &m, 1)) throw_errno("send mode");
  }
  ~RawClient() { ::close(fd_); }
  RawClient(const RawClient&) = delete;
  RawClient& operator=(const RawClient&) = delete;
  int fd() const { return fd_; }

 private:
  int fd_ = -1;
};

// --- Shared fixtures (created on first use, destroyed before main returns) -------------------

std::shared_ptr<spdlog::logger> quiet_logger(const std::string& name) {
  auto log = std::make_shared<spdlog::logger>(
      name, std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  log->set_level(spdlog::level::warn);
  return log;
}

p::CommunicatorOptions quiet_options(const std::string& name) {
  p::CommunicatorOptions options;
  options.name = name;
  options.logger = quiet_logger(name);
  return options;
}

// A server Communicator with the Echo servant at "/echo" and a client Communicator connected
// to it, both on loopback in this process (each runs its own io thread).
struct PlanetPair {
  p::Communicator server{quiet_options("bench-server")};
  p::Communicator client{quiet_options("bench-client")};
  std::shared_ptr<p::Peer> peer;

  PlanetPair() {
    server.adapter().add("/echo", planet_test::make_echo_servant(server));
    server.adapter().add("/streams", planet_test::make_streams_servant(server));
    const std::uint16_t port = server.listen("127.0.0.1", 0);
    peer = client.connect("127.0.0.1", port);
    if (!peer->wait_connected(std::chrono::seconds(5))) {
      throw std::runtime_error("PLANET client did not connect: " + peer->last_error());
    }
  }
};

std::unique_ptr<RawServer> g_raw;
std::unique_ptr<PlanetPair> g_planet;

RawServer& raw_server() {
  if (!g_raw) g_raw = std::make_unique<RawServer>();
  return *g_raw;
}

PlanetPair& planet_pair() {
  if (!g_planet) g_planet = std::make_unique<PlanetPair>();
  return *g_planet;
}

p::Proxy echo_proxy() {
  PlanetPair& pair = planet_pair();
  return p::Proxy(pair.client, pair.peer, "/echo");
}

void skip_with(benchmark::State& state, const std::string& why) {
  state.SkipWithError(why.c_str());
}

// --- 1. Serialization -----------------------------------------------------------------------

planet_test::Reading make_reading() {
  planet_test::Reading r;
  r.sensor = "lidar-front";
  r.color = planet_test::Color::green;
  r.stamp = 1'700'000'000'000;
  for (int i = 0; i < 16; ++i) {
    const double d = static_cast<double>(i);
    r.path.push_back({d * 0.5, d * -0.25, d * 0.1});
  }
  return r;
}

std::vector<double> make_doubles() {
  std::vector<double> v(1024);
  for (std::size_t i = 0; i < v.size(); ++i) v[i] = static_cast<double>(i) * 1.5;
  return v;
}

p::Event make_event() {
  p::Event e("SoundEvent");
  e.set("direction", 1.25)
      .set("volume", std::int32_t{72})
      .set("source", std::string("kitchen"))
      .set("stamp", std::int64_t{1'700'000'000'000});
  return e;
}

// One iteration = encode_tagged into a reused buffer + decode_tagged of the result. Bytes/s
// counts the encoded (tagged) size once per iteration.
template <class T>
void BM_Serialize(benchmark::State& state, T value) {
  std::vector<std::byte> buffer;
  {
    p::Writer w(buffer);
    p::encode_tagged(w, value);
    p::Reader r(buffer);
    if (p::decode_tagged<T>(r) != value || r.remaining() != 0) {
      state.SkipWithError("round trip changed the value");
      return;
    }
  }
  const std::size_t encoded = buffer.size();
  for (auto _ : state) {
    buffer.clear();
    p::Writer w(buffer);
    p::encode_tagged(w, value);
    p::Reader r(buffer);
    T out = p::decode_tagged<T>(r);
    benchmark::DoNotOptimize(out);
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(state.iterations() * static_cast<std::int64_t>(encoded));
  state.counters["encoded_bytes"] = static_cast<double>(encoded);
}
BENCHMARK_CAPTURE(BM_Serialize, int32, std::int32_t{42});
BENCHMARK_CAPTURE(BM_Serialize, string32, std::string(32, 'x'));
BENCHMARK_CAPTURE(BM_Serialize, reading16, make_reading());
BENCHMARK_CAPTURE(BM_Serialize, doubles1024, make_doubles());
BENCHMARK_CAPTURE(BM_Serialize, event4, make_event());

// --- 2. Raw TCP ping-pong -------------------------------------------------------------------

// One iteration = write 64 bytes, read the 64-byte echo.
void BM_RawTcp_PingPong64(benchmark::State& state) {
  try {
    RawClient client(raw_server().port(), RawMode::ping);
    std::array<std::byte, kPingSize> out{};
    std::array<std::byte, kPingSize> in{};
    out.fill(std::byte{0x2A});
    for (auto _ : state) {
      if (!write_all(client.fd(), out.data(), out.size()) ||
          !read_exact(client.fd(), in.data(), in.size())) {
        state.SkipWithError("raw TCP ping-pong failed");
        break;
      }
      benchmark::DoNotOptimize(in.data());
    }
  } catch (const std::exception& e) {
    skip_with(state, e.what());
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_RawTcp_PingPong64)->UseRealTime();

// --- 3. PLANET synchronous call -------------------------------------------------------------

// One iteration = Proxy::call(Echo::echo_int, 42), blocking for the reply.
void BM_Planet_SyncCall(benchmark::State& state) {
  try {
    const p::Proxy echo = echo_proxy();
    for (auto _ : state) {
      const std::int32_t v = echo.call(Echo::echo_int, 42);
      if (v != 42) {
        state.SkipWithError("echo_int returned a different value");
        break;
      }
      benchmark::DoNotOptimize(v);
    }
  } catch (const std::exception& e) {
    skip_with(state, e.what());
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_Planet_SyncCall)->UseRealTime();

// --- 4. PLANET asynchronous call throughput -------------------------------------------------

// Keeps kInFlight echo_int calls outstanding; one iteration = issuing one call once a slot is
// free, so time/iteration is the inverse of the call throughput. The completions run on the
// client's io thread and only release a slot.
void BM_Planet_AsyncCalls(benchmark::State& state) {
  // Outlive every completion: all slots are reacquired below before these go away.
  std::counting_semaphore<kInFlight> slots(kInFlight);
  std::atomic<std::int64_t> failures{0};
  try {
    const p::Proxy echo = echo_proxy();
    for (auto _ : state) {
      slots.acquire();
      try {
        echo.async_call(Echo::echo_int, {42},
                        [&slots, &failures](std::exception_ptr e, std::int32_t v) {
                          if (e || v != 42) failures.fetch_add(1, std::memory_order_relaxed);
                          slots.release();
                        });
      } catch (...) {
        slots.release();  // this call was never started
        throw;
      }
    }
  } catch (const std::exception& e) {
    skip_with(state, e.what());
  }
  for (int i = 0; i < kInFlight; ++i) slots.acquire();  // wait for the last calls
  if (failures.load() != 0 && !state.error_occurred()) {
    skip_with(state, std::to_string(failures.load()) + " async calls failed");
  }
  state.SetItemsProcessed(state.iterations());
  state.counters["in_flight"] = kInFlight;
}
BENCHMARK(BM_Planet_AsyncCalls)->UseRealTime();

// --- 5. PLANET one-way NOTIFY throughput ----------------------------------------------------

// One iteration = kNotifyBatch NOTIFYs of Echo::count, then a synchronous `counted` call that
// proves every one of them was delivered (NOTIFY and CALL share the connection, in order).
void BM_Planet_Notify(benchmark::State& state) {
  std::int64_t overloaded = 0;
  try {
    const p::Proxy echo = echo_proxy();
    std::int64_t expected = echo.call(Echo::counted);
    for (auto _ : state) {
      for (std::int64_t i = 0; i < kNotifyBatch; ++i) {
        for (;;) {
          try {
            echo.notify(Echo::count, 1);
            break;
          } catch (const p::Error& e) {
            if (e.kind() != p::ErrorKind::overloaded) throw;
            ++overloaded;  // send queue full: let the io thread drain it
            std::this_thread::yield();
          }
        }
      }
      expected += kNotifyBatch;
      const std::int64_t got = echo.call(Echo::counted);
      if (got != expected) {
        skip_with(state, "NOTIFYs lost: counted " + std::to_string(got) + ", expected " +
                             std::to_string(expected));
        break;
      }
    }
  } catch (const std::exception& e) {
    skip_with(state, e.what());
  }
  state.SetItemsProcessed(state.iterations() * kNotifyBatch);
  state.counters["overloaded_retries"] = static_cast<double>(overloaded);
}
BENCHMARK(BM_Planet_Notify)->UseRealTime();

// --- 6. 1 MiB transfers ---------------------------------------------------------------------

// One iteration = write a u64 length + 1 MiB, read the u64 reply.
void BM_RawTcp_Bulk1MiB(benchmark::State& state) {
  try {
    RawClient client(raw_server().port(), RawMode::bulk);
    const std::vector<std::byte> body(kBulkSize, std::byte{0x5A});
    const std::uint64_t size = body.size();
    for (auto _ : state) {
      std::uint64_t reply = 0;
      if (!write_all(client.fd(), &size, sizeof size) ||
          !write_all(client.fd(), body.data(), body.size()) ||
          !read_exact(client.fd(), &reply, sizeof reply) || reply != size) {
        state.SkipWithError("raw TCP 1 MiB transfer failed");
        break;
      }
    }
  } catch (const std::exception& e) {
    skip_with(state, e.what());
  }
  state.SetBytesProcessed(state.iterations() * static_cast<std::int64_t>(kBulkSize));
}
BENCHMARK(BM_RawTcp_Bulk1MiB)->UseRealTime();

// One iteration = Proxy::call(Echo::size_of, 1 MiB Binary), which answers the size.
void BM_Planet_Binary1MiB(benchmark::State& state) {
  try {
    const p::Proxy echo = echo_proxy();
    p::Binary blob;
    blob.bytes.assign(kBulkSize, std::byte{0x5A});
    for (auto _ : state) {
      const std::int64_t n = echo.call(Echo::size_of, blob);
      if (n != static_cast<std::int64_t>(kBulkSize)) {
        state.SkipWithError("size_of returned the wrong size");
        break;
      }
    }
  } catch (const std::exception& e) {
    skip_with(state, e.what());
  }
  state.SetBytesProcessed(state.iterations() * static_cast<std::int64_t>(kBulkSize));
}
BENCHMARK(BM_Planet_Binary1MiB)->UseRealTime();

// One iteration = read 1 MiB from an endless stream the server writes (pulled with the default
// 1 MiB window, in one-frame DATA chunks).
void BM_Planet_Stream1MiB(benchmark::State& state) {
  try {
    PlanetPair& pair = planet_pair();
    const p::Proxy streams(pair.client, pair.peer, "/streams");
    auto in = p::InputStream::open(pair.client, pair.peer,
                                   streams.call(planet_test::Streams::produce,
                                                std::int64_t{1} << 50, 1 << 20));
    for (auto _ : state) {
      std::size_t got = 0;
      while (got < kBulkSize) {
        auto chunk = in->read();
        if (chunk.empty()) throw std::runtime_error("the endless stream ended");
        got += chunk.size();
      }
    }
    in->cancel("benchmark done");
  } catch (const std::exception& e) {
    skip_with(state, e.what());
  }
  state.SetBytesProcessed(state.iterations() * static_cast<std::int64_t>(kBulkSize));
}
BENCHMARK(BM_Planet_Stream1MiB)->UseRealTime();

}  // namespace

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  g_planet.reset();  // closes the PLANET connections and joins both io threads
  g_raw.reset();     // the raw clients are gone, so every server thread has returned
  return 0;
}
