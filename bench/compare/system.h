// The contract every compared system implements (raw TCP, PLANET, gRPC, ZeroC Ice, Cap'n Proto),
// so that icars-compare runs the same workloads over each of them, client and server in separate
// processes on loopback. Each system implements it in its own idiom (its IDL, its async API,
// its event mechanism); what is measured is what a user of that system would write.
//
// The server side of every system offers:
//   echo_int(i32) -> i32            a small synchronous call
//   size_of(bytes) -> u64           a large upload (the server answers the byte count)
//   echo_bytes(bytes) -> bytes      a large echo (the server answers the same bytes)
//   subscribe                       a subscriber connection receives every published event
//   publish(count, payload_size)    the server sends `count` events of `payload_size` bytes to
//                                   every subscriber, and answers once it has queued them
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace icars::bench {

using Bytes = std::vector<std::byte>;

// One connection to a server. call, upload and echo may be used from several threads at once on
// the same Client (the head-of-line workload issues small calls while an echo is in progress);
// they throw std::exception on failure.
class Client {
 public:
  virtual ~Client() = default;
  virtual std::int32_t call(std::int32_t x) = 0;
  virtual std::uint64_t upload(const Bytes& data) = 0;
  virtual Bytes echo(const Bytes& data) = 0;
  // `count` echo_int calls issued asynchronously on this connection with at most `window`
  // unanswered at any time; returns when every call is answered (and checks every answer).
  virtual void pipeline(std::int64_t count, int window) = 0;
  // One echo_int attempt that gives up within about a second; true when it was answered. Used
  // after the server restarts: the client keeps calling through the system's own reconnection.
  virtual bool try_call() noexcept = 0;
  // Called before a timed transfer of `data`: a system whose applications hold their data in
  // its own type (PLANET's Binary) converts it here, so the transfer alone is timed, as it is
  // for the systems that send a caller's buffer as it is.
  virtual void prepare(const Bytes& data) { (void)data; }
};

// `count` subscriber connections to one server, each counting the events it receives.
class Subscribers {
 public:
  virtual ~Subscribers() = default;
  // Asks the server (over one more connection) to publish `events` events of `payload` bytes and
  // returns when every subscriber has received all of them; throws when `timeout` passes first.
  virtual void publish_and_wait(int events, std::size_t payload,
                                std::chrono::milliseconds timeout) = 0;
};

class System {
 public:
  virtual ~System() = default;
  // "raw-tcp", "planet", "grpc", "ice" or "capnp"; a TLS variant's ends in "-tls".
  virtual std::string name() const = 0;
  // Listens on 127.0.0.1:port, calls ready() once connections are accepted, then serves until
  // the process is killed (never returns normally).
  virtual void serve(std::uint16_t port, const std::function<void()>& ready) = 0;
  virtual std::unique_ptr<Client> connect(const std::string& host, std::uint16_t port) = 0;
  // Returns once all `count` subscriptions are established at the server.
  virtual std::unique_ptr<Subscribers> subscribe(const std::string& host, std::uint16_t port,
                                                 int count) = 0;
};

// The certificates of a TLS variant ("planet-tls", "grpc-tls", "ice-tls"), as
// scripts/make-certs.sh writes them into one directory. Every variant is secured as a default
// ICARS home is (docs/security.md): the server presents server.pem, the client checks it against
// ca.pem and the host it connected to (127.0.0.1, a name server.pem carries); clients present no
// certificate.
struct TlsFiles {
  std::filesystem::path dir;
  std::string ca() const { return (dir / "ca.pem").string(); }
  std::string certificate() const { return (dir / "server.pem").string(); }
  std::string private_key() const { return (dir / "server.key").string(); }
};

// The systems built into this binary (raw TCP and PLANET always; gRPC, Ice and Cap'n Proto when
// found); with `tls`, the system's TLS variant (Cap'n Proto has none here).
std::unique_ptr<System> make_raw_tcp();
std::unique_ptr<System> make_planet(std::optional<TlsFiles> tls = std::nullopt);
#ifdef ICARS_BENCH_WITH_GRPC
std::unique_ptr<System> make_grpc(std::optional<TlsFiles> tls = std::nullopt);
#endif
#ifdef ICARS_BENCH_WITH_ICE
std::unique_ptr<System> make_ice(std::optional<TlsFiles> tls = std::nullopt);
#endif
#ifdef ICARS_BENCH_WITH_CAPNP
std::unique_ptr<System> make_capnp();
#endif

}  // namespace icars::bench
