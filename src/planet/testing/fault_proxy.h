// Test support: a TCP proxy that injects network faults between two endpoints.
//
// A FaultProxy listens on 127.0.0.1 (a free port) and forwards every connection it accepts to
// one target host:port, byte for byte, on its own io thread. From the test's thread, at any
// time, each direction (client→server, server→client) can be given a fault that applies to
// the connections open now and to those accepted later, until another fault replaces it:
//
//   pass         forward everything (the default)
//   drop         discard the bytes read while it lasts: the receiver sees a corrupted stream
//   delay(ms)    forward every byte `ms` after it was read, in order
//   truncate(n)  forward n more bytes on each connection, then close both of its sides
//   blackhole    read and forward nothing, keep the sockets open: a silent, frozen peer
//
// and for the whole proxy: cut() closes every open connection now (both sides, FIN or RST);
// refuse(true) closes new connections as soon as they are accepted. Counters tell what went
// through. Every method is thread-safe; the destructor closes everything and joins the thread.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

namespace planet_test {

enum class Direction : std::uint8_t {
  client_to_server,  // what the connecting side sends
  server_to_client,  // what the target answers
  both,
};

enum class FaultKind : std::uint8_t { pass, drop, delay, truncate, blackhole };

namespace detail {
struct FaultProxyState;
}

class FaultProxy {
 public:
  // Starts listening at once; throws std::system_error when it cannot.
  FaultProxy(const std::string& target_host, std::uint16_t target_port);
  ~FaultProxy();
  FaultProxy(const FaultProxy&) = delete;
  FaultProxy& operator=(const FaultProxy&) = delete;

  std::uint16_t port() const { return port_; }  // where clients connect (127.0.0.1)

  void pass(Direction d = Direction::both);
  void drop(Direction d = Direction::both);
  void delay(std::chrono::milliseconds by, Direction d = Direction::both);
  // Each connection open now (counted from this call) or accepted later forwards `bytes` more
  // bytes in direction `d`, then both of its sides are closed.
  void truncate(std::size_t bytes, Direction d = Direction::both);
  void blackhole(Direction d = Direction::both);
  // Closes every open connection, both sides; `reset` sends RST instead of FIN.
  void cut(bool reset = false);
  // While on, new connections are accepted and closed at once (the target never sees them).
  void refuse(bool on = true);

  FaultKind fault(Direction d) const;  // of one direction (client_to_server for `both`)

  std::uint64_t connections_accepted() const;
  std::size_t open_connections() const;
  // Bytes written to the other side; for `both`, the sum.
  std::uint64_t bytes_forwarded(Direction d) const;
  std::uint64_t bytes_dropped(Direction d) const;  // read while `drop` was on

 private:
  std::shared_ptr<detail::FaultProxyState> state_;
  std::uint16_t port_ = 0;
};

}  // namespace planet_test
