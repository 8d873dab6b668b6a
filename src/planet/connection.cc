#include "icars/planet/connection.h"

#include "buffer_pool.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/uio.h>

#include <openssl/bio.h>
#include <openssl/err.h>
#include <openssl/ssl.h>
#include <openssl/x509.h>

#include <algorithm>
#include <asio/post.hpp>
#include <asio/ssl.hpp>
#include <asio/write.hpp>
#include <cerrno>
#include <cstring>
#include <stdexcept>

#include "frame_scheduler.h"
#include "icars/planet/serializer.h"
#include "message_assembly.h"
#include "transport_limits.h"

namespace icars::planet {

namespace {

constexpr std::size_t kReadBufferSize = 256 * 1024;
constexpr std::size_t kMaxBatchBytes = 256 * 1024;  // one gathered write
constexpr std::size_t kMaxBatchFrames = 64;
// The receive-budget reservation of one DATA_ACK(more): the frames it grants.
constexpr std::size_t kAckBytes = std::size_t{kAckEvery} * kMaxFramePayload;

// " (N more since the last report)" for a rate-limited log line that held N lines back.
std::string held_back(std::uint64_t n) {
  return n == 0 ? std::string() : fmt::format(" ({} more since the last report)", n);
}

std::int64_t ms(std::chrono::steady_clock::duration d) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(d).count();
}

// A full read buffer moves its unhandled bytes to the front: a complete frame always fits
// after compaction.
void compact_when_full(std::byte* buffer, std::size_t& begin, std::size_t& end) {
  if (end != kReadBufferSize) return;
  std::memmove(buffer, buffer + begin, end - begin);
  end -= begin;
  begin = 0;
}

std::vector<std::byte> frame_bytes(const FrameHeader& h, std::span<const std::byte> payload) {
  std::vector<std::byte> out(kFrameHeaderSize + payload.size());
  const auto header = encode_header(h);
  std::memcpy(out.data(), header.data(), header.size());
  if (!payload.empty()) std::memcpy(out.data() + kFrameHeaderSize, payload.data(), payload.size());
  return out;
}

}  // namespace

void ConnectionOptions::validate() const {
  if (heartbeat_interval.count() <= 0) throw std::invalid_argument("heartbeat_interval must be > 0");
  if (heartbeat_timeout <= heartbeat_interval) {
    throw std::invalid_argument("heartbeat_timeout must be longer than heartbeat_interval");
  }
  if (handshake_timeout.count() <= 0) throw std::invalid_argument("handshake_timeout must be > 0");
  if (max_message_size == 0) throw std::invalid_argument("max_message_size must be > 0");
  if (send_queue_limit < max_message_size) {
    throw std::invalid_argument("send_queue_limit must be at least max_message_size");
  }
  if (receive_budget < max_message_size) {
    throw std::invalid_argument("receive_budget must be at least max_message_size");
  }
  if (max_connections == 0) throw std::invalid_argument("max_connections must be > 0");
  if (max_connections_per_address == 0) {
    throw std::invalid_argument("max_connections_per_address must be > 0");
  }
  if (message_progress_timeout.count() <= 0) {
    throw std::invalid_argument("message_progress_timeout must be > 0");
  }
  if (total_receive_budget < max_message_size) {
    throw std::invalid_argument("total_receive_budget must be at least max_message_size");
  }
  if (max_incomplete_messages < kMaxInterleavedMessages) {
    throw std::invalid_argument("max_incomplete_messages must be at least 16 (protocol minimum)");
  }
}

// TLS over the connection's socket: OpenSSL's engine between two memory BIOs, the socket read
// and written by the connection itself. So whichever thread reads or writes the socket (the io
// thread, a caller sending its request or reading its reply directly) runs the engine there,
// under `engine`, and a TLS call takes the same direct paths as a plaintext one. Lock order:
// send_mutex_ or read_mutex_, then `engine`.
struct Connection::Tls {
  explicit Tls(asio::ssl::context& context) : ssl(SSL_new(context.native_handle())) {
    if (ssl == nullptr) throw std::runtime_error("SSL_new failed");
    BIO* in_bio = BIO_new(BIO_s_mem());
    BIO* out_bio = BIO_new(BIO_s_mem());
    if (in_bio == nullptr || out_bio == nullptr) {
      BIO_free(in_bio);
      BIO_free(out_bio);
      SSL_free(ssl);
      throw std::runtime_error("BIO_new failed");
    }
    // Renegotiation (TLS 1.2) would let the peer make a write wait for a read.
    SSL_set_options(ssl, SSL_OP_NO_RENEGOTIATION);
    BIO_set_mem_eof_return(in_bio, -1);  // empty: "more to come", not the end of the stream
    SSL_set_bio(ssl, in_bio, out_bio);   // owned by ssl from here
    in = in_bio;
    out = out_bio;
  }
  ~Tls() { SSL_free(ssl); }
  Tls(const Tls&) = delete;
  Tls& operator=(const Tls&) = delete;

  // What the engine wrote for the peer, appended to `to` (engine held).
  void take_output(std::vector<std::byte>& to) {
    const std::size_t n = BIO_ctrl_pending(out);
    if (n == 0) return;
    const std::size_t at = to.size();
    to.resize(at + n);
    const int got = BIO_read(out, to.data() + at, static_cast<int>(n));
    to.resize(at + static_cast<std::size_t>(std::max(got, 0)));
  }
  // Encrypts `plain` onto `to` (engine held). False, with `error` set, if the engine failed.
  bool seal(std::span<const std::byte> plain, std::vector<std::byte>& to) {
    std::size_t done = 0;
    while (done < plain.size()) {
      ERR_clear_error();
      const int chunk = static_cast<int>(std::min<std::size_t>(plain.size() - done, 1 << 30));
      const int n = SSL_write(ssl, plain.data() + done, chunk);
      if (n <= 0) {
        error = describe_error(n, "TLS write");
        return false;
      }
      done += static_cast<std::size_t>(n);
    }
    take_output(to);
    return true;
  }
  // Decrypts into [to, to + space) what the engine holds (engine held): the bytes written, 0
  // when it needs more from the peer, -1 at the peer's close_notify, -2 on an error (`error`).
  std::ptrdiff_t open_some(std::byte* to, std::size_t space) {
    std::size_t got = 0;
    input_left = true;  // unless the engine runs out of input below
    while (got < space) {
      if (got > 0 && SSL_pending(ssl) == 0 && BIO_ctrl_pending(in) == 0) {
        input_left = false;  // every byte received is decrypted: no SSL_read to be told so
        break;
      }
      ERR_clear_error();
      const int n = SSL_read(ssl, to + got, static_cast<int>(std::min<std::size_t>(space - got, 1 << 30)));
      if (n > 0) {
        got += static_cast<std::size_t>(n);
        continue;
      }
      const int e = SSL_get_error(ssl, n);
      if (e == SSL_ERROR_WANT_READ) {
        input_left = false;
        break;
      }
      if (got > 0) break;  // the close or the error is reported by the next call
      if (e == SSL_ERROR_ZERO_RETURN) return -1;
      error = describe_error(n, "TLS read");
      return -2;
    }
    return static_cast<std::ptrdiff_t>(got);
  }
  // Reads into rbuf_ after rend_ (read_mutex_ held), as ::recv would: what the engine holds
  // first, then what the socket has. The plaintext bytes; 0 at the end of the stream (the
  // peer's close_notify, or its end of the TCP stream); -1 with errno EAGAIN when nothing
  // decryptable came yet, EPROTO when the engine failed (`error`), or the socket's error.
  ssize_t read(Connection& c);
  // Sends a one-frame message from the sending thread (send_mutex_ held, no write in flight):
  // sealed here; what the kernel does not take at once is written next by the io thread.
  // False when it must be queued instead (earlier ciphertext waits, or the engine failed).
  bool direct_send(Connection& c, const FrameHeaderBytes& header, const detail::OutgoingMessage& msg);
  bool holds_input() {
    std::lock_guard lock(engine);
    return input_left;
  }
  bool has_pending() {
    std::lock_guard lock(engine);
    return !pending.empty();
  }
  std::string describe_error(int result, const char* what) const {
    const int e = SSL_get_error(ssl, result);
    const unsigned long code = ERR_peek_last_error();
    if (code != 0) {
      const char* reason = ERR_reason_error_string(code);
      return reason != nullptr ? reason : fmt::format("{} failed (OpenSSL error {:#x})", what, code);
    }
    return fmt::format("{} failed (SSL error {})", what, e);
  }

  SSL* ssl;
  BIO* in;   // ciphertext from the peer, for the engine to read
  BIO* out;  // ciphertext the engine wrote, for the socket
  std::mutex engine;
  // The engine may hold whole records not decrypted yet (the last open_some stopped for want of
  // space, or the handshake's last read brought more): read them before waiting on the socket.
  bool input_left = false;
  std::vector<std::byte> pending;  // ciphertext not yet handed to the socket, in order (engine)
  std::string error;               // the last engine failure (engine)
  // read_mutex_ (or the handshake): ciphertext received from the socket. Not zero-filled: an
  // idle connection never touches most of it.
  static constexpr std::size_t kReceiveSize = 64 * 1024;
  std::unique_ptr<std::byte[]> received = std::make_unique_for_overwrite<std::byte[]>(kReceiveSize);
  // io thread while writing_: the batch's plaintext gathered into one buffer (a record per
  // 9-byte header would cost more than the copy), and the ciphertext being written.
  std::vector<std::byte> gathered;
  std::vector<std::byte> writing;
  std::size_t writing_plain = 0;  // the plaintext bytes `writing` carries
  // The handshake (io thread): a step of the engine, its output written, the peer's read.
  void handshake_step(const std::shared_ptr<Connection>& self);
  void handshake_failed(Connection& c, const std::string& why);
  void handshake_done(Connection& c);
  std::vector<std::byte> handshake_out;
};

namespace {

std::string certificate_common_name(SSL* ssl) {
  X509* cert = SSL_get1_peer_certificate(ssl);
  if (cert == nullptr) return {};
  char name[256] = {};
  const int n = X509_NAME_get_text_by_NID(X509_get_subject_name(cert), NID_commonName, name,
                                          static_cast<int>(sizeof name));
  X509_free(cert);
  return n > 0 ? std::string(name, static_cast<std::size_t>(n)) : std::string();
}

}  // namespace

std::atomic<std::uint64_t> Connection::next_id_{1};

std::vector<std::byte> MessageHandler::join(std::vector<std::vector<std::byte>> blocks) {
  if (blocks.size() == 1) return std::move(blocks[0]);
  std::size_t size = 0;
  for (const auto& b : blocks) size += b.size();
  std::vector<std::byte> message = detail::take_buffer(size);
  for (auto& b : blocks) {
    message.insert(message.end(), b.begin(), b.end());
    detail::give_buffer(std::move(b));  // each block is recycled as soon as it is copied
  }
  return message;
}

void MessageHandler::on_large_message(const std::shared_ptr<Connection>& connection,
                                      std::vector<std::vector<std::byte>> blocks) {
  on_message(connection, join(std::move(blocks)));
}

Connection::Connection(std::shared_ptr<asio::io_context> io, asio::ip::tcp::socket socket,
                       ConnectionRole role, std::string local_pun,
                       const ConnectionOptions& options, MessageHandler& handler,
                       std::shared_ptr<spdlog::logger> logger, Acceptor acceptor,
                       ConnectionSecurity security,
                       std::shared_ptr<detail::TransportLimits> limits)
    : io_(std::move(io)),
      socket_(std::move(socket)),
      timer_(socket_.get_executor()),
      role_(role),
      local_pun_(std::move(local_pun)),
      options_(options),
      handler_(handler),
      log_(std::move(logger)),
      acceptor_(std::move(acceptor)),
      token_(std::move(security.token)),
      id_(next_id_.fetch_add(1)),
      limits_(limits ? std::move(limits)
                     : std::make_shared<detail::TransportLimits>(options.total_receive_budget,
                                                                 kAckBytes)),
      // Not zero-filled: a connection carrying small messages only ever touches the first pages.
      rbuf_(std::make_unique_for_overwrite<std::byte[]>(kReadBufferSize)),
      scheduler_(std::make_unique<detail::FrameScheduler>()) {
  options_.validate();
  std::error_code ec;
  socket_.set_option(asio::ip::tcp::no_delay(true), ec);
  const auto remote = socket_.remote_endpoint(ec);
  remote_ip_ = ec ? "unknown" : remote.address().to_string();
  remote_address_ = ec ? "unknown" : fmt::format("{}:{}", remote_ip_, remote.port());
  if (options_.activity && !ec) {
    const auto local = socket_.local_endpoint(ec);
    if (!ec) link_ = options_.activity->join(fmt::format("{}:{}", local.address().to_string(), local.port()), remote_address_);
  }
  batch_headers_.reserve(kMaxBatchFrames);
  batch_frames_picked_.reserve(kMaxBatchFrames);
  if (security.tls) {
    tls_ = std::make_unique<Tls>(*security.tls);
    if (role_ == ConnectionRole::client) {
      const std::string& name = security.server_name;
      // SNI, and the name the server's certificate must carry (an IP address is matched
      // against the certificate's IP subject alternative names).
      std::error_code address_ec;
      (void)asio::ip::make_address(name, address_ec);
      if (address_ec) {  // SSL_set_tlsext_host_name, without the macro's C cast
        SSL_ctrl(tls_->ssl, SSL_CTRL_SET_TLSEXT_HOSTNAME, TLSEXT_NAMETYPE_host_name,
                 const_cast<char*>(name.c_str()));
        SSL_set_hostflags(tls_->ssl, X509_CHECK_FLAG_NO_PARTIAL_WILDCARDS);
        SSL_set1_host(tls_->ssl, name.c_str());
      } else {
        X509_VERIFY_PARAM_set1_ip_asc(SSL_get0_param(tls_->ssl), name.c_str());
      }
      SSL_set_verify(tls_->ssl, SSL_VERIFY_PEER, nullptr);
      SSL_set_connect_state(tls_->ssl);
    } else {
      SSL_set_accept_state(tls_->ssl);
    }
  }
}

Connection::~Connection() { link_.close(); }

void Connection::start() {
  opened_at_ = std::chrono::steady_clock::now();
  last_received_.store(opened_at_, std::memory_order_relaxed);
  arm_timer();  // the handshake timeout covers the TLS handshake too
  if (!tls_) {
    begin_handshake();
    return;
  }
  tls_->handshake_step(shared_from_this());
}

// The TLS handshake, on the io thread before anything else reads or writes the socket: the
// engine's output written whole, then the peer's answer read, until the engine is done.
void Connection::Tls::handshake_step(const std::shared_ptr<Connection>& self) {
  Connection& c = *self;
  if (c.state_.load() == State::closed) return;
  int result = 0;
  std::string failure;
  {
    std::lock_guard lock(engine);
    ERR_clear_error();
    result = SSL_do_handshake(ssl);
    if (result != 1 && SSL_get_error(ssl, result) != SSL_ERROR_WANT_READ) {
      failure = describe_error(result, "TLS handshake");
    }
    handshake_out.clear();
    take_output(handshake_out);  // an alert too, if it failed
  }
  const auto next = [self, result, failure] {
    Connection& conn = *self;
    if (conn.state_.load() == State::closed) return;
    if (!failure.empty()) return conn.tls_->handshake_failed(conn, failure);
    if (result == 1) return conn.tls_->handshake_done(conn);
    conn.socket_.async_read_some(asio::buffer(conn.tls_->received.get(), Tls::kReceiveSize),
                                 [self](const std::error_code& ec, std::size_t n) {
                                   Connection& reader = *self;
                                   if (reader.state_.load() == State::closed) return;
                                   if (ec) {
                                     return reader.tls_->handshake_failed(
                                         reader, ec == asio::error::eof ? "the peer closed the connection" : ec.message());
                                   }
                                   reader.note_received(n);
                                   {
                                     std::lock_guard lock(reader.tls_->engine);
                                     BIO_write(reader.tls_->in, reader.tls_->received.get(), static_cast<int>(n));
                                   }
                                   reader.tls_->handshake_step(self);
                                 });
  };
  if (handshake_out.empty()) return next();
  asio::async_write(c.socket_, asio::buffer(handshake_out),
                    [self, next, failed = !failure.empty()](const std::error_code& ec, std::size_t n) {
                      Connection& writer = *self;
                      if (writer.state_.load() == State::closed) return;
                      if (ec && !failed) return writer.tls_->handshake_failed(writer, ec.message());
                      {
                        std::lock_guard lock(writer.send_mutex_);
                        writer.stats_.bytes_sent += n;
                      }
                      next();
                    });
}

void Connection::Tls::handshake_failed(Connection& c, const std::string& why) {
  long verify = X509_V_OK;
  {
    std::lock_guard lock(engine);
    verify = SSL_get_verify_result(ssl);
  }
  const std::string detail =
      verify != X509_V_OK ? fmt::format(" ({})", X509_verify_cert_error_string(verify)) : std::string();
  const std::string reason =
      fmt::format("TLS handshake with {} failed: {}{}", c.remote_address_, why, detail);
  // A server hears of every client that fails (a wrong CA, plaintext, a scanner), so the line
  // is rate-limited per address.
  const bool server = c.role_ == ConnectionRole::server;
  if (server) {
    if (auto held = c.limits_->tls_failures.admit(c.remote_ip_)) {
      c.log_->warn("{}{}", reason, held_back(*held));
    }
  }
  c.fail(ErrorKind::refused, reason, server);
}

void Connection::Tls::handshake_done(Connection& c) {
  std::string name;
  {
    std::lock_guard lock(engine);
    name = certificate_common_name(ssl);
  }
  {
    std::lock_guard lock(c.info_mutex_);
    c.peer_certificate_name_ = std::move(name);
  }
  std::vector<std::byte>().swap(handshake_out);
  {
    std::lock_guard lock(engine);
    input_left = true;  // the handshake's last read may have brought the first records
  }
  c.begin_handshake();
}

ssize_t Connection::Tls::read(Connection& c) {
  std::byte* to = c.rbuf_.get() + c.rend_;
  const std::size_t space = kReadBufferSize - c.rend_;
  // Fills the space while the socket has bytes: a large message needs fewer wake-ups. A close or
  // an error after some plaintext is reported by the next call (both stay).
  std::size_t total = 0;
  bool drained = false;
  for (;;) {
    std::ptrdiff_t got = 0;
    {
      std::lock_guard lock(engine);
      if (!error.empty()) {
        if (total > 0) return static_cast<ssize_t>(total);
        errno = EPROTO;
        return -1;
      }
      // Nothing decryptable is held before the first read of the socket (open_some said so).
      got = total == 0 && !input_left && BIO_ctrl_pending(in) == 0 ? 0 : open_some(to + total, space - total);
      if (BIO_ctrl_pending(out) > 0) {  // the engine answered the peer (a key update, say)
        take_output(pending);
        asio::post(c.socket_.get_executor(), [self = c.shared_from_this()] {
          std::lock_guard send_lock(self->send_mutex_);
          if (self->send_open_) self->schedule_write_locked();
        });
      }
    }
    if (got > 0) {
      total += static_cast<std::size_t>(got);
      // Full, or the socket was drained by the last read (it returned less than asked): another
      // recv would find nothing and cost a system call on every small message.
      if (total == space || drained) return static_cast<ssize_t>(total);
    } else if (got == -1 || got == -2) {
      if (total > 0) return static_cast<ssize_t>(total);
      if (got == -1) return 0;
      errno = EPROTO;
      return -1;
    }
    const ssize_t n = ::recv(c.socket_.native_handle(), received.get(), Tls::kReceiveSize, MSG_DONTWAIT);
    if (n <= 0) return total > 0 ? static_cast<ssize_t>(total) : n;
    drained = static_cast<std::size_t>(n) < Tls::kReceiveSize;
    std::lock_guard lock(engine);
    BIO_write(in, received.get(), static_cast<int>(n));
  }
}

bool Connection::Tls::direct_send(Connection& c, const FrameHeaderBytes& header,
                                  const detail::OutgoingMessage& msg) {
  thread_local std::vector<std::byte> plain;
  thread_local std::vector<std::byte> sealed;
  std::lock_guard lock(engine);
  if (!pending.empty() || !error.empty()) return false;
  plain.assign(header.begin(), header.end());
  plain.insert(plain.end(), msg.payload.begin(), msg.payload.end());
  sealed.clear();
  if (!seal(plain, sealed)) return false;  // the io thread meets the failure and reports it
  const ssize_t n = ::send(c.socket_.native_handle(), sealed.data(), sealed.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
  const std::size_t written = n > 0 ? static_cast<std::size_t>(n) : 0;
  if (written < sealed.size()) {
    pending.insert(pending.end(), sealed.begin() + static_cast<std::ptrdiff_t>(written), sealed.end());
    c.schedule_write_locked();
  }
  c.queued_bytes_ -= msg.payload.size();
  ++c.stats_.frames_sent;
  c.stats_.bytes_sent += plain.size();
  if (plain.capacity() > 64 * 1024) std::vector<std::byte>().swap(plain);  // one large frame
  if (sealed.capacity() > 64 * 1024) std::vector<std::byte>().swap(sealed);
  return true;
}

void Connection::begin_handshake() {
  if (role_ == ConnectionRole::client) {
    std::vector<std::byte> payload;
    Writer w(payload);
    w.str(local_pun_);
    if (!token_.empty()) w.str(token_);  // protocol 3.1: the optional credential
    send_control(FrameCode::connect, std::move(payload));
  }
  read_more();
}

std::string Connection::peer_certificate_name() const {
  std::lock_guard lock(info_mutex_);
  return peer_certificate_name_;
}

std::shared_ptr<const Principal> Connection::principal() const {
  std::lock_guard lock(info_mutex_);
  return principal_;
}

std::string Connection::peer_pun() const {
  std::lock_guard lock(info_mutex_);
  return peer_pun_;
}

std::string Connection::describe() const {
  const std::string pun = peer_pun();
  return pun.empty() ? remote_address_ : fmt::format("{} ({})", pun, remote_address_);
}

std::shared_ptr<Connection> Connection::connection() const {
  return std::const_pointer_cast<Connection>(shared_from_this());
}

std::size_t Connection::queued_bytes() const {
  std::lock_guard lock(send_mutex_);
  return queued_bytes_;
}

ConnectionStats Connection::stats() const {
  std::lock_guard lock(send_mutex_);
  return stats_;
}

// --- Sending -------------------------------------------------------------------------------

void Connection::send(std::vector<std::byte> message, SendHandler on_sent, bool in_order) {
  std::unique_lock lock(send_mutex_);
  if (!send_open_ || state_.load() != State::open) {
    throw Error(ErrorKind::disconnected, fmt::format("connection to {} is not open", remote_address_));
  }
  if (peer_hung_up_unread()) {
    throw Error(ErrorKind::disconnected,
                fmt::format("{} closed the connection while nothing was heard from it for over "
                            "{} ms (this process did not run meanwhile)",
                            remote_address_, options_.heartbeat_timeout.count()));
  }
  if (message.size() > options_.max_message_size) {
    throw Error(ErrorKind::overloaded,
                fmt::format("message of {} bytes exceeds max_message_size ({} bytes)",
                            message.size(), options_.max_message_size));
  }
  if (queued_bytes_ + message.size() > options_.send_queue_limit) {
    throw Error(ErrorKind::overloaded,
                fmt::format("send queue to {} is full ({} bytes queued, limit {}): the peer is not "
                            "reading fast enough; retry later",
                            remote_address_, queued_bytes_, options_.send_queue_limit));
  }
  detail::OutgoingMessage msg;
  msg.msg_no = next_msg_no_++;
  if (next_msg_no_ == 0) next_msg_no_ = 1;
  msg.payload = std::move(message);
  msg.on_sent = std::move(on_sent);
  msg.in_order = in_order;
  queued_bytes_ += msg.payload.size();
  ++stats_.messages_sent;
  link_.sent();  // before it can reach the receiver

  // Fast path: nothing queued and the message fits one frame, so write it straight from this
  // thread; the io thread is not woken at all when the kernel takes the whole frame. Not while
  // the io thread is handling what one read brought: the replies to a batch of requests then
  // leave together in one write after it.
  if (!writing_ && !handling_read_.load(std::memory_order_relaxed) && control_.empty() &&
      scheduler_->empty() &&
      msg.payload.size() <= kMaxFramePayload && !msg.on_sent && try_direct_send_locked(msg)) {
    // Written, but into a link the peer had closed while this process did not run (it stopped
    // between the check above and the write): the message is lost, and the caller is told.
    if (peer_hung_up_unread()) {
      throw Error(ErrorKind::disconnected,
                  fmt::format("{} had closed the connection (nothing heard from it for over {} "
                              "ms): the message was not received",
                              remote_address_, options_.heartbeat_timeout.count()));
    }
    return;
  }
  scheduler_->add(std::move(msg));
  schedule_write_locked();
}

bool Connection::try_direct_send_locked(detail::OutgoingMessage& msg) {
  FrameHeader h;
  h.length = static_cast<std::uint32_t>(kFrameHeaderSize + msg.payload.size());
  h.msg_no = msg.msg_no;
  h.frame_no = 0;
  h.final = true;
  h.code = FrameCode::data;
  auto header = encode_header(h);
  if (tls_) return tls_->direct_send(*this, header, msg);
  iovec iov[2] = {{header.data(), header.size()}, {msg.payload.data(), msg.payload.size()}};
  msghdr mh{};
  mh.msg_iov = iov;
  mh.msg_iovlen = msg.payload.empty() ? 1 : 2;
  const ssize_t n = ::sendmsg(socket_.native_handle(), &mh, MSG_DONTWAIT | MSG_NOSIGNAL);
  const std::size_t total = h.length;
  const std::size_t written = n > 0 ? static_cast<std::size_t>(n) : 0;
  if (written == 0) return false;  // let the io thread handle EAGAIN and errors
  queued_bytes_ -= msg.payload.size();
  ++stats_.frames_sent;
  stats_.bytes_sent += written;
  if (written < total) {
    // The kernel took part of the frame: the rest goes out first, before any other frame.
    std::vector<std::byte> rest(total - written);
    const std::size_t from_header = written < kFrameHeaderSize ? kFrameHeaderSize - written : 0;
    if (from_header) std::memcpy(rest.data(), header.data() + written, from_header);
    const std::size_t payload_from = written < kFrameHeaderSize ? 0 : written - kFrameHeaderSize;
    std::memcpy(rest.data() + from_header, msg.payload.data() + payload_from,
                msg.payload.size() - payload_from);
    --stats_.frames_sent;  // the rest counts as the frame when written
    control_.push_front(std::move(rest));
    schedule_write_locked();
  }
  return true;
}

void Connection::send_control(FrameCode code, std::vector<std::byte> payload, std::uint32_t msg_no) {
  FrameHeader h;
  h.length = static_cast<std::uint32_t>(kFrameHeaderSize + payload.size());
  h.msg_no = msg_no;
  h.code = code;
  std::lock_guard lock(send_mutex_);
  if (!send_open_) return;
  if (control_.size() >= kMaxQueuedControlFrames) {
    send_open_ = false;
    asio::post(socket_.get_executor(), [self = shared_from_this()] {
      self->fail(ErrorKind::overloaded,
                 fmt::format("{} does not read: {} control frames queued", self->describe(),
                             kMaxQueuedControlFrames));
    });
    return;
  }
  control_.push_back(frame_bytes(h, payload));
  schedule_write_locked();
}

void Connection::schedule_write_locked() {
  if (writing_) return;
  writing_ = true;
  asio::post(socket_.get_executor(), [self = shared_from_this()] { self->write_batch(); });
}

void Connection::write_batch() {
  std::unique_lock lock(send_mutex_);
  batch_.clear();
  batch_headers_.clear();
  batch_payload_bytes_ = 0;
  batch_frames_ = 0;
  std::size_t bytes = 0;
  if (!send_open_) {
    writing_ = false;
    return;
  }
  // Control frames (handshake, heartbeats, acks) go first: they are small and time-critical.
  while (!control_.empty() && batch_frames_ < kMaxBatchFrames) {
    batch_control_.push_back(std::move(control_.front()));
    control_.pop_front();
    batch_.emplace_back(asio::buffer(batch_control_.back()));
    bytes += batch_control_.back().size();
    ++batch_frames_;
  }
  // Then the data frames, as the scheduler picks them: one from each message with credit in turn.
  batch_frames_picked_.clear();
  if (bytes < kMaxBatchBytes && batch_frames_ < kMaxBatchFrames) {
    bytes += scheduler_->next_frames(kMaxBatchBytes - bytes, kMaxBatchFrames - batch_frames_,
                                     std::chrono::steady_clock::now(), batch_frames_picked_, batch_done_, retired_);
  }
  for (const auto& frame : batch_frames_picked_) {
    batch_headers_.push_back(encode_header(frame.header));
    batch_.emplace_back(asio::buffer(batch_headers_.back()));
    if (!frame.payload.empty()) batch_.emplace_back(asio::buffer(frame.payload.data(), frame.payload.size()));
    batch_payload_bytes_ += frame.payload.size();
    ++batch_frames_;
  }
  if (batch_.empty() && !(tls_ && tls_->has_pending())) {
    writing_ = false;
    return;
  }
  write_started_ = std::chrono::steady_clock::now();
  lock.unlock();
  auto on_done = [self = shared_from_this()](const std::error_code& ec, std::size_t n) {
    self->on_written(ec, n);
  };
  if (!tls_) {
    asio::async_write(socket_, batch_, std::move(on_done));
    return;
  }
  // Sealed after what the engine produced before (a direct send's rest, an answer to the
  // peer), in the order it was produced.
  std::string failure;
  {
    std::lock_guard engine(tls_->engine);
    tls_->writing.clear();
    tls_->writing.swap(tls_->pending);
    tls_->writing_plain = asio::buffer_size(batch_);
    if (batch_.size() == 1) {  // one buffer (a control frame, the rest of a frame): as it is
      const auto& b = batch_.front();
      if (!tls_->seal({static_cast<const std::byte*>(b.data()), b.size()}, tls_->writing)) failure = tls_->error;
    } else if (!batch_.empty()) {
      // Gathered into one buffer: sealed buffer by buffer, a record per 9-byte header would
      // cost more than this copy.
      tls_->gathered.resize(tls_->writing_plain);
      asio::buffer_copy(asio::buffer(tls_->gathered), batch_);
      if (!tls_->seal(tls_->gathered, tls_->writing)) failure = tls_->error;
    }
  }
  if (!failure.empty()) {  // fails the batch's messages and the connection
    log_->warn("TLS error on the link to {}: {}", describe(), failure);
    on_written(std::make_error_code(std::errc::protocol_error), 0);
    return;
  }
  asio::async_write(socket_, asio::buffer(tls_->writing),
                    [self = shared_from_this()](const std::error_code& ec, std::size_t) {
                      self->on_written(ec, self->tls_->writing_plain);
                    });
}

void Connection::on_written(const std::error_code& ec, std::size_t n) {
  std::vector<detail::OutgoingMessage> done;
  {
    std::lock_guard lock(send_mutex_);
    done.swap(batch_done_);
    write_started_.reset();
    batch_control_.clear();
    retired_.clear();
    if (!ec) {
      queued_bytes_ -= std::min(queued_bytes_, batch_payload_bytes_);
      stats_.frames_sent += batch_frames_;
      stats_.bytes_sent += n;
    }
  }
  if (ec) {
    {
      std::lock_guard lock(send_mutex_);
      writing_ = false;
    }
    for (auto& m : done) {
      if (m.on_sent) m.on_sent(std::make_exception_ptr(Error(ErrorKind::disconnected, "write failed")));
    }
    fail(ErrorKind::disconnected, fmt::format("write to {} failed: {}", describe(), ec.message()));
    return;
  }
  for (auto& m : done) {
    if (m.on_sent) m.on_sent(nullptr);
    detail::give_buffer(std::move(m.payload));  // a large message's memory serves the next one
  }
  write_batch();
  if (close_after_flush_) {
    std::unique_lock lock(send_mutex_);
    if (!writing_) {
      lock.unlock();
      finish_close();
    }
  }
}

// --- Receiving -----------------------------------------------------------------------------

void Connection::read_more() {
  if (state_.load() == State::closed || close_after_flush_) return;
  compact_when_full(rbuf_.get(), rbegin_, rend_);
  if (tls_ && tls_->holds_input()) {  // records the engine has not decrypted yet: no waiting
    asio::post(socket_.get_executor(), [self = shared_from_this()] { self->resume_reading(); });
    return;
  }
  // Wait until the socket has bytes (a peek reads nothing), then read them under read_mutex_,
  // so that the io thread and a direct reader never both take from the stream.
  if (peek_armed_) return;
  peek_armed_ = true;
  socket_.async_receive(asio::buffer(&peek_byte_, 1), asio::socket_base::message_peek,
                        [self = shared_from_this()](const std::error_code& ec, std::size_t) {
                          self->peek_armed_ = false;
                          self->on_readable(ec);
                        });
}

void Connection::on_readable(const std::error_code& ec) {
  if (state_.load() == State::closed) return;
  std::unique_lock lock(read_mutex_);
  if (direct_reader_) {  // a caller reads for now; it hands the socket back (resume_reading)
    io_parked_ = true;
    return;
  }
  if (ec) {
    if (ec != asio::error::operation_aborted) handle_buffered(false);  // what came before the end
    on_read(ec, 0);
    return;
  }
  read_available();
}

void Connection::read_available() {
  compact_when_full(rbuf_.get(), rbegin_, rend_);
  const ssize_t n = tls_ ? tls_->read(*this)
                        : ::recv(socket_.native_handle(), rbuf_.get() + rend_, kReadBufferSize - rend_,
                                 MSG_DONTWAIT);
  if (n > 0) {
    on_read({}, static_cast<std::size_t>(n));
  } else if (n == 0) {
    handle_buffered(false);  // what a direct reader left, before the end
    on_read(asio::error::make_error_code(asio::error::eof), 0);
  } else if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) {
    if (rbegin_ != rend_) {
      handle_buffered();  // what a direct reader left
    } else {
      read_more();  // a direct reader took what there was
    }
  } else if (tls_ && errno == EPROTO) {
    handle_buffered(false);  // what was decrypted before
    std::string why;
    {
      std::lock_guard lock(tls_->engine);
      why = tls_->error;
    }
    fail(ErrorKind::bad_data, fmt::format("TLS error from {}: {}", describe(), why));
  } else {
    on_read(std::error_code(errno, std::system_category()), 0);
  }
}

void Connection::resume_reading() {
  if (state_.load() == State::closed) return;
  std::unique_lock lock(read_mutex_);
  if (direct_reader_) {
    io_parked_ = true;
    return;
  }
  if (rbegin_ == rend_ && !(tls_ && tls_->holds_input())) {
    // A direct reader took all there was (its reply): wait for the socket again, without a
    // read that would find nothing while the next caller wants the socket.
    read_more();
    return;
  }
  read_available();
}

void Connection::note_received(std::size_t n) {
  const auto now = std::chrono::steady_clock::now();
  if (now - last_received_.load(std::memory_order_relaxed) >= options_.heartbeat_timeout) {
    // Bytes after a silence this long may be old news (this process did not run): until a
    // heartbeat timeout has passed, senders check that the peer has not hung up meanwhile.
    suspect_until_.store(now + options_.heartbeat_timeout, std::memory_order_relaxed);
  }
  last_received_.store(now, std::memory_order_relaxed);
  std::lock_guard lock(send_mutex_);
  stats_.bytes_received += n;
}

void Connection::on_read(const std::error_code& ec, std::size_t n) {
  if (state_.load() == State::closed) return;
  if (ec) {
    const bool closed = ec == asio::error::eof;
    fail(ErrorKind::disconnected, closed ? fmt::format("{} closed the connection", describe())
                                      : fmt::format("read from {} failed: {}", describe(),
                                                    ec.message()));
    return;
  }
  rend_ += n;
  note_received(n);
  handle_buffered();
}

void Connection::handle_buffered(bool read_next) {
  handling_read_ = true;
  struct HandlingRead {
    std::atomic<bool>& flag;
    ~HandlingRead() { flag = false; }
  } handling{handling_read_};
  bool completed_frame = false;
  while (state_.load() != State::closed && !close_after_flush_) {
    const std::span<const std::byte> avail(rbuf_.get() + rbegin_, rend_ - rbegin_);
    const HeaderParse parsed = parse_header(avail);
    if (!parsed.error.empty()) {
      if (parsed.version_mismatch && role_ == ConnectionRole::server &&
          state_.load() == State::handshaking) {
        std::vector<std::byte> payload;
        Writer w(payload);
        w.u8(kConnectDeny);
        w.str(parsed.error.substr(0, kMaxControlPayload - 16));
        send_control(FrameCode::connect_ack, std::move(payload));
        log_denial(remote_address_, parsed.error);
        close_after_flush_ = true;
        return;
      }
      fail(ErrorKind::bad_data, fmt::format("protocol error from {}: {}", describe(), parsed.error));
      return;
    }
    if (!parsed.header || avail.size() < parsed.header->length) break;
    const FrameHeader& h = *parsed.header;
    if (!handle_frame(h, avail.subspan(kFrameHeaderSize, h.payload_size()))) return;
    rbegin_ += h.length;
    completed_frame = true;
  }
  // A frame started must complete within message_progress_timeout (checked in on_timer): bytes
  // trickling in never make a frame, but keep the heartbeat timeout from firing.
  if (rbegin_ == rend_) {
    rbegin_ = rend_ = 0;
    partial_frame_since_.reset();
  } else if (completed_frame || !partial_frame_since_) {
    partial_frame_since_ = last_received_.load(std::memory_order_relaxed);
  }
  if (read_next) read_more();
}

bool Connection::read_directly(std::chrono::steady_clock::time_point until,
                               const std::function<bool()>& answered,
                               const std::function<bool(std::span<const std::byte>)>& take) {
  if (options_.activity) return false;
  {
    std::unique_lock lock(read_mutex_, std::try_to_lock);
    if (!lock || direct_reader_ || read_closed_ || state_.load() != State::open ||
        close_after_flush_ || rbegin_ != rend_ || incoming_count_.load() != 0 || answered() ||
        (tls_ && tls_->holds_input())) {
      return false;
    }
    // Large messages on their way out wait for the peer's acks: those are read by the io
    // thread, which writes on as soon as they come.
    std::lock_guard send_lock(send_mutex_);
    if (!scheduler_->empty()) return false;
    direct_reader_ = true;
  }
  bool taken = false;
  bool handed_over = false;
  while (!taken && !handed_over) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= until || answered()) break;
    // In slices, so that a call completed elsewhere (cancelled, its connection failed) is seen.
    const auto slice =
        std::min<std::chrono::steady_clock::duration>(until - now, std::chrono::milliseconds(50));
    pollfd p{};
    p.fd = socket_.native_handle();
    p.events = POLLIN;
    const int ready = ::poll(&p, 1, static_cast<int>(std::chrono::ceil<std::chrono::milliseconds>(slice).count()));
    if (ready < 0 && errno != EINTR) break;
    if (ready <= 0) continue;
    std::lock_guard lock(read_mutex_);
    if (read_closed_ || state_.load() != State::open) break;
    const ssize_t n = tls_ ? tls_->read(*this)
                          : ::recv(socket_.native_handle(), rbuf_.get() + rend_, kReadBufferSize - rend_,
                                   MSG_DONTWAIT);
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) continue;
    handed_over = true;  // unless the first frame is the message `take` waits for
    if (n <= 0) break;   // the end of the stream, or an error: the io thread reports it
    rend_ += static_cast<std::size_t>(n);
    note_received(static_cast<std::size_t>(n));
    const std::span<const std::byte> avail(rbuf_.get() + rbegin_, rend_ - rbegin_);
    const HeaderParse parsed = parse_header(avail);
    if (!parsed.error.empty() || !parsed.header || avail.size() < parsed.header->length) break;
    const FrameHeader& h = *parsed.header;
    if (h.code != FrameCode::data || h.frame_no != 0 || !h.final ||
        h.payload_size() > options_.max_message_size) {
      break;
    }
    if (take(avail.subspan(kFrameHeaderSize, h.payload_size()))) {
      rbegin_ += h.length;
      if (rbegin_ == rend_) rbegin_ = rend_ = 0;
      {
        std::lock_guard stats(send_mutex_);
        ++stats_.frames_received;
        ++stats_.messages_received;
        ++stats_.messages_read_by_callers;
      }
      taken = true;
      handed_over = false;
    }
  }
  // The socket goes back to the io thread, with whatever was read and not taken.
  std::lock_guard lock(read_mutex_);
  direct_reader_ = false;
  if (io_parked_ || rbegin_ != rend_ || (tls_ && tls_->holds_input())) {
    io_parked_ = false;
    asio::post(socket_.get_executor(), [self = shared_from_this()] { self->resume_reading(); });
  }
  return taken;
}

bool Connection::handle_frame(const FrameHeader& h, std::span<const std::byte> payload) {
  {
    std::lock_guard lock(send_mutex_);
    ++stats_.frames_received;
  }
  if (state_.load() == State::handshaking) {
    const FrameCode expected =
        role_ == ConnectionRole::server ? FrameCode::connect : FrameCode::connect_ack;
    if (h.code != expected) {
      fail(ErrorKind::bad_data, fmt::format("protocol error from {}: expected {}, got {}",
                                            remote_address_, to_string(expected), to_string(h.code)));
      return false;
    }
    return h.code == FrameCode::connect ? handle_connect(h, payload) : handle_connect_ack(payload);
  }
  switch (h.code) {
    case FrameCode::heartbeat:
      send_control(FrameCode::heartbeat_ack, {});
      return true;
    case FrameCode::heartbeat_ack:
      return true;
    case FrameCode::data:
      return handle_data(h, payload);
    case FrameCode::data_ack:
      return handle_data_ack(payload);
    case FrameCode::connect:
    case FrameCode::connect_ack:
      break;
  }
  fail(ErrorKind::bad_data, fmt::format("protocol error from {}: unexpected {} on an open connection",
                                        describe(), to_string(h.code)));
  return false;
}

bool Connection::handle_connect(const FrameHeader& h, std::span<const std::byte> payload) {
  ConnectRequest request;
  try {
    Reader r(payload);
    request.pun = r.str();
    if (r.remaining() != 0) request.token = r.str();  // protocol 3.1: the optional credential
    if (r.remaining() != 0) r.fail("trailing bytes after the token");
  } catch (const Error& e) {
    fail(ErrorKind::bad_data, fmt::format("malformed CONNECT from {}: {}", remote_address_, e.what()));
    return false;
  }
  request.remote_address = remote_address_;
  request.remote_ip = remote_ip_;
  request.certificate_name = peer_certificate_name();
  if (h.version_minor > kProtocolMinor) {
    log_->debug("{} speaks {}.{}; answering as {}.{}", remote_address_, h.version_major,
                h.version_minor, kProtocolMajor, kProtocolMinor);
  }
  Admission admission;
  if (acceptor_) admission = acceptor_(request);
  std::optional<std::string>& deny = admission.deny;
  const std::string& pun = request.pun;
  if (deny && deny->size() > kMaxControlPayload - 16) deny->resize(kMaxControlPayload - 16);
  std::vector<std::byte> reply;
  Writer w(reply);
  if (deny) {
    w.u8(kConnectDeny);
    w.str(*deny);
    send_control(FrameCode::connect_ack, std::move(reply));
    log_denial(fmt::format("{} ({})", pun, remote_address_), *deny);
    close_after_flush_ = true;
    return false;
  }
  w.u8(kConnectAccept);
  w.str(local_pun_);
  {
    std::lock_guard lock(info_mutex_);
    peer_pun_ = pun;
    principal_ = std::move(admission.principal);
  }
  send_control(FrameCode::connect_ack, std::move(reply));
  state_ = State::open;
  was_open_ = true;
  arm_timer();
  handler_.on_open(shared_from_this());
  return state_.load() != State::closed;
}

bool Connection::handle_connect_ack(std::span<const std::byte> payload) {
  std::uint8_t status = 0;
  std::string text;
  try {
    Reader r(payload);
    status = r.u8();
    text = r.str();
    if (r.remaining() != 0) r.fail("trailing bytes in CONNECT_ACK");
    if (status != kConnectAccept && status != kConnectDeny) {
      r.fail(fmt::format("unknown CONNECT_ACK status 0x{:02X}", status));
    }
  } catch (const Error& e) {
    fail(ErrorKind::bad_data, fmt::format("malformed CONNECT_ACK from {}: {}", remote_address_, e.what()));
    return false;
  }
  if (status == kConnectDeny) {
    fail(ErrorKind::refused, fmt::format("{} denied the connection: {}", remote_address_, text));
    return false;
  }
  {
    std::lock_guard lock(info_mutex_);
    peer_pun_ = std::move(text);
  }
  state_ = State::open;
  was_open_ = true;
  arm_timer();
  handler_.on_open(shared_from_this());
  return state_.load() != State::closed;
}

bool Connection::handle_data(const FrameHeader& h, std::span<const std::byte> payload) {
  auto it = std::find_if(incoming_.begin(), incoming_.end(),
                         [&](const auto& in) { return in->msg_no == h.msg_no; });
  detail::IncomingMessage* in = it == incoming_.end() ? nullptr : it->get();
  auto protocol_error = [&](const std::string& what) {
    fail(ErrorKind::bad_data, fmt::format("protocol error from {}: {}", describe(), what));
    return false;
  };
  const auto now = std::chrono::steady_clock::now();

  if (h.frame_no == 0) {
    if (in) return protocol_error(fmt::format("message #{} started twice", h.msg_no));
    if (h.final && payload.size() > options_.max_message_size) {
      return protocol_error(fmt::format("message #{} of {} bytes exceeds max_message_size ({})",
                                        h.msg_no, payload.size(), options_.max_message_size));
    }
    if (h.final) {  // the common case: a whole message in one frame, delivered without copying
      {
        std::lock_guard lock(send_mutex_);
        ++stats_.messages_received;
      }
      handler_.on_message(shared_from_this(), payload);
      link_.handled();
      return state_.load() != State::closed;
    }
    if (incoming_.size() >= options_.max_incomplete_messages) {
      return protocol_error(fmt::format("more than {} interleaved incomplete messages",
                                        options_.max_incomplete_messages));
    }
    incoming_.push_back(std::make_unique<detail::IncomingMessage>());
    incoming_count_.store(incoming_.size());
    in = incoming_.back().get();
    in->msg_no = h.msg_no;
    in->last_progress = now;
    spare_used_ = true;
    it = std::prev(incoming_.end());
    // The sender may send a whole window without an ack: reserve it in the budget of all
    // connections, or refuse the message while the budget is spent (one message at a time may
    // exceed it, so that something always completes and frees room).
    detail::ReceiveBudget& budget = limits_->receive;
    if (!budget.fits(std::size_t{kWindowFrames} * kMaxFramePayload) && !budget.claim(id_, h.msg_no)) {
      in->next_frame = 1;
      in->refused = true;
      send_data_ack(h.msg_no, AckCode::no_more);
      const std::string reason = fmt::format(
          "message #{} from {} refused: the receive budget of all connections "
          "(total_receive_budget, {} bytes) is spent; retry later",
          h.msg_no, describe(), budget.limit());
      if (auto held = limits_->refusals.admit(remote_ip_)) log_->warn("{}{}", reason, held_back(*held));
      handler_.on_message_refused(shared_from_this(), payload, reason);
      link_.handled();
      return state_.load() != State::closed;
    }
  } else if (!in) {
    return protocol_error(fmt::format("frame #{} of unknown message #{}", h.frame_no, h.msg_no));
  }
  if (auto misfit = in->misfit(h)) return protocol_error(*misfit);  // out of order, beyond the window
  ++in->next_frame;
  in->last_progress = now;
  if (in->refused) {  // frames already in flight when we said NO_MORE
    if (h.final) incoming_.erase(it);
    incoming_count_.store(incoming_.size());
    return true;
  }
  if (in->size + payload.size() > options_.max_message_size) {
    const std::string reason =
        fmt::format("message #{} from {} exceeds max_message_size ({} bytes); refused", h.msg_no,
                    describe(), options_.max_message_size);
    log_->warn("{}", reason);
    send_data_ack(h.msg_no, AckCode::no_more);
    in->refused = true;
    incomplete_bytes_ -= in->size;
    forget_incoming(*in);
    // The first block holds the first frame, which names the request to answer.
    const std::vector<std::byte> received =
        in->blocks.empty() ? std::vector<std::byte>{} : std::move(in->blocks.front());
    in->blocks = {};
    in->size = 0;
    if (h.final) incoming_.erase(it);
    incoming_count_.store(incoming_.size());
    handler_.on_message_refused(shared_from_this(), received, reason);
    link_.handled();
    if (state_.load() == State::closed) return false;
    release_deferred_acks();
    return true;
  }
  in->append(payload, spare_);
  incomplete_bytes_ += payload.size();
  if (h.final) {
    std::vector<std::vector<std::byte>> blocks = std::move(in->blocks);
    incomplete_bytes_ -= in->size;
    forget_incoming(*in);
    incoming_.erase(it);
    incoming_count_.store(incoming_.size());
    {
      std::lock_guard lock(send_mutex_);
      ++stats_.messages_received;
    }
    if (blocks.size() <= 1) {
      std::vector<std::byte> message = blocks.empty() ? std::vector<std::byte>{} : std::move(blocks[0]);
      handler_.on_message(shared_from_this(), message);
      if (message.capacity() > spare_.capacity()) spare_ = std::move(message);
    } else {
      handler_.on_large_message(shared_from_this(), std::move(blocks));
    }
    link_.handled();
    if (state_.load() == State::closed) return false;
    release_deferred_acks();
    return true;
  }
  update_reservation(*in);
  // Keep the sender kGrantAheadFrames beyond what has arrived (docs/protocol.md 5.3: a receiver
  // may send MORE at any time), so a large message streams at the link's speed rather than
  // waiting for an ack every 64 KiB; the receive budgets still hold acks back.
  if (const auto acks = in->acks_to_owe(); acks > 0) {
    in->owed_acks += acks;
    release_deferred_acks();
  }
  return true;
}

// What a message may still make the receiver hold: what arrived plus the credit not yet used.
void Connection::update_reservation(detail::IncomingMessage& in) {
  const std::size_t now_reserved = in.holding();
  if (now_reserved > in.reserved) {
    limits_->receive.add(now_reserved - in.reserved);
  } else {
    limits_->receive.remove(in.reserved - now_reserved);
  }
  in.reserved = now_reserved;
}

// The message completed, was refused or is dropped with the connection.
void Connection::forget_incoming(detail::IncomingMessage& in) {
  limits_->receive.remove(std::exchange(in.reserved, 0));
  limits_->receive.release(id_, in.msg_no);
}

// Sends the acks that the receive budgets allow, oldest message first. The oldest incomplete
// message of a connection proceeds within the budget of all connections, and one message at a
// time (the privileged one) beyond it, so messages can never wait on each other for ever.
void Connection::release_deferred_acks() {
  detail::ReceiveBudget& budget = limits_->receive;
  bool oldest = true;
  bool blocked = false;
  for (const auto& entry : incoming_) {
    detail::IncomingMessage& in = *entry;
    if (in.refused) continue;
    const bool first = oldest;
    oldest = false;
    while (in.owed_acks > 0) {
      bool allowed = budget.is_privileged(id_, in.msg_no);
      if (!allowed && (first || incomplete_bytes_.load() <= options_.receive_budget)) {
        allowed = budget.fits(kAckBytes) || (first && budget.claim(id_, in.msg_no));
        blocked = blocked || !allowed;
      }
      if (!allowed) break;
      in.grant_one(std::chrono::steady_clock::now());
      update_reservation(in);
      send_data_ack(in.msg_no, AckCode::more);
    }
  }
  if (blocked && !waiting_for_budget_) {
    // Woken when another connection's message frees room (and by on_timer in any case).
    waiting_for_budget_ = true;
    budget.wait([weak = weak_from_this()] {
      auto self = weak.lock();
      if (!self) return;
      asio::post(self->socket_.get_executor(), [self] {
        self->waiting_for_budget_ = false;
        if (self->state_.load() == State::open) self->release_deferred_acks();
      });
    });
  }
}

void Connection::send_data_ack(std::uint32_t msg_no, AckCode code) {
  std::vector<std::byte> ack;
  Writer w(ack);
  w.u32(msg_no);
  w.u32(static_cast<std::uint32_t>(code));
  send_control(FrameCode::data_ack, std::move(ack), msg_no);
}

bool Connection::handle_data_ack(std::span<const std::byte> payload) {
  std::uint32_t msg_no = 0;
  std::uint32_t code = 0;
  try {
    Reader r(payload);
    msg_no = r.u32();
    code = r.u32();
    if (r.remaining() != 0) r.fail("trailing bytes in DATA_ACK");
    if (code != static_cast<std::uint32_t>(AckCode::more) &&
        code != static_cast<std::uint32_t>(AckCode::no_more)) {
      r.fail(fmt::format("unknown DATA_ACK control code 0x{:02X}", code));
    }
  } catch (const Error& e) {
    fail(ErrorKind::bad_data, fmt::format("malformed DATA_ACK from {}: {}", describe(), e.what()));
    return false;
  }
  SendHandler refused_handler;
  bool refused = false;
  {
    std::lock_guard lock(send_mutex_);
    if (code == static_cast<std::uint32_t>(AckCode::more)) {
      if (scheduler_->grant(msg_no)) schedule_write_locked();
      return true;  // or already fully written
    }
    auto refusal = scheduler_->refuse(msg_no);
    if (!refusal) return true;  // already fully written, or refused before
    // The message ends with an empty final frame, so the receiver can forget it.
    refused = true;
    queued_bytes_ -= std::min(queued_bytes_, refusal->unsent_bytes);
    refused_handler = std::move(refusal->on_sent);
    schedule_write_locked();
  }
  if (refused) {
    // NO_MORE: larger than the peer's max_message_size, or beyond its receive budget.
    log_->warn("{} refused message #{} (too large for its max_message_size, or its receive "
               "budget is spent)", describe(), msg_no);
    if (refused_handler) {
      refused_handler(std::make_exception_ptr(
          Error(ErrorKind::overloaded,
                fmt::format("{} refused message #{}: larger than its max_message_size, or its "
                            "receive budget is spent (retry later)",
                            describe(), msg_no))));
    }
  }
  return true;
}

// --- Timers and closing --------------------------------------------------------------------

std::size_t Connection::unread_bytes() {
  int n = 0;
  if (::ioctl(socket_.native_handle(), FIONREAD, &n) != 0 || n < 0) return 0;
  return static_cast<std::size_t>(n);
}

bool Connection::peer_hung_up_unread() {
  // Cheap while the peer is heard from (its heartbeats come every heartbeat_interval).
  const auto now = std::chrono::steady_clock::now();
  if (now - last_received_.load(std::memory_order_relaxed) < options_.heartbeat_timeout &&
      now >= suspect_until_.load(std::memory_order_relaxed)) {
    return false;
  }
  pollfd p{};
  p.fd = socket_.native_handle();
  p.events = POLLRDHUP;
  return ::poll(&p, 1, 0) == 1 && (p.revents & (POLLRDHUP | POLLHUP | POLLERR)) != 0;
}

void Connection::arm_timer() {
  const auto delay = state_.load() == State::handshaking
                         ? options_.handshake_timeout
                         : std::chrono::milliseconds(options_.heartbeat_interval);
  timer_.expires_after(delay);
  timer_.async_wait([weak = weak_from_this()](const std::error_code& ec) {
    if (ec) return;
    if (auto self = weak.lock()) self->on_timer();
  });
}

void Connection::on_timer() {
  const auto now = std::chrono::steady_clock::now();
  switch (state_.load()) {
    case State::closed:
      return;
    case State::handshaking:
      if (now - opened_at_ >= options_.handshake_timeout) {
        fail(ErrorKind::disconnected,
             fmt::format("handshake with {} timed out: no {} within {} ms", remote_address_,
                         role_ == ConnectionRole::server ? "CONNECT" : "CONNECT_ACK",
                         options_.handshake_timeout.count()));
        return;
      }
      break;
    case State::open: {
      const auto silent = std::chrono::duration_cast<std::chrono::milliseconds>(
          now - last_received_.load(std::memory_order_relaxed));
      if (silent < options_.heartbeat_timeout) {
        late_read_grace_ = false;
      } else if (!late_read_grace_ && unread_bytes() > 0) {
        // Not silence: the peer's bytes wait in the socket because this process did not run
        // (stopped, or starved). They are read first; what they say decides.
        late_read_grace_ = true;
      } else {
        fail(ErrorKind::disconnected,
             fmt::format("heartbeat timeout: nothing heard from {} for {} ms", describe(),
                         silent.count()));
        return;
      }
      if (!check_progress(now)) return;
      // A reassembly buffer unused for a whole heartbeat interval goes back to the allocator.
      if (!spare_used_) spare_ = {};
      spare_used_ = false;
      send_control(FrameCode::heartbeat, {});
      release_deferred_acks();  // in case a wake-up from the receive budget was missed
      break;
    }
  }
  arm_timer();
}

void Connection::close(const std::string& reason) {
  {
    std::lock_guard lock(send_mutex_);
    send_open_ = false;
  }
  asio::post(socket_.get_executor(), [self = shared_from_this(), reason] {
    self->fail(ErrorKind::disconnected, fmt::format("closed locally: {}", reason));
  });
}

// False (and the connection closed) if a message in flight made no progress for
// message_progress_timeout: a frame started and not finished, an incoming message with credit
// and no frame, an outgoing one without credit, or a write the peer does not drain.
bool Connection::check_progress(std::chrono::steady_clock::time_point now) {
  const auto limit = options_.message_progress_timeout;
  std::string stalled;
  if (partial_frame_since_ && now - *partial_frame_since_ >= limit) {
    stalled = fmt::format("a frame from {} has been incomplete for {} ms", describe(),
                          ms(now - *partial_frame_since_));
  }
  for (const auto& in : incoming_) {
    if (!stalled.empty()) break;
    if (in->stalled(now, limit)) {
      stalled = fmt::format(
          "message #{} from {} has received no frame for {} ms although {} more were granted",
          in->msg_no, describe(), ms(now - in->last_progress), in->granted - in->next_frame);
    }
  }
  if (stalled.empty()) {
    std::lock_guard lock(send_mutex_);
    if (const auto* m = scheduler_->starved(now, limit)) {
      stalled = fmt::format(
          "message #{} to {} has waited {} ms for flow-control credit (DATA_ACK) after frame #{}",
          m->msg_no, describe(), ms(now - *m->starved_since), m->next_frame - 1);
    }
    if (stalled.empty() && write_started_ && now - *write_started_ >= limit) {
      stalled = fmt::format("a write to {} has not completed for {} ms: the peer does not read",
                            describe(), ms(now - *write_started_));
    }
  }
  if (stalled.empty()) return true;
  fail(ErrorKind::disconnected,
       fmt::format("{} (message_progress_timeout {} ms)", stalled, limit.count()));
  return false;
}

void Connection::log_denial(const std::string& who, const std::string& reason) {
  // A denied client may retry without end: at most one line a second per address.
  if (auto held = limits_->denials.admit(remote_ip_)) {
    log_->warn("denied {}: {}{}", who, reason, held_back(*held));
  }
}

void Connection::finish_close() {
  fail(ErrorKind::refused, fmt::format("connection from {} denied", remote_address_), true);
}

void Connection::fail(ErrorKind kind, const std::string& reason, bool quiet) {
  if (state_.exchange(State::closed) == State::closed) return;
  link_.close();  // what was on its way over this connection will never be handled
  if (quiet) {
    log_->debug("connection {} closed: {}", id_, reason);
  } else if (kind == ErrorKind::bad_data) {
    log_->warn("closing connection {}: {}", id_, reason);
  } else {
    log_->info("connection {} closed: {}", id_, reason);
  }
  std::vector<SendHandler> dropped;
  {
    std::lock_guard lock(send_mutex_);
    send_open_ = false;
    for (auto& m : scheduler_->take_all()) {
      ++stats_.messages_dropped;
      if (m.on_sent) dropped.push_back(std::move(m.on_sent));
      retired_.push_back(std::move(m));
    }
    control_.clear();
    queued_bytes_ = 0;
    if (!writing_) retired_.clear();
  }
  timer_.cancel();
  std::error_code ignored;
  socket_.shutdown(asio::ip::tcp::socket::shutdown_both, ignored);  // wakes a direct reader
  {
    std::lock_guard lock(read_mutex_);  // a direct reader never reads a closed (reused) socket
    read_closed_ = true;
    socket_.close(ignored);
  }
  for (auto& in : incoming_) forget_incoming(*in);
  incoming_.clear();
  incoming_count_.store(0);
  incomplete_bytes_ = 0;
  const Error error(ErrorKind::disconnected, reason);
  for (auto& h : dropped) h(std::make_exception_ptr(error));
  handler_.on_close(shared_from_this(), Error(kind, reason));
}

}  // namespace icars::planet
