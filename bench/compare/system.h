// The contract every compared system implements (raw TCP, PLANET, gRPC, ZeroC Ice), so that
// icars-compare runs the same workloads over each of them, client and server in separate
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
#include <functional>
#include <memory>
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
  // "raw-tcp", "planet", "grpc" or "ice".
  virtual std::string name() const = 0;
  // Listens on 127.0.0.1:port, calls ready() once connections are accepted, then serves until
  // the process is killed (never returns normally).
  virtual void serve(std::uint16_t port, const std::function<void()>& ready) = 0;
  virtual std::unique_ptr<Client> connect(const std::string& host, std::uint16_t port) = 0;
  // Returns once all `count` subscriptions are established at the server.
  virtual std::unique_ptr<Subscribers> subscribe(const std::string& host, std::uint16_t port,
                                                 int count) = 0;
};

// The systems built into this binary (raw TCP and PLANET always; gRPC and Ice when found).
std::unique_ptr<System> make_raw_tcp();
std::unique_ptr<System> make_planet();
#ifdef ICARS_BENCH_WITH_GRPC
std::unique_ptr<System> make_grpc();
#endif
#ifdef ICARS_BENCH_WITH_ICE
std::unique_ptr<System> make_ice();
#endif

}  // namespace icars::bench
