// PLANET Connection Manager: the client and server roles of the message transfer layer.
//
// The server role accepts TCP connections, completes the TLS handshake where the listener is
// secured and the CONNECT / CONNECT_ACK handshake (admitting a client only within
// `max_connections` and `max_connections_per_address`, when its token or certificate names a
// principal of the AccessPolicy, and when the optional acceptor agrees) and tracks live
// connections; when descriptors run out it backs off instead of failing accept() in a loop. The
// client
// role is a `Peer`: a link to one server that connects in the background and, whenever the
// link drops, reconnects by itself with exponential backoff until stopped. Listeners hear of
// every connection, disconnection and reconnection. Either side may invoke objects on the other
// over the same connection, so a device behind NAT connects out and is called back.
#pragma once

#include <asio/io_context.hpp>
#include <asio/ip/tcp.hpp>
#include <asio/steady_timer.hpp>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "icars/planet/connection.h"

namespace icars::planet {

struct ReconnectPolicy {
  std::chrono::milliseconds initial_delay{10};   // first retry after a drop or failed attempt
  std::chrono::milliseconds max_delay{2000};     // backoff doubles up to this
  std::chrono::milliseconds connect_timeout{3000};  // per TCP connect attempt
  // After the server refused the link (CONNECT_ACK 0xFF: not authenticated, not authorized,
  // full; or a failed TLS handshake) the next retry waits at least refused_delay, doubling up to
  // refused_max_delay: asking again at once rarely changes the answer.
  std::chrono::milliseconds refused_delay{1000};
  std::chrono::milliseconds refused_max_delay{60000};
};

// Descriptors a server keeps free of connections (for files, pipes, listening sockets, the
// process's other libraries): max_connections is lowered to the process's RLIMIT_NOFILE soft
// limit minus this (or to half the limit, if that is smaller), and the listeners stop accepting
// while that many connections (of any state) are open.
inline constexpr std::size_t kDescriptorReserve = 64;

// Raises the soft RLIMIT_NOFILE to the hard limit and returns the soft limit now in force.
// Every ConnectionManager calls it once per process.
std::size_t raise_descriptor_limit();

enum class LinkEventKind : std::uint8_t { connected, disconnected, reconnected };

class Peer;

struct ConnectionEvent {
  LinkEventKind kind;
  std::shared_ptr<Connection> connection;
  std::shared_ptr<Peer> peer;  // set for client-role links
  std::string reason;          // why a link went down
};

// Runs on the io thread; must not block.
using ConnectionListener = std::function<void(const ConnectionEvent&)>;

class ConnectionManager;

// The client role: a self-healing link to one server.
class Peer final : public Link, public std::enable_shared_from_this<Peer> {
 public:
  Peer(ConnectionManager& manager, std::string host, std::uint16_t port, ReconnectPolicy policy);

  std::shared_ptr<Connection> connection() const override;  // null while down
  std::string describe() const override;
  bool is_connected() const;
  // Blocks (never call on the io thread) until connected or the timeout passes.
  bool wait_connected(std::chrono::milliseconds timeout) const;
  // Times the handshake succeeded; 2 or more means the link has been re-established.
  std::uint64_t connect_count() const;
  std::string last_error() const;
  // Stops reconnecting and closes the link. Thread-safe.
  void stop();
  bool uses_tls() const { return tls_; }

 private:
  friend class ConnectionManager;
  void attempt();
  void retry_later(const std::string& why, bool refused = false);
  void on_open(const std::shared_ptr<Connection>& c);
  void on_close(const std::shared_ptr<Connection>& c, const Error& reason);

  void stop_on_io();

  ConnectionManager& manager_;
  std::shared_ptr<asio::io_context> io_;  // declared first: outlives the timer and resolver
  std::string host_;
  std::uint16_t port_;
  ReconnectPolicy policy_;
  bool tls_ = false;
  std::chrono::milliseconds delay_;
  asio::ip::tcp::resolver resolver_;
  asio::steady_timer timer_;
  std::shared_ptr<asio::ip::tcp::socket> connecting_;

  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  std::shared_ptr<Connection> current_;   // open connection
  std::shared_ptr<Connection> handshaking_;
  std::uint64_t connect_count_ = 0;
  bool stopped_ = false;
  std::string last_error_;
};

class ConnectionManager final : public MessageHandler {
 public:
  // `io` is shared with every connection and peer, so one that outlives the manager (held by a
  // proxy) never refers to a destroyed io_context.
  ConnectionManager(std::shared_ptr<asio::io_context> io, MessageHandler& upper,
                    const ConnectionOptions& options, std::shared_ptr<spdlog::logger> logger);
  ~ConnectionManager() override;

  // Server role: listens on address:port (port 0 picks a free one) and returns the bound port.
  // The listener uses TLS when the TlsMode says so for `address` (set_tls); throws
  // std::invalid_argument when it must and no certificate is configured.
  std::uint16_t listen(const std::string& address, std::uint16_t port);
  // Client role: a Peer that connects in the background and keeps reconnecting; over TLS when
  // the TlsMode says so for `host`, verifying the server's certificate.
  std::shared_ptr<Peer> connect(const std::string& host, std::uint16_t port,
                                ReconnectPolicy policy = {});

  // Security (call before listen() and connect()). Throws std::invalid_argument for unreadable
  // files or a certificate that does not match its key.
  void set_tls(const TlsOptions& options);
  void set_token(std::string token);  // sent in every CONNECT this endpoint makes (<= 256 bytes)
  void set_access_policy(std::shared_ptr<const AccessPolicy> policy);

  std::uint64_t add_listener(ConnectionListener listener);
  // Once this returns the listener is not running and never runs again (a listener may remove
  // itself). Thread-safe.
  void remove_listener(std::uint64_t id);
  // An extra admission check after the connection limit and the AccessPolicy; call before listen().
  void set_acceptor(Connection::Acceptor acceptor);
  void set_local_pun(std::string pun);  // defaults to "<address>:<port>" of the socket
  std::string local_pun() const;

  // Server-side connections that completed the handshake, and client links that are up.
  std::vector<std::shared_ptr<Connection>> connections() const;
  // Server role: clients admitted at once: max_connections, lowered (at listen) to what the
  // descriptor limit allows.
  std::size_t connection_cap() const { return connection_cap_.load(); }
  // Accepts that failed (descriptors or memory exhausted, ...) since the manager was made.
  std::uint64_t accept_failures() const { return accept_failures_.load(); }
  // Bytes reserved for incomplete incoming messages across all connections (received, plus
  // credit granted), bounded by total_receive_budget (plus the one message allowed past it).
  std::size_t receive_reserved() const;
  const ConnectionOptions& options() const { return options_; }
  asio::io_context& io() { return *io_; }
  const std::shared_ptr<asio::io_context>& shared_io() const { return io_; }
  spdlog::logger& log() { return *log_; }

  // Stops listening, stops every Peer and closes every connection. Call on the io thread, or
  // from another thread while the io thread runs.
  void shutdown();

  // MessageHandler (called by connections on the io thread)
  void on_message(const std::shared_ptr<Connection>& c, std::span<const std::byte> m) override;
  void on_large_message(const std::shared_ptr<Connection>& c,
                        std::vector<std::vector<std::byte>> blocks) override;
  void on_message_refused(const std::shared_ptr<Connection>& c, std::span<const std::byte> first,
                          const std::string& reason) override;
  void on_open(const std::shared_ptr<Connection>& c) override;
  void on_close(const std::shared_ptr<Connection>& c, const Error& reason) override;

 private:
  friend class Peer;
  struct Acceptor;
  void accept_next(const std::shared_ptr<Acceptor>& acceptor);
  void on_accept_failed(const std::shared_ptr<Acceptor>& acceptor, const std::error_code& ec);
  bool pause_if_full(const std::shared_ptr<Acceptor>& acceptor);
  void resume_accepting();
  void limit_to_descriptors();
  std::shared_ptr<Connection> adopt(asio::ip::tcp::socket socket, ConnectionRole role,
                                    const std::shared_ptr<Peer>& owner, bool tls);
  Admission admit(const ConnectRequest& request);
  bool wants_tls(const std::string& host) const;
  std::shared_ptr<asio::ssl::context> client_context();
  void notify(const ConnectionEvent& event);
  void shutdown_on_io();

  std::shared_ptr<asio::io_context> io_;
  MessageHandler& upper_;
  ConnectionOptions options_;
  std::shared_ptr<spdlog::logger> log_;
  std::shared_ptr<detail::TransportLimits> limits_;  // shared with every connection
  std::atomic<std::size_t> connection_cap_;
  // Connections of any state (and role) the descriptor limit leaves room for; beyond it the
  // listeners pause until one closes.
  std::atomic<std::size_t> descriptor_cap_{std::numeric_limits<std::size_t>::max()};
  std::atomic<std::uint64_t> accept_failures_{0};

  mutable std::mutex mutex_;
  std::string local_pun_;
  Connection::Acceptor accept_policy_;
  TlsOptions tls_options_;
  std::shared_ptr<asio::ssl::context> server_tls_;  // null until a certificate is configured
  std::shared_ptr<asio::ssl::context> client_tls_;  // made on the first TLS connect
  std::string token_;
  std::shared_ptr<const AccessPolicy> access_;
  std::vector<std::shared_ptr<Acceptor>> acceptors_;
  std::unordered_map<std::uint64_t, std::shared_ptr<Connection>> connections_;
  std::unordered_map<std::uint64_t, std::weak_ptr<Peer>> owners_;
  std::vector<std::weak_ptr<Peer>> peers_;
  struct ListenerEntry {
    ConnectionListener fn;
    std::recursive_mutex calling;  // held while fn runs; remove_listener waits on it
    bool removed = false;
  };
  std::map<std::uint64_t, std::shared_ptr<ListenerEntry>> listeners_;
  std::uint64_t next_listener_ = 1;
  bool shut_down_ = false;
};

}  // namespace icars::planet
