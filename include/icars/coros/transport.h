// COROS communication: the agent server and client over UDP (COROS 4.2, AbstractServer and
// AbstractClient).
//
// An agent owns two sockets on its io_context:
//   - its own unicast socket (ip:port, port 0 picks a free one), which sends everything —
//     unicast replies and broadcasts — and receives the replies addressed to the agent;
//   - a socket bound to the fleet's shared broadcast port (SO_REUSEADDR, so every agent on a
//     host binds it), which receives what agents broadcast (HELLO, auctions, task states).
// A broadcast is one datagram to the fleet's broadcast address (127.255.255.255 on one host,
// the subnet's broadcast address on a network) at the shared port; every agent, the sender
// included, gets it. Receivers learn the sender's unicast endpoint from the datagram's source.
//
// With a fleet key (TransportOptions::key) every datagram sent is signed and every one received
// is verified before delivery (authentication.h): unsigned, badly tagged and replayed datagrams
// are counted by reason and by source address in TransportStats and logged at warn, at most
// once a second per source address, and never reach the receiver. Malformed datagrams are
// counted the same way and handed to the ErrorSink (the agent aggregates them into events). Without a key the transport refuses to exist unless
// `insecure` is set; it then sends unsigned datagrams and accepts any well-formed one.
//
// FaultInjection is the test hook: it drops, duplicates and delays (so reorders) outgoing
// datagrams at random, from a seed, to show the protocols survive a lossy network.
#pragma once

#include <asio/io_context.hpp>
#include <asio/ip/udp.hpp>
#include <asio/steady_timer.hpp>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "icars/coros/authentication.h"
#include "icars/coros/messages.h"

namespace spdlog {
class logger;
}

namespace icars::coros {

struct FaultInjection {
  double drop = 0;       // probability that a datagram is not sent
  double duplicate = 0;  // probability that it is sent twice
  double delay = 0;      // probability that it is held back, so later datagrams overtake it
  int max_delay_ms = 50;
  std::uint64_t seed = 1;
  bool active() const { return drop > 0 || duplicate > 0 || delay > 0; }
  // "drop=0.2,duplicate=0.1,delay=0.3,max_delay_ms=80,seed=7"; throws CorosError.
  static FaultInjection parse(const std::string& spec);
  // The inverse of parse(): every key, each number written so parse() reads it back exactly.
  std::string spec() const;
  friend bool operator==(const FaultInjection&, const FaultInjection&) = default;
};

struct TransportOptions {
  std::string ip = "127.0.0.1";  // address of the unicast socket
  std::uint16_t port = 0;        // 0: any free port
  std::string broadcast_address = "127.255.255.255";
  std::uint16_t broadcast_port = 47800;
  FaultInjection faults;
  std::optional<FleetKey> key;             // the fleet's key: sign and verify every datagram
  bool insecure = false;                   // no key on purpose: nothing is signed or checked
  std::shared_ptr<spdlog::logger> logger;  // warnings; default: a stderr logger "coros"
};

struct TransportStats {
  std::uint64_t sent = 0, received = 0, dropped_by_hook = 0, duplicated_by_hook = 0,
                delayed_by_hook = 0, malformed = 0, send_errors = 0;
  // Dropped before delivery, by reason (Rejection): no trailer, a tag that does not match,
  // a generation and counter seen before or too old.
  std::uint64_t rejected_unsigned = 0, rejected_bad_tag = 0, rejected_replayed = 0;
  std::uint64_t rejected() const {
    return rejected_unsigned + rejected_bad_tag + rejected_replayed;
  }
  // The same drops (malformed and rejected) by source IP address: the first kMaxDropSources
  // addresses heard from each get an entry, later ones are summed under "other", so a flood
  // from many addresses cannot grow it without bound.
  struct SourceDrops {
    std::uint64_t malformed = 0, rejected_unsigned = 0, rejected_bad_tag = 0, rejected_replayed = 0;
    std::uint64_t total() const {
      return malformed + rejected_unsigned + rejected_bad_tag + rejected_replayed;
    }
  };
  static constexpr std::size_t kMaxDropSources = 256;
  std::map<std::string, SourceDrops> dropped_by_source;
};

class UdpTransport {
 public:
  using Receiver = std::function<void(const Datagram&, const asio::ip::udp::endpoint& from)>;
  // Called with what was wrong with a datagram that could not be decoded.
  using ErrorSink = std::function<void(const std::string&, const asio::ip::udp::endpoint& from)>;

  // Binds both sockets; throws CorosError naming the address when it cannot, or when there is
  // neither a key nor `insecure`.
  UdpTransport(asio::io_context& io, TransportOptions options);
  ~UdpTransport();
  UdpTransport(const UdpTransport&) = delete;
  UdpTransport& operator=(const UdpTransport&) = delete;

  // Starts receiving; handlers run on the io_context. Own datagrams (broadcasts coming back)
  // and datagrams that fail authentication are not delivered. An insecure transport says so
  // at warn level here.
  void start(Receiver on_datagram, ErrorSink on_error = {});
  void close();

  // Both sign the datagram (with a key) and return at once; it leaves from the io_context
  // (errors are counted). Thread-safe. Throws CorosError for bytes that cannot be signed.
  void send_to(const asio::ip::udp::endpoint& to, std::vector<std::byte> datagram);
  void broadcast(std::vector<std::byte> datagram);

  asio::ip::udp::endpoint local_endpoint() const;
  const TransportOptions& options() const { return options_; }
  TransportStats stats() const;  // thread-safe
  bool authenticated() const { return options_.key.has_value(); }

 private:
  struct Impl;
  std::shared_ptr<Impl> impl_;
  TransportOptions options_;
};

// A UDP port on this host that was free a moment ago (bound to port 0 and read back): a fleet's
// broadcast port for a run or a test. Throws CorosError saying why when no socket can be bound.
std::uint16_t free_udp_port();

}  // namespace icars::coros
