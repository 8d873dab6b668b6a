// PLANET message transfer layer: one framed, flow-controlled, heart-beaten TCP connection.
//
// A Connection carries whole messages (byte strings) in both directions. It divides each
// outgoing message into 16 KiB frames, interleaves the frames of concurrent messages fairly
// (the I/O scheduler: control frames first, then one frame per message in turn), merges incoming
// frames back into messages, enforces the DATA_ACK window (flow control), exchanges heartbeats
// and closes itself when the peer falls silent. All of its state lives on one io_context
// thread; `send` and `close` may be called from any thread.
#pragma once

#include <asio/io_context.hpp>
#include <asio/ip/tcp.hpp>
#include <asio/steady_timer.hpp>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "icars/clock/activity.h"
#include "icars/planet/error.h"
#include "icars/planet/frame.h"
#include "icars/planet/security.h"

namespace spdlog {
class logger;
}
namespace asio::ssl {
class context;
}

namespace icars::planet {

namespace detail {
struct TransportLimits;
struct OutgoingMessage;
struct ScheduledFrame;
class FrameScheduler;
struct IncomingMessage;
}

// Frames of one message the sender may have outstanding before a DATA_ACK(more); each ack
// grants kAckEvery more. Fixed by protocol version 1 (docs/protocol.md, "Flow control").
inline constexpr std::uint32_t kWindowFrames = 8;
inline constexpr std::uint32_t kAckEvery = kWindowFrames / 2;
// Multi-frame messages a sender may have started and not finished on one connection; a
// receiver must accept at least this many interleaved incomplete messages.
inline constexpr std::size_t kMaxInterleavedMessages = 16;
// Control frames (acks, heartbeats) queued but unwritten; beyond this the peer is not reading
// and the connection is closed.
inline constexpr std::size_t kMaxQueuedControlFrames = 4096;
// The longest token a client may send in CONNECT (protocol 3.1).
inline constexpr std::size_t kMaxTokenSize = 256;

struct ConnectionOptions {
  std::chrono::milliseconds heartbeat_interval{1000};  // a HEARTBEAT is sent this often
  std::chrono::milliseconds heartbeat_timeout{5000};   // silence longer than this closes the link
  std::chrono::milliseconds handshake_timeout{5000};   // CONNECT / CONNECT_ACK must arrive by then
  std::size_t max_message_size = 64u << 20;    // larger incoming messages are refused (NO_MORE)
  std::size_t send_queue_limit = 128u << 20;   // bytes accepted but unwritten; beyond: overloaded
  std::size_t receive_budget = 128u << 20;     // bytes of incomplete incoming messages before
                                               // acks are held back (only the oldest proceeds)
  std::size_t max_incomplete_messages = 256;   // interleaved incoming messages per connection
                                               // (at least kMaxInterleavedMessages)
  std::size_t max_connections = 1024;  // server role: clients admitted at once; more are denied
                                       // (also kept below the process's descriptor limit)
  // Server role: clients admitted at once from one IP address (loopback addresses included), so
  // that one host cannot take every slot; more are denied.
  std::size_t max_connections_per_address = 64;
  // A message in flight must make progress this often: an incomplete incoming message that was
  // granted credit and receives no frame, a started frame that does not complete, a queued
  // message waiting for flow-control credit (DATA_ACK), or a write the peer does not drain,
  // for longer than this closes the connection.
  std::chrono::milliseconds message_progress_timeout{30000};
  // Bytes of incomplete incoming messages (received plus credit granted) across all connections
  // of a ConnectionManager; beyond it new multi-frame messages are refused (NO_MORE) and acks are
  // held back, except for one message at a time that may complete.
  std::size_t total_receive_budget = 256u << 20;
  // Lock-step (icars/clock/activity.h): when set, a message to an endpoint of this process that
  // shares the activity counts as work from send() until its receiver has handled it, and the
  // communicator's io thread is one of the activity's queues. Null: nothing is counted.
  std::shared_ptr<Activity> activity;

  void validate() const;  // throws std::invalid_argument naming the bad option
};

enum class ConnectionRole : std::uint8_t { client, server };

// What a client says about itself in CONNECT, and what TLS proved about it.
struct ConnectRequest {
  // The client's PUN (PLANET unique name): the name it announces for itself, by default its
  // "<ip>:<port>" (CommunicatorOptions::pun explains it). Not checked for uniqueness.
  std::string pun;
  std::string token;             // empty: none sent
  std::string certificate_name;  // common name of its verified TLS client certificate, if any
  std::string remote_address;
  std::string remote_ip;  // remote_address without the port
};

// A server's decision on a CONNECT.
struct Admission {
  std::optional<std::string> deny;             // set: CONNECT_ACK 0xFF with this reason
  std::shared_ptr<const Principal> principal;  // who the client is; null: not authenticated
};

// How a connection protects itself: plaintext when `tls` is null.
struct ConnectionSecurity {
  std::shared_ptr<asio::ssl::context> tls;
  std::string server_name;  // client: the name the server's certificate must carry
  std::string token;        // client: sent in CONNECT to authenticate this endpoint
};

class Connection;

// Implemented by the layer above the transport (the RMI layer). Called on the io thread.
class MessageHandler {
 public:
  virtual ~MessageHandler() = default;
  // A complete message; the span is valid only during the call.
  virtual void on_message(const std::shared_ptr<Connection>& connection,
                          std::span<const std::byte> message) = 0;
  // A complete message larger than one reassembly block (1 MiB), in its blocks, to be handled
  // wherever suits the layer above (the RMI layer hands it to a worker thread so that the io
  // thread keeps serving small messages). By default: joined and passed to on_message.
  virtual void on_large_message(const std::shared_ptr<Connection>& connection,
                                std::vector<std::vector<std::byte>> blocks);
  // The blocks of a large message as one contiguous message.
  static std::vector<std::byte> join(std::vector<std::vector<std::byte>> blocks);
  // A message this side refused (too large): its first frame, so the RMI layer can answer the
  // request with an error instead of leaving the caller waiting.
  virtual void on_message_refused(const std::shared_ptr<Connection>& connection,
                                  std::span<const std::byte> first_frame,
                                  const std::string& reason) = 0;
  virtual void on_open(const std::shared_ptr<Connection>& connection) = 0;
  virtual void on_close(const std::shared_ptr<Connection>& connection, const Error& reason) = 0;
};

// Something a proxy can send through: a live connection, or a reconnecting client Peer.
class Link {
 public:
  virtual ~Link() = default;
  // The connection to use now; null while a reconnecting link is down.
  virtual std::shared_ptr<Connection> connection() const = 0;
  virtual std::string describe() const = 0;  // for error messages
};

// Completion of a queued message: null once its last frame is written, or the error that
// dropped it (disconnected, or refused by the peer).
using SendHandler = std::function<void(const std::exception_ptr&)>;

struct ConnectionStats {
  std::uint64_t messages_sent = 0;
  std::uint64_t messages_received = 0;
  std::uint64_t frames_sent = 0;
  std::uint64_t frames_received = 0;
  std::uint64_t bytes_sent = 0;
  std::uint64_t bytes_received = 0;
  std::uint64_t messages_dropped = 0;  // queued messages discarded when the link closed
  std::uint64_t messages_read_by_callers = 0;  // replies read by their caller (read_directly)
};

class Connection final : public Link, public std::enable_shared_from_this<Connection> {
 public:
  // Decides whether a server admits a client (runs on the io thread during the handshake).
  using Acceptor = std::function<Admission(const ConnectRequest&)>;

  Connection(std::shared_ptr<asio::io_context> io, asio::ip::tcp::socket socket,
             ConnectionRole role, std::string local_pun,
             const ConnectionOptions& options, MessageHandler& handler,
             std::shared_ptr<spdlog::logger> logger, Acceptor acceptor = {},
             ConnectionSecurity security = {},
             std::shared_ptr<detail::TransportLimits> limits = {});  // null: its own
  ~Connection() override;
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  // Starts the handshake (TLS first when secured, then a client sends CONNECT) and the read
  // loop. Call once, on the io thread.
  void start();

  // Queues a message. Never blocks. Throws Error(disconnected) when the connection is not open
  // and Error(overloaded) when the send queue would exceed `send_queue_limit`. `on_sent`, if
  // given, runs exactly once on the io thread. Thread-safe.
  //
  // Frames of different messages are interleaved (a large message does not hold up small ones),
  // so messages may complete at the receiver in another order than they were sent. Messages
  // sent `in_order` do not: one starts only when every earlier in_order message on this
  // connection has been written whole (a publisher's events, whatever their sizes).
  void send(std::vector<std::byte> message, SendHandler on_sent = {}, bool in_order = false);

  // Closes the connection; queued messages are dropped and MessageHandler::on_close runs with
  // Error(disconnected, reason). Thread-safe and idempotent.
  void close(const std::string& reason);

  bool is_open() const { return state_.load() == State::open; }
  // True once the handshake completed, even after the connection closed.
  bool was_open() const { return was_open_; }
  ConnectionRole role() const { return role_; }
  std::uint64_t id() const { return id_; }
  const std::string& local_pun() const { return local_pun_; }
  std::string peer_pun() const;  // the PUN the peer announced in CONNECT / CONNECT_ACK
  bool is_tls() const { return tls_ != nullptr; }
  // The common name of the peer's verified TLS certificate; empty without one.
  std::string peer_certificate_name() const;
  // Server role: the principal the client authenticated as (null without an AccessPolicy).
  std::shared_ptr<const Principal> principal() const;
  const std::string& remote_address() const { return remote_address_; }
  const std::string& remote_ip() const { return remote_ip_; }  // without the port
  std::size_t queued_bytes() const;  // bytes accepted by send() and not yet written
  ConnectionStats stats() const;
  std::size_t incomplete_bytes() const { return incomplete_bytes_.load(); }

  std::shared_ptr<Connection> connection() const override;
  std::string describe() const override;

  // A synchronous caller reads its own reply: waits on this thread for what the peer sends next
  // and reads it here instead of on the io thread, so the reply reaches the waiting thread
  // without passing through another one. Only while no one else reads this connection (no
  // bytes or incomplete messages waiting for the io thread) and no message on its way out
  // waits for the peer's acks, in plaintext and without lock-step; false at once otherwise. The first message read, if it came whole in one frame,
  // is offered to `take` (on this thread); anything else read (another message, a control
  // frame, part of a frame, the end of the stream) is left to the io thread, in order. Returns
  // true when `take` accepted a message; false when something else came first, `answered()`
  // turned true (the io thread completed the call) or `until` passed.
  bool read_directly(std::chrono::steady_clock::time_point until,
                     const std::function<bool()>& answered,
                     const std::function<bool(std::span<const std::byte>)>& take);

 private:
  enum class State : std::uint8_t { handshaking, open, closed };
  struct Tls;

  void begin_handshake();
  void read_more();
  void on_readable(const std::error_code& ec);  // plaintext: the peer sent bytes
  void read_available();                        // read_mutex_ held
  void resume_reading();                        // after a direct reader gave the socket back
  void on_read(const std::error_code& ec, std::size_t n);
  void handle_buffered(bool read_next = true);  // the whole frames in rbuf_, then read_more()
  void note_received(std::size_t n);
  bool handle_frame(const FrameHeader& h, std::span<const std::byte> payload);
  bool handle_connect(const FrameHeader& h, std::span<const std::byte> payload);
  bool handle_connect_ack(std::span<const std::byte> payload);
  bool handle_data(const FrameHeader& h, std::span<const std::byte> payload);
  bool handle_data_ack(std::span<const std::byte> payload);
  void release_deferred_acks();
  void update_reservation(detail::IncomingMessage& in);
  void forget_incoming(detail::IncomingMessage& in);
  bool check_progress(std::chrono::steady_clock::time_point now);
  void log_denial(const std::string& who, const std::string& reason);
  void send_data_ack(std::uint32_t msg_no, AckCode code);
  void send_control(FrameCode code, std::vector<std::byte> payload, std::uint32_t msg_no = 0);
  void schedule_write_locked();
  void write_batch();
  void on_written(const std::error_code& ec, std::size_t n);
  bool try_direct_send_locked(detail::OutgoingMessage& msg);
  void arm_timer();
  void on_timer();
  void fail(ErrorKind kind, const std::string& reason, bool quiet = false);  // quiet: debug log
  void finish_close();

  static std::atomic<std::uint64_t> next_id_;

  std::shared_ptr<asio::io_context> io_;  // declared first: outlives the socket and timer
  // Bytes received by the kernel and not yet read (0 when it cannot tell).
  std::size_t unread_bytes();
  // Whether the peer has been silent past the heartbeat timeout and the socket says it hung up
  // (a FIN or an error not read yet): after this process was stopped, say. Any thread.
  bool peer_hung_up_unread();

  asio::ip::tcp::socket socket_;
  asio::steady_timer timer_;
  ConnectionRole role_;
  std::string local_pun_;
  ConnectionOptions options_;
  MessageHandler& handler_;
  std::shared_ptr<spdlog::logger> log_;
  Acceptor acceptor_;
  std::string token_;
  std::unique_ptr<Tls> tls_;  // null: plaintext
  std::uint64_t id_;
  std::string remote_address_;
  Activity::LinkEnd link_;  // to the other end, when it is in this process (lock-step)
  std::string remote_ip_;
  std::shared_ptr<detail::TransportLimits> limits_;
  std::atomic<State> state_{State::handshaking};
  // When bytes last came from the peer; read by senders on any thread.
  std::atomic<std::chrono::steady_clock::time_point> last_received_;
  // Until then a send checks the socket for a hang-up (bytes came after a long silence).
  std::atomic<std::chrono::steady_clock::time_point> suspect_until_{};
  std::chrono::steady_clock::time_point opened_at_;
  // The heartbeat timeout found bytes waiting unread (this process was stopped or starved):
  // they get one heartbeat interval to be read before the silence counts.
  bool late_read_grace_ = false;
  bool close_after_flush_ = false;
  bool was_open_ = false;

  // Receive side: the io thread's, except that a direct reader (read_directly) may read into
  // rbuf_ while it holds the socket. rbuf_, rbegin_, rend_ and the reading of the socket are
  // guarded by read_mutex_ (held by the io thread while it handles what it read).
  std::recursive_mutex read_mutex_;
  bool direct_reader_ = false;  // a caller thread reads the socket (read_mutex_)
  bool io_parked_ = false;      // the io thread found it reading and waits to resume (read_mutex_)
  bool read_closed_ = false;    // the socket is closed: nothing may read it (read_mutex_)
  bool peek_armed_ = false;     // io thread: waiting for the socket to become readable
  std::byte peek_byte_{};
  std::atomic<std::size_t> incoming_count_{0};  // incoming_.size(), for direct readers
  std::unique_ptr<std::byte[]> rbuf_;  // kReadBufferSize bytes
  std::size_t rbegin_ = 0;
  std::size_t rend_ = 0;
  // The first reassembly block of the last multi-frame message, kept for the next one while
  // such messages keep arriving; released after a heartbeat interval without one (on_timer).
  std::vector<std::byte> spare_;
  std::atomic<bool> handling_read_{false};  // the io thread is handling frames of one read
  bool spare_used_ = false;
  std::vector<std::unique_ptr<detail::IncomingMessage>> incoming_;  // in arrival order; the first is the oldest
  std::atomic<std::size_t> incomplete_bytes_{0};
  // Since when the bytes after the last whole frame have waited for the rest of their frame.
  std::optional<std::chrono::steady_clock::time_point> partial_frame_since_;
  bool waiting_for_budget_ = false;  // registered with the receive budget for a wake-up

  // Send side (guarded by send_mutex_).
  mutable std::mutex send_mutex_;
  bool send_open_ = true;
  bool writing_ = false;
  std::size_t queued_bytes_ = 0;
  std::uint32_t next_msg_no_ = 1;
  std::deque<std::vector<std::byte>> control_;  // whole frames (header included), sent first
  std::unique_ptr<detail::FrameScheduler> scheduler_;  // the messages with frames left
  ConnectionStats stats_;
  std::vector<detail::OutgoingMessage> retired_;  // removed while a write may still reference their bytes

  mutable std::mutex info_mutex_;
  std::string peer_pun_;
  std::string peer_certificate_name_;
  std::shared_ptr<const Principal> principal_;

  // The batch being written (io thread only while writing_).
  std::vector<asio::const_buffer> batch_;
  std::vector<detail::ScheduledFrame> batch_frames_picked_;
  std::vector<FrameHeaderBytes> batch_headers_;
  std::vector<std::vector<std::byte>> batch_control_;
  std::vector<detail::OutgoingMessage> batch_done_;  // messages whose last frame is in the batch
  std::size_t batch_payload_bytes_ = 0;
  std::size_t batch_frames_ = 0;
  std::optional<std::chrono::steady_clock::time_point> write_started_;  // guarded by send_mutex_
};

}  // namespace icars::planet
