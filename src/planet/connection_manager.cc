#include "icars/planet/connection_manager.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <sys/resource.h>

#include <algorithm>
#include <asio/connect.hpp>
#include <asio/post.hpp>
#include <asio/ssl/context.hpp>
#include <cerrno>
#include <future>
#include <limits>

#include "transport_limits.h"

namespace icars::planet {

struct ConnectionManager::Acceptor {
  explicit Acceptor(asio::io_context& io) : socket(io), retry(io) {}
  asio::ip::tcp::acceptor socket;
  // Accepting again at once when descriptors or memory ran out would fail again at once (the
  // pending connection stays queued): wait instead, 50 ms doubling to 1 s, until one succeeds.
  asio::steady_timer retry;
  std::chrono::milliseconds backoff{0};
  std::uint64_t failures_unreported = 0;
  std::chrono::steady_clock::time_point last_report;
  // Not accepting while the connections hold all the descriptors they may (io thread only).
  bool paused = false;
  std::uint64_t pauses_unreported = 0;
  std::chrono::steady_clock::time_point last_pause_report;
};

namespace {

// TLS 1.2 or later, in the role given, with this endpoint's certificate if it has one.
std::shared_ptr<asio::ssl::context> make_context(const TlsOptions& o, bool server) {
  auto context = std::make_shared<asio::ssl::context>(server ? asio::ssl::context::tls_server
                                                             : asio::ssl::context::tls_client);
  context->set_options(asio::ssl::context::default_workarounds | asio::ssl::context::no_sslv2 |
                       asio::ssl::context::no_sslv3 | asio::ssl::context::no_tlsv1 |
                       asio::ssl::context::no_tlsv1_1);
  const auto step = [](const char* what, const std::string& file, auto&& load) {
    std::error_code ec;
    load(ec);
    if (ec) {
      throw std::invalid_argument(fmt::format("tls.{} '{}': {}", what, file, ec.message()));
    }
  };
  if (!o.certificate_file.empty()) {
    step("certificate_file", o.certificate_file,
         [&](std::error_code& ec) { context->use_certificate_chain_file(o.certificate_file, ec); });
    step("private_key_file", o.private_key_file, [&](std::error_code& ec) {
      context->use_private_key_file(o.private_key_file, asio::ssl::context::pem, ec);
    });
  }
  if (!o.ca_file.empty()) {
    step("ca_file", o.ca_file, [&](std::error_code& ec) { context->load_verify_file(o.ca_file, ec); });
  } else if (!server) {
    context->set_default_verify_paths();
  }
  if (server) {
    if (o.require_client_certificate) {
      context->set_verify_mode(asio::ssl::verify_peer | asio::ssl::verify_fail_if_no_peer_cert);
    } else if (!o.ca_file.empty()) {
      context->set_verify_mode(asio::ssl::verify_peer);  // a client certificate, if sent, is checked
    }
  } else {
    context->set_verify_mode(asio::ssl::verify_peer);
  }
  return context;
}

constexpr std::chrono::milliseconds kAcceptBackoffFirst{50};
constexpr std::chrono::milliseconds kAcceptBackoffMax{1000};

// Failures of accept() that say the process (or the system) is out of a resource rather than
// that one pending connection went bad.
bool out_of_resources(const std::error_code& ec) {
  if (ec.category() != asio::error::get_system_category()) return false;
  const int e = ec.value();
  return e == EMFILE || e == ENFILE || e == ENOBUFS || e == ENOMEM;
}

// CONNECT (PUN and token) and CONNECT_ACK must each fit one control frame.
void check_connect_fits(const std::string& pun, const std::string& token) {
  const std::size_t room = kMaxControlPayload - 16 - (token.empty() ? 0 : 4 + token.size());
  if (pun.size() > room) {
    throw std::invalid_argument(fmt::format("PUN of {} bytes is longer than {}{}", pun.size(),
                                            room, token.empty() ? "" : " (with the token)"));
  }
}

}  // namespace

// --- Peer ----------------------------------------------------------------------------------

Peer::Peer(ConnectionManager& manager, std::string host, std::uint16_t port, ReconnectPolicy policy)
    : manager_(manager),
      io_(manager.shared_io()),
      host_(std::move(host)),
      port_(port),
      policy_(policy),
      tls_(manager.wants_tls(host_)),
      delay_(policy.initial_delay),
      resolver_(*io_),
      timer_(*io_) {}

std::shared_ptr<Connection> Peer::connection() const {
  std::lock_guard lock(mutex_);
  return current_;
}

std::string Peer::describe() const { return fmt::format("{}:{}", host_, port_); }

bool Peer::is_connected() const {
  std::lock_guard lock(mutex_);
  return current_ != nullptr;
}

bool Peer::wait_connected(std::chrono::milliseconds timeout) const {
  std::unique_lock lock(mutex_);
  return changed_.wait_for(lock, timeout, [&] { return current_ != nullptr || stopped_; }) &&
         current_ != nullptr;
}

std::uint64_t Peer::connect_count() const {
  std::lock_guard lock(mutex_);
  return connect_count_;
}

std::string Peer::last_error() const {
  std::lock_guard lock(mutex_);
  return last_error_;
}

void Peer::stop() {
  {
    std::lock_guard lock(mutex_);
    if (stopped_) return;
    stopped_ = true;
  }
  changed_.notify_all();
  if (io_->get_executor().running_in_this_thread()) {
    stop_on_io();
  } else {
    asio::post(*io_, [self = shared_from_this()] { self->stop_on_io(); });
  }
}

void Peer::stop_on_io() {
  timer_.cancel();
  resolver_.cancel();
  if (connecting_) {
    std::error_code ignored;
    connecting_->close(ignored);
  }
  std::shared_ptr<Connection> a;
  std::shared_ptr<Connection> b;
  {
    std::lock_guard lock(mutex_);
    a = current_;
    b = handshaking_;
  }
  if (a) a->close("peer stopped");
  if (b) b->close("peer stopped");
}

void Peer::attempt() {
  {
    std::lock_guard lock(mutex_);
    if (stopped_) return;
  }
  auto self = shared_from_this();
  resolver_.async_resolve(
      host_, std::to_string(port_),
      [self](const std::error_code& ec, const asio::ip::tcp::resolver::results_type& results) {
        if (ec) {
          self->retry_later(fmt::format("cannot resolve {}: {}", self->host_, ec.message()));
          return;
        }
        auto socket = std::make_shared<asio::ip::tcp::socket>(*self->io_);
        self->connecting_ = socket;
        self->timer_.expires_after(self->policy_.connect_timeout);
        self->timer_.async_wait([socket](const std::error_code& tec) {
          if (!tec) {
            std::error_code ignored;
            socket->close(ignored);
          }
        });
        asio::async_connect(
            *socket, results,
            [self, socket](const std::error_code& cec, const asio::ip::tcp::endpoint&) {
              self->timer_.cancel();
              self->connecting_.reset();
              if (cec) {
                self->retry_later(fmt::format("cannot connect to {}: {}", self->describe(),
                                              cec.message()));
                return;
              }
              {
                std::lock_guard lock(self->mutex_);
                if (self->stopped_) return;
              }
              auto connection =
                  self->manager_.adopt(std::move(*socket), ConnectionRole::client, self, self->tls_);
              std::lock_guard lock(self->mutex_);
              self->handshaking_ = connection;
            });
      });
}

void Peer::retry_later(const std::string& why, bool refused) {
  {
    std::lock_guard lock(mutex_);
    if (stopped_) return;
    last_error_ = why;
  }
  if (refused) delay_ = std::max(delay_, policy_.refused_delay);
  manager_.log().debug("{}; retrying in {} ms", why, delay_.count());
  timer_.expires_after(delay_);
  delay_ = std::min(refused ? policy_.refused_max_delay : policy_.max_delay, delay_ * 2);
  timer_.async_wait([self = shared_from_this()](const std::error_code& ec) {
    if (!ec) self->attempt();
  });
}

void Peer::on_open(const std::shared_ptr<Connection>& c) {
  bool reconnect = false;
  {
    std::lock_guard lock(mutex_);
    handshaking_.reset();
    current_ = c;
    reconnect = connect_count_++ > 0;
    delay_ = policy_.initial_delay;
  }
  changed_.notify_all();
  manager_.notify({reconnect ? LinkEventKind::reconnected : LinkEventKind::connected, c,
                   shared_from_this(), {}});
}

void Peer::on_close(const std::shared_ptr<Connection>& c, const Error& error) {
  const std::string reason = error.what();
  bool was_open = false;
  {
    std::lock_guard lock(mutex_);
    if (current_ == c) {
      current_.reset();
      was_open = true;
    }
    if (handshaking_ == c) handshaking_.reset();
    last_error_ = reason;
  }
  changed_.notify_all();
  if (was_open) {
    manager_.notify({LinkEventKind::disconnected, c, shared_from_this(), reason});
  }
  // A refusal during the handshake (CONNECT_ACK 0xFF, a failed TLS handshake) backs off longer.
  retry_later(reason, error.kind() == ErrorKind::refused && !c->was_open());
}

// --- ConnectionManager ---------------------------------------------------------------------

ConnectionManager::ConnectionManager(std::shared_ptr<asio::io_context> io, MessageHandler& upper,
                                     const ConnectionOptions& options,
                                     std::shared_ptr<spdlog::logger> logger)
    : io_(std::move(io)),
      upper_(upper),
      options_(options),
      log_(std::move(logger)),
      limits_(std::make_shared<detail::TransportLimits>(
          options.total_receive_budget, std::size_t{kAckEvery} * kMaxFramePayload)),
      connection_cap_(options.max_connections) {
  options_.validate();
  static std::once_flag raised;
  std::call_once(raised, [] { raise_descriptor_limit(); });
}

std::size_t raise_descriptor_limit() {
  rlimit limit{};
  if (::getrlimit(RLIMIT_NOFILE, &limit) != 0) return 0;
  if (limit.rlim_cur < limit.rlim_max) {
    rlimit raised = limit;
    raised.rlim_cur = limit.rlim_max;
    if (::setrlimit(RLIMIT_NOFILE, &raised) == 0) limit = raised;
  }
  return limit.rlim_cur == RLIM_INFINITY ? std::numeric_limits<std::size_t>::max()
                                         : static_cast<std::size_t>(limit.rlim_cur);
}

// Admitted connections must leave descriptors for everything else, or accept() fails for all.
void ConnectionManager::limit_to_descriptors() {
  rlimit limit{};
  if (::getrlimit(RLIMIT_NOFILE, &limit) != 0 || limit.rlim_cur == RLIM_INFINITY) return;
  const auto soft = static_cast<std::size_t>(limit.rlim_cur);
  const std::size_t allowed = std::max<std::size_t>(
      1, soft > 2 * kDescriptorReserve ? soft - kDescriptorReserve : soft / 2);
  descriptor_cap_ = allowed;
  const std::size_t cap = std::min(options_.max_connections, allowed);
  if (connection_cap_.exchange(cap) != cap && cap < options_.max_connections) {
    log_->warn("max_connections lowered from {} to {}: this process may open {} file descriptors "
               "(RLIMIT_NOFILE) and keeps {} for other uses; raise the limit "
               "(ulimit -n, LimitNOFILE=) to admit more",
               options_.max_connections, cap, soft, soft - cap);
  }
}

std::size_t ConnectionManager::receive_reserved() const { return limits_->receive.reserved(); }

ConnectionManager::~ConnectionManager() = default;

void ConnectionManager::set_acceptor(Connection::Acceptor acceptor) {
  std::lock_guard lock(mutex_);
  accept_policy_ = std::move(acceptor);
}

void ConnectionManager::set_tls(const TlsOptions& options) {
  options.validate();
  // A context loads what its files hold, so configured files are checked here, at start. With
  // none and TLS only where a link needs it (the default), the client context is made at the
  // first TLS connect: OpenSSL costs a process about 2 MiB the moment it is first used, which
  // a device manager on loopback never needs.
  auto server = options.certificate_file.empty() ? nullptr : make_context(options, true);
  const bool configured = options.mode == TlsMode::on || !options.ca_file.empty() || !options.certificate_file.empty();
  auto client = configured ? make_context(options, false) : nullptr;
  std::lock_guard lock(mutex_);
  tls_options_ = options;
  server_tls_ = std::move(server);
  client_tls_ = std::move(client);
}

void ConnectionManager::set_token(std::string token) {
  if (token.size() > kMaxTokenSize) {
    throw std::invalid_argument(
        fmt::format("token of {} bytes is longer than {}", token.size(), kMaxTokenSize));
  }
  std::lock_guard lock(mutex_);
  check_connect_fits(local_pun_, token);
  token_ = std::move(token);
}

void ConnectionManager::set_access_policy(std::shared_ptr<const AccessPolicy> policy) {
  std::lock_guard lock(mutex_);
  access_ = std::move(policy);
}

bool ConnectionManager::wants_tls(const std::string& host) const {
  std::lock_guard lock(mutex_);
  switch (tls_options_.mode) {
    case TlsMode::on:
      return true;
    case TlsMode::off:
      return false;
    case TlsMode::automatic:
      break;
  }
  return !is_loopback_host(host);
}

std::shared_ptr<asio::ssl::context> ConnectionManager::client_context() {
  std::lock_guard lock(mutex_);
  if (!client_tls_) client_tls_ = make_context(tls_options_, false);
  return client_tls_;
}

Admission ConnectionManager::admit(const ConnectRequest& request) {
  Connection::Acceptor extra;
  std::shared_ptr<const AccessPolicy> access;
  std::size_t admitted = 0;
  std::size_t from_address = 0;
  {
    std::lock_guard lock(mutex_);
    extra = accept_policy_;
    access = access_;
    for (const auto& [id, c] : connections_) {
      if (c->role() == ConnectionRole::server && c->is_open()) {
        ++admitted;
        if (c->remote_ip() == request.remote_ip) ++from_address;
      }
    }
  }
  Admission admission;
  if (from_address >= options_.max_connections_per_address) {
    admission.deny = fmt::format("too many connections from {}: {} open "
                                 "(max_connections_per_address); retry later",
                                 request.remote_ip, from_address);
    return admission;
  }
  if (admitted >= connection_cap_.load()) {
    admission.deny = fmt::format("server full: {} connections open (max_connections); retry later",
                                 admitted);
    return admission;
  }
  if (access) {
    const Principal* principal = access->authenticate(request.token, request.certificate_name);
    if (principal == nullptr) {
      admission.deny =
          request.token.empty() && request.certificate_name.empty()
              ? std::string("authentication required: send a token (CommunicatorOptions::token) "
                            "or a client certificate")
              : fmt::format("authentication failed: {} is not a known principal",
                            request.certificate_name.empty()
                                ? std::string("the token")
                                : fmt::format("certificate '{}' and the token",
                                              request.certificate_name));
      return admission;
    }
    admission.principal = std::shared_ptr<const Principal>(access, principal);
  }
  if (extra) {
    Admission decided = extra(request);
    if (decided.deny) return decided;
    if (decided.principal) admission.principal = std::move(decided.principal);
  }
  return admission;
}

void ConnectionManager::set_local_pun(std::string pun) {
  std::lock_guard lock(mutex_);
  check_connect_fits(pun, token_);
  local_pun_ = std::move(pun);
}

std::string ConnectionManager::local_pun() const {
  std::lock_guard lock(mutex_);
  return local_pun_;
}

std::uint16_t ConnectionManager::listen(const std::string& address, std::uint16_t port) {
  auto acceptor = std::make_shared<Acceptor>(*io_);
  if (wants_tls(address)) {  // some clients will need TLS
    std::lock_guard lock(mutex_);
    if (!server_tls_) {
      throw std::invalid_argument(fmt::format(
          "listening on {} needs TLS ({}): configure tls.certificate_file and "
          "tls.private_key_file, or set tls.mode = off on a network where every host is trusted",
          address, tls_options_.mode == TlsMode::on ? "tls.mode = on" : "not a loopback address"));
    }
  }
  const asio::ip::tcp::endpoint endpoint(asio::ip::make_address(address), port);
  acceptor->socket.open(endpoint.protocol());
  acceptor->socket.set_option(asio::ip::tcp::acceptor::reuse_address(true));
  acceptor->socket.bind(endpoint);
  acceptor->socket.listen(asio::socket_base::max_listen_connections);
  const std::uint16_t bound = acceptor->socket.local_endpoint().port();
  limit_to_descriptors();
  {
    std::lock_guard lock(mutex_);
    if (local_pun_.empty()) local_pun_ = fmt::format("{}:{}", address, bound);
    acceptors_.push_back(acceptor);
  }
  asio::post(*io_, [this, acceptor] { accept_next(acceptor); });
  log_->info("listening on {}:{}{}", address, bound, wants_tls(address) ? " (TLS)" : "");
  return bound;
}

void ConnectionManager::on_accept_failed(const std::shared_ptr<Acceptor>& acceptor,
                                         const std::error_code& ec) {
  ++accept_failures_;
  ++acceptor->failures_unreported;
  const auto now = std::chrono::steady_clock::now();
  // One line a second at most, however fast accept fails.
  if (now - acceptor->last_report >= std::chrono::seconds(1)) {
    log_->warn("accept failed: {} ({} failure{} since the last report){}", ec.message(),
               acceptor->failures_unreported, acceptor->failures_unreported == 1 ? "" : "s",
               out_of_resources(ec) ? "; backing off while the process is out of descriptors or "
                                      "memory (see ulimit -n)"
                                    : "");
    acceptor->failures_unreported = 0;
    acceptor->last_report = now;
  }
  if (!out_of_resources(ec)) return;
  acceptor->backoff = acceptor->backoff.count() == 0
                          ? kAcceptBackoffFirst
                          : std::min(kAcceptBackoffMax, acceptor->backoff * 2);
  acceptor->retry.expires_after(acceptor->backoff);
  acceptor->retry.async_wait([this, acceptor](const std::error_code& tec) {
    if (tec || !acceptor->socket.is_open()) return;
    accept_next(acceptor);
  });
}

void ConnectionManager::accept_next(const std::shared_ptr<Acceptor>& acceptor) {
  acceptor->socket.async_accept([this, acceptor](const std::error_code& ec,
                                                 asio::ip::tcp::socket socket) {
    if (ec == asio::error::operation_aborted || !acceptor->socket.is_open()) return;
    if (ec) {
      on_accept_failed(acceptor, ec);
      if (out_of_resources(ec)) return;  // accept_next runs when the backoff timer fires
    } else {
      acceptor->backoff = std::chrono::milliseconds(0);
      // In automatic mode a loopback client speaks plaintext and any other one TLS, as each
      // client decides from the host it connects to.
      std::error_code rec;
      const auto remote = socket.remote_endpoint(rec);
      const bool tls = wants_tls(rec ? std::string("unknown") : remote.address().to_string());
      adopt(std::move(socket), ConnectionRole::server, nullptr, tls);
      if (pause_if_full(acceptor)) return;  // on_close resumes
    }
    accept_next(acceptor);
  });
}

// Connections (in any state, silent ones too) may hold only the descriptors the cap leaves:
// accepting more would run the process out of descriptors for everything else.
bool ConnectionManager::pause_if_full(const std::shared_ptr<Acceptor>& acceptor) {
  std::size_t open = 0;
  {
    std::lock_guard lock(mutex_);
    open = connections_.size();
  }
  if (open < descriptor_cap_.load()) return false;
  acceptor->paused = true;
  ++acceptor->pauses_unreported;
  const auto now = std::chrono::steady_clock::now();
  if (now - acceptor->last_pause_report >= std::chrono::seconds(1)) {
    log_->warn("not accepting connections: {} open, as many as this process's descriptor limit "
               "allows (RLIMIT_NOFILE less a reserve of {}); resuming when one closes ({} "
               "pause{} since the last report)",
               open, kDescriptorReserve, acceptor->pauses_unreported,
               acceptor->pauses_unreported == 1 ? "" : "s");
    acceptor->pauses_unreported = 0;
    acceptor->last_pause_report = now;
  }
  return true;
}

void ConnectionManager::resume_accepting() {
  std::vector<std::shared_ptr<Acceptor>> acceptors;
  {
    std::lock_guard lock(mutex_);
    if (connections_.size() >= descriptor_cap_.load()) return;
    acceptors = acceptors_;
  }
  for (auto& a : acceptors) {
    if (!a->paused || !a->socket.is_open()) continue;
    a->paused = false;
    accept_next(a);
  }
}

std::shared_ptr<Connection> ConnectionManager::adopt(asio::ip::tcp::socket socket,
                                                     ConnectionRole role,
                                                     const std::shared_ptr<Peer>& owner, bool tls) {
  std::string pun;
  ConnectionSecurity security;
  {
    std::lock_guard lock(mutex_);
    pun = local_pun_;
    if (role == ConnectionRole::client) security.token = token_;
    if (tls && role == ConnectionRole::server) security.tls = server_tls_;
  }
  if (tls && role == ConnectionRole::client) {
    security.tls = client_context();
    std::lock_guard lock(mutex_);
    security.server_name = tls_options_.server_name.empty() && owner ? owner->host_
                                                                     : tls_options_.server_name;
  }
  Connection::Acceptor policy;
  if (role == ConnectionRole::server) {
    policy = [this](const ConnectRequest& request) { return admit(request); };
  }
  if (pun.empty()) {
    std::error_code ec;
    const auto local = socket.local_endpoint(ec);
    pun = ec ? "unknown" : fmt::format("{}:{}", local.address().to_string(), local.port());
  }
  auto connection = std::make_shared<Connection>(io_, std::move(socket), role, std::move(pun),
                                                 options_, *this, log_, std::move(policy),
                                                 std::move(security), limits_);
  {
    std::lock_guard lock(mutex_);
    connections_.emplace(connection->id(), connection);
    if (owner) owners_.emplace(connection->id(), owner);
  }
  connection->start();
  return connection;
}

std::shared_ptr<Peer> ConnectionManager::connect(const std::string& host, std::uint16_t port,
                                                 ReconnectPolicy policy) {
  auto peer = std::make_shared<Peer>(*this, host, port, policy);
  {
    std::lock_guard lock(mutex_);
    peers_.push_back(peer);
  }
  asio::post(*io_, [peer] { peer->attempt(); });
  return peer;
}

std::uint64_t ConnectionManager::add_listener(ConnectionListener listener) {
  auto entry = std::make_shared<ListenerEntry>();
  entry->fn = std::move(listener);
  std::lock_guard lock(mutex_);
  listeners_.emplace(next_listener_, std::move(entry));
  return next_listener_++;
}

void ConnectionManager::remove_listener(std::uint64_t id) {
  std::shared_ptr<ListenerEntry> entry;
  {
    std::lock_guard lock(mutex_);
    auto it = listeners_.find(id);
    if (it == listeners_.end()) return;
    entry = std::move(it->second);
    listeners_.erase(it);
  }
  // Waits for a call in progress on the io thread, so the listener's owner may be destroyed
  // as soon as this returns.
  std::lock_guard calling(entry->calling);
  entry->removed = true;
}

void ConnectionManager::notify(const ConnectionEvent& event) {
  std::vector<std::shared_ptr<ListenerEntry>> listeners;
  {
    std::lock_guard lock(mutex_);
    for (const auto& [id, l] : listeners_) listeners.push_back(l);
  }
  for (const auto& l : listeners) {
    std::lock_guard calling(l->calling);
    if (l->removed) continue;
    try {
      l->fn(event);
    } catch (const std::exception& e) {
      log_->error("connection listener threw: {}", e.what());
    }
  }
}

std::vector<std::shared_ptr<Connection>> ConnectionManager::connections() const {
  std::lock_guard lock(mutex_);
  std::vector<std::shared_ptr<Connection>> out;
  for (const auto& [id, c] : connections_) {
    if (c->is_open()) out.push_back(c);
  }
  return out;
}

void ConnectionManager::on_message(const std::shared_ptr<Connection>& c,
                                   std::span<const std::byte> m) {
  upper_.on_message(c, m);
}

void ConnectionManager::on_large_message(const std::shared_ptr<Connection>& c,
                                         std::vector<std::vector<std::byte>> blocks) {
  upper_.on_large_message(c, std::move(blocks));
}

void ConnectionManager::on_message_refused(const std::shared_ptr<Connection>& c,
                                           std::span<const std::byte> first,
                                           const std::string& reason) {
  upper_.on_message_refused(c, first, reason);
}

void ConnectionManager::on_open(const std::shared_ptr<Connection>& c) {
  std::shared_ptr<Peer> owner;
  {
    std::lock_guard lock(mutex_);
    if (auto it = owners_.find(c->id()); it != owners_.end()) owner = it->second.lock();
  }
  log_->info("connection {} open: {} ({})", c->id(), c->describe(),
             c->role() == ConnectionRole::client ? "client" : "server");
  upper_.on_open(c);
  if (owner) {
    owner->on_open(c);
  } else {
    notify({LinkEventKind::connected, c, nullptr, {}});
  }
}

void ConnectionManager::on_close(const std::shared_ptr<Connection>& c, const Error& reason) {
  std::shared_ptr<Peer> owner;
  bool had_owner = false;
  {
    std::lock_guard lock(mutex_);
    connections_.erase(c->id());
    if (auto it = owners_.find(c->id()); it != owners_.end()) {
      owner = it->second.lock();
      had_owner = true;
      owners_.erase(it);
    }
  }
  resume_accepting();
  upper_.on_close(c, reason);
  if (owner) {
    owner->on_close(c, reason);
  } else if (!had_owner && c->was_open()) {
    notify({LinkEventKind::disconnected, c, nullptr, reason.what()});
  }
}

void ConnectionManager::shutdown() {
  if (io_->get_executor().running_in_this_thread() || io_->stopped()) {
    shutdown_on_io();
    return;
  }
  std::promise<void> done;
  auto finished = done.get_future();
  asio::post(*io_, [this, &done] {
    shutdown_on_io();
    done.set_value();
  });
  finished.wait();
}

void ConnectionManager::shutdown_on_io() {
  std::vector<std::shared_ptr<Acceptor>> acceptors;
  std::vector<std::shared_ptr<Peer>> peers;
  std::vector<std::shared_ptr<Connection>> connections;
  {
    std::lock_guard lock(mutex_);
    if (shut_down_) return;
    shut_down_ = true;
    acceptors.swap(acceptors_);
    for (auto& w : peers_) {
      if (auto p = w.lock()) peers.push_back(p);
    }
    peers_.clear();
    for (auto& [id, c] : connections_) connections.push_back(c);
  }
  for (auto& a : acceptors) {
    std::error_code ignored;
    a->socket.close(ignored);
    a->retry.cancel();
  }
  for (auto& p : peers) p->stop();
  for (auto& c : connections) c->close("shutting down");
}

}  // namespace icars::planet
