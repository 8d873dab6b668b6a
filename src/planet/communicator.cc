#include "icars/planet/communicator.h"

#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <asio/co_spawn.hpp>
#include <asio/post.hpp>
#include <future>
#include <stdexcept>

#include "buffer_pool.h"
#include "stream_table.h"

namespace icars::planet {

namespace {
constexpr auto kSweepInterval = std::chrono::milliseconds(20);
}

std::string_view to_string(RmiCode code) noexcept {
  switch (code) {
    case RmiCode::call:
      return "CALL";
    case RmiCode::reply:
      return "REPLY";
    case RmiCode::error:
      return "ERROR";
    case RmiCode::notify:
      return "NOTIFY";
    case RmiCode::stream:
      return "STREAM";
  }
  return "UNKNOWN";
}

Communicator::Communicator(CommunicatorOptions options)
    : options_(std::move(options)),
      log_(options_.logger ? options_.logger
                           : std::make_shared<spdlog::logger>(
                                 options_.name,
                                 std::make_shared<spdlog::sinks::stderr_color_sink_mt>())),
      io_(std::make_shared<asio::io_context>()),
      work_(std::make_unique<asio::executor_work_guard<asio::io_context::executor_type>>(
          io_->get_executor())),
      manager_(std::make_unique<ConnectionManager>(io_, static_cast<MessageHandler&>(*this), options_.connection, log_)),
      adapter_([this] { return in_io_thread(); }),
      streams_(std::make_unique<detail::StreamTable>(*log_)),
      sweep_timer_(std::make_unique<asio::steady_timer>(*io_)) {
  if (!options_.token.empty()) manager_->set_token(options_.token);
  if (!options_.pun.empty()) manager_->set_local_pun(options_.pun);
  manager_->set_tls(options_.tls);
  if (options_.access) manager_->set_access_policy(options_.access);
  if (options_.max_pending_calls == 0) throw std::invalid_argument("max_pending_calls must be > 0");
  // A Peer is up again (its connection is current by now): send the idempotent calls that wait.
  manager_->add_listener([this](const ConnectionEvent& e) {
    if (e.peer && e.kind != LinkEventKind::disconnected) resend_waiting(*e.peer);
  });
  std::promise<std::thread::id> started;
  auto id = started.get_future();
  io_thread_ = std::thread([this, &started] {
    started.set_value(std::this_thread::get_id());
    for (;;) {
      try {
        io_->run();
        return;
      } catch (const std::exception& e) {  // a handler threw: log it and keep the loop alive
        log_->error("unhandled exception on the io thread: {}", e.what());
      }
    }
  });
  io_thread_id_ = id.get();
  asio::post(*io_, [this] { sweep_deadlines(); });
  if (const auto& activity = options_.connection.activity) {
    activity_queue_ = activity->add_queue([io = io_](std::function<void()> marker) { asio::post(*io, std::move(marker)); });
  }
}

Communicator::~Communicator() {
  if (activity_queue_ != 0) options_.connection.activity->remove_queue(activity_queue_);
  // Idempotent calls waiting for their link end now, while the io thread still runs the
  // completions they post; those in flight fail as their connections close below.
  std::vector<Completion> waiting;
  {
    std::lock_guard lock(pending_mutex_);
    closing_ = true;
    for (auto it = pending_.begin(); it != pending_.end();) {
      if (it->second.connection_id == 0) {
        waiting.push_back(std::move(it->second.done));
        it = pending_.erase(it);
      } else {
        ++it;
      }
    }
  }
  for (auto& done : waiting) {
    done(std::make_exception_ptr(Error(
             ErrorKind::disconnected,
             "communicator destroyed while the call waited for its link to come back")),
         nullptr);
  }
  manager_->shutdown();
  {
    // Large messages still being handled finish first (their replies fail: the links are down).
    std::unique_lock lock(bulk_mutex_);
    auto bulk = std::move(bulk_);
    lock.unlock();
    if (bulk) bulk->join();
  }
  asio::post(*io_, [this] { sweep_timer_->cancel(); });
  work_.reset();
  // Everything was closed above; give pending handlers a moment to run, then stop the loop.
  auto stopper = std::async(std::launch::async, [this] {
    for (int i = 0; i < 200 && !io_->stopped(); ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    io_->stop();
  });
  io_thread_.join();
  stopper.wait();
  std::unordered_map<std::uint32_t, Pending> pending;
  {
    std::lock_guard lock(pending_mutex_);
    pending.swap(pending_);
  }
  for (auto& [id, p] : pending) {
    p.done(std::make_exception_ptr(Error(ErrorKind::disconnected, "communicator destroyed")),
           nullptr);
  }
}

std::uint16_t Communicator::listen(const std::string& address, std::uint16_t port) {
  return manager_->listen(address, port);
}

std::shared_ptr<Peer> Communicator::connect(const std::string& host, std::uint16_t port,
                                            ReconnectPolicy policy) {
  return manager_->connect(host, port, policy);
}

// --- Remote references ---------------------------------------------------------------------

ObjectRef Communicator::reference(const std::string& path) const {
  auto servant = adapter_.find(path);
  if (!servant) throw std::invalid_argument("no servant registered at '" + path + "'");
  return ObjectRef{manager_->local_pun(), path, servant->type_id()};
}

std::shared_ptr<Link> Communicator::resolve(const ObjectRef& ref,
                                            const std::shared_ptr<Link>& via) {
  if (ref.pun.empty()) return via;
  if (via) {
    if (auto c = via->connection(); c && c->peer_pun() == ref.pun) return via;
  }
  for (auto& c : manager_->connections()) {
    if (c->is_open() && c->peer_pun() == ref.pun) return c;
  }
  if (ref.pun == manager_->local_pun()) {
    throw Error(ErrorKind::refused,
                fmt::format("the reference to {} names this endpoint ('{}') itself; PLANET does "
                            "not call its own servants over the network: use the servant at that "
                            "path directly",
                            ref.path, ref.pun));
  }
  throw Error(ErrorKind::refused,
              fmt::format("the reference to {} names endpoint '{}', which is neither the peer it "
                          "came from nor any connected endpoint",
                          ref.path, ref.pun));
}

// --- Request Manager -----------------------------------------------------------------------

std::uint32_t Communicator::start_call(const std::shared_ptr<Link>& link,
                                       std::vector<std::byte> request,
                                       std::chrono::milliseconds timeout, CallMode mode,
                                       Completion done) {
  std::shared_ptr<Peer> retry_over;
  if (mode == CallMode::idempotent) retry_over = std::dynamic_pointer_cast<Peer>(link);
  auto connection = link->connection();
  if (!connection && !retry_over) {
    done(std::make_exception_ptr(Error(ErrorKind::disconnected,
                                       fmt::format("link to {} is down", link->describe()))),
         nullptr);
    return 0;
  }
  std::uint32_t id = 0;
  {
    std::unique_lock lock(pending_mutex_);
    if (closing_ && !connection) {
      lock.unlock();
      done(std::make_exception_ptr(Error(
               ErrorKind::disconnected,
               fmt::format("link to {} is down and the communicator is being destroyed",
                           link->describe()))),
           nullptr);
      return 0;
    }
    if (pending_.size() >= options_.max_pending_calls) {
      const std::size_t pending = pending_.size();
      lock.unlock();
      done(std::make_exception_ptr(Error(
               ErrorKind::overloaded,
               fmt::format("{} calls are awaiting replies (max_pending_calls); retry later",
                           pending))),
           nullptr);
      return 0;
    }
    do {
      id = next_request_id_++;
    } while (id == 0 || pending_.contains(id));
    detail::store_be32(request.data() + kRequestIdOffset, id);
    Pending pending{connection ? connection->id() : 0,
                    std::chrono::steady_clock::now() + timeout, std::move(done), retry_over, {}};
    // A call that waits keeps its only copy in the table; one sent now keeps a copy to resend.
    if (retry_over) pending.request = connection ? request : std::move(request);
    pending_.emplace(id, std::move(pending));
  }
  if (!connection) {
    // The link may have come back between connection() and the registration above, after its
    // reconnection event: look again now that the call is in the table.
    send_waiting(id);
    return id;
  }
  const std::uint64_t connection_id = connection->id();
  try {
    connection->send(std::move(request));
  } catch (const Error& e) {
    on_send_failed(id, connection_id, e);
  }
  return id;
}

void Communicator::send_waiting(std::uint32_t request_id) {
  std::shared_ptr<Peer> peer;
  {
    std::lock_guard lock(pending_mutex_);
    auto it = pending_.find(request_id);
    if (it == pending_.end() || it->second.connection_id != 0) return;
    peer = it->second.retry_over;
  }
  auto connection = peer->connection();
  if (!connection) return;  // the next reconnection event sends it
  std::vector<std::byte> request;
  {
    std::lock_guard lock(pending_mutex_);
    auto it = pending_.find(request_id);
    if (it == pending_.end() || it->second.connection_id != 0 || closing_) return;
    it->second.connection_id = connection->id();
    request = it->second.request;
  }
  log_->debug("request {} (idempotent) sent again over {}", request_id, connection->describe());
  try {
    connection->send(std::move(request));
  } catch (const Error& e) {
    on_send_failed(request_id, connection->id(), e);
  }
}

void Communicator::resend_waiting(const Peer& peer) {
  std::vector<std::uint32_t> waiting;
  {
    std::lock_guard lock(pending_mutex_);
    for (const auto& [id, p] : pending_) {
      if (p.connection_id == 0 && p.retry_over.get() == &peer) waiting.push_back(id);
    }
  }
  for (auto id : waiting) send_waiting(id);
}

// A send that throws queued nothing. An idempotent call over a Peer whose connection was closing
// waits for the next one (looked for again on the io thread, after the close is handled);
// anything else fails with the send's error.
void Communicator::on_send_failed(std::uint32_t request_id, std::uint64_t connection_id,
                                  const Error& error) {
  if (error.kind() == ErrorKind::disconnected) {
    std::lock_guard lock(pending_mutex_);
    auto it = pending_.find(request_id);
    if (it == pending_.end() || it->second.connection_id != connection_id) return;
    if (it->second.retry_over && !closing_) {
      it->second.connection_id = 0;
      asio::post(*io_, [this, request_id] { send_waiting(request_id); });
      return;
    }
  }
  Completion done;
  {
    std::lock_guard lock(pending_mutex_);
    auto it = pending_.find(request_id);
    if (it == pending_.end() || it->second.connection_id != connection_id) return;
    done = std::move(it->second.done);
    pending_.erase(it);
  }
  done(std::make_exception_ptr(error), nullptr);
}

bool Communicator::cancel_call(std::uint32_t request_id, const Error& error) {
  Completion done;
  {
    std::lock_guard lock(pending_mutex_);
    auto it = pending_.find(request_id);
    if (it == pending_.end()) return false;
    done = std::move(it->second.done);
    pending_.erase(it);
  }
  done(std::make_exception_ptr(error), nullptr);
  return true;
}

void Communicator::send_oneway(const Link& link, std::vector<std::byte> request) {
  auto connection = link.connection();
  if (!connection) {
    throw Error(ErrorKind::disconnected, fmt::format("link to {} is down", link.describe()));
  }
  connection->send(std::move(request));
}

std::size_t Communicator::pending_calls() const {
  std::lock_guard lock(pending_mutex_);
  return pending_.size();
}

void Communicator::complete(const Connection& from, std::uint32_t request_id,
                            std::exception_ptr error, Reader* result) {
  Completion done;
  {
    std::lock_guard lock(pending_mutex_);
    auto it = pending_.find(request_id);
    if (it == pending_.end() || it->second.connection_id != from.id()) {
      log_->debug("reply to unknown or expired request {} from {} dropped", request_id,
                  from.describe());
      return;
    }
    done = std::move(it->second.done);
    pending_.erase(it);
  }
  done(std::move(error), result);
}

void Communicator::sweep_deadlines() {
  const auto now = std::chrono::steady_clock::now();
  std::vector<std::pair<std::uint32_t, std::string>> expired;  // id, the link it waited for
  {
    std::lock_guard lock(pending_mutex_);
    for (const auto& [id, p] : pending_) {
      if (p.deadline > now) continue;
      expired.emplace_back(id, p.connection_id == 0 ? p.retry_over->describe() : std::string());
    }
  }
  for (const auto& [id, link] : expired) {
    cancel_call(id, Error(ErrorKind::timeout,
                          link.empty() ? fmt::format("no reply to request {} in time", id)
                                       : fmt::format("no reply to request {} in time: the link "
                                                     "to {} stayed down",
                                                     id, link)));
  }
  streams_->sweep(now);
  detail::trim_buffers(std::chrono::seconds(2));
  sweep_timer_->expires_after(kSweepInterval);
  sweep_timer_->async_wait([this](const std::error_code& ec) {
    if (!ec) sweep_deadlines();
  });
}

// --- Incoming messages ---------------------------------------------------------------------

void Communicator::on_message(const std::shared_ptr<Connection>& c, std::span<const std::byte> m) {
  // Behind a large NOTIFY of the same connection still on the bulk thread, a NOTIFY waits its
  // turn there: one-way messages (a publisher's events) are handled in the order they came.
  // Calls are not held back (a small call is answered while a servant works on a large one).
  if (bulk_notifies_.load(std::memory_order_acquire) != 0 && !m.empty() &&
      static_cast<RmiCode>(m[0]) == RmiCode::notify) {
    std::unique_lock lock(bulk_mutex_);
    if (bulk_ && bulk_pending_.contains(c.get())) {
      std::vector<std::vector<std::byte>> copy;
      copy.emplace_back(m.begin(), m.end());
      post_bulk(lock, c, std::move(copy), true);
      return;
    }
  }
  handle_message(c, m);
}

void Communicator::post_bulk(std::unique_lock<std::mutex>& lock, const std::shared_ptr<Connection>& c,
                             std::vector<std::vector<std::byte>> blocks, bool notify) {
  if (!bulk_) bulk_ = std::make_unique<asio::thread_pool>(1);
  if (notify) {
    ++bulk_pending_[c.get()];
    bulk_notifies_.fetch_add(1, std::memory_order_acq_rel);
  }
  asio::post(*bulk_, [this, c, notify, blocks = std::move(blocks),
                      hold = Activity::Hold(activity().get())]() mutable {
    {
      Reader r(blocks);  // read where the connection assembled it: never joined
      handle_message(c, r);
    }
    hold.release();
    for (auto& b : blocks) detail::give_buffer(std::move(b));
    if (!notify) return;
    std::lock_guard done(bulk_mutex_);
    if (auto it = bulk_pending_.find(c.get()); it != bulk_pending_.end() && --it->second == 0) {
      bulk_pending_.erase(it);
    }
    bulk_notifies_.fetch_sub(1, std::memory_order_acq_rel);
  });
  (void)lock;
}

void Communicator::handle_message(const std::shared_ptr<Connection>& c, std::span<const std::byte> m) {
  Reader r(m);
  handle_message(c, r);
}

void Communicator::handle_message(const std::shared_ptr<Connection>& c, Reader& r) {
  std::uint32_t request_id = 0;
  RmiCode code{};
  try {
    code = static_cast<RmiCode>(r.u8());
    switch (code) {
      case RmiCode::call:
      case RmiCode::notify:
        dispatch_request(c, r, code == RmiCode::notify);
        return;
      case RmiCode::reply:
        request_id = r.u32();
        complete(*c, request_id, nullptr, &r);
        return;
      case RmiCode::error: {
        request_id = r.u32();
        const std::uint8_t raw_kind = r.u8();
        RemoteException exception = Codec<RemoteException>::decode(r);
        std::exception_ptr error;
        if (raw_kind == static_cast<std::uint8_t>(ErrorKind::failed) ||
            raw_kind < static_cast<std::uint8_t>(ErrorKind::failed) ||
            raw_kind > static_cast<std::uint8_t>(ErrorKind::denied)) {
          error = std::make_exception_ptr(std::move(exception));
        } else {
          error = std::make_exception_ptr(Error(static_cast<ErrorKind>(raw_kind),
                                                exception.remote_message() + " (reported by " +
                                                    c->describe() + ")"));
        }
        complete(*c, request_id, error, nullptr);
        return;
      }
      case RmiCode::stream:
        streams_->on_message(c, r);
        return;
    }
    log_->warn("message with unknown RMI code {} from {} dropped",
               static_cast<unsigned>(code), c->describe());
  } catch (const Error& e) {
    log_->warn("malformed {} message from {} dropped: {}", to_string(code), c->describe(),
               e.what());
    if ((code == RmiCode::reply || code == RmiCode::error) && request_id != 0) {
      // The caller still learns why: the answer it waited for could not be read.
      complete(*c, request_id, std::make_exception_ptr(e), nullptr);
    }
  }
}

void Communicator::read_reply(const Link& link, std::uint32_t request_id,
                              std::chrono::steady_clock::time_point until,
                              const std::function<bool()>& answered) {
  const auto c = link.connection();
  if (!c) return;
  c->read_directly(until, answered, [&](std::span<const std::byte> m) {
    // Only the reply (or error) to this call; anything else is the io thread's to handle.
    if (m.size() < 5) return false;  // code and request id, read as handle_message reads them
    Reader head(m);
    const auto code = static_cast<RmiCode>(head.u8());
    if ((code != RmiCode::reply && code != RmiCode::error) || head.u32() != request_id) return false;
    handle_message(c, m);
    return true;
  });
}

void Communicator::on_large_message(const std::shared_ptr<Connection>& c,
                                    std::vector<std::vector<std::byte>> blocks) {
  const auto code = blocks.front().empty() ? RmiCode{} : static_cast<RmiCode>(blocks.front()[0]);
  if (code != RmiCode::call && code != RmiCode::notify && code != RmiCode::reply) {
    Reader r(blocks);  // anything else keeps its place on the io thread
    handle_message(c, r);
    for (auto& b : blocks) detail::give_buffer(std::move(b));
    return;
  }
  std::unique_lock lock(bulk_mutex_);
  post_bulk(lock, c, std::move(blocks), code == RmiCode::notify);
}

void Communicator::dispatch_request(const std::shared_ptr<Connection>& c, Reader& r, bool oneway) {
  const std::uint32_t request_id = r.u32();
  std::string_view path;
  std::string_view method;
  try {
    path = r.str_view();
    method = r.str_view();
  } catch (const Error& e) {
    log_->warn("malformed request header from {}: {}", c->describe(), e.what());
    if (!oneway) send_error(c, request_id, ErrorKind::bad_data, "planet::BadData", e.message());
    return;
  }
  if (options_.access && c->role() == ConnectionRole::server) {
    // Requests over links this endpoint opened come from the server it chose (and, over TLS,
    // verified); requests from its own clients need their principal's permission.
    const auto principal = c->principal();
    if (!principal || !principal->may_call_path(path)) {
      const std::string message =
          fmt::format("{} may not call '{}' (access policy)",
                      principal ? fmt::format("principal '{}'", principal->name) : c->describe(),
                      path);
      log_->warn("denied {} ({}.{})", message, path, method);
      if (!oneway) send_error(c, request_id, ErrorKind::denied, "planet::Denied", message);
      return;
    }
  }
  auto call = adapter_.begin_call(path);
  if (!call) {
    const std::string message = fmt::format("no servant at path '{}'", path);
    log_->debug("{} (method '{}', from {})", message, method, c->describe());
    if (!oneway) send_error(c, request_id, ErrorKind::unimplemented, "planet::NoSuchObject", message);
    return;
  }
  const Current current{c, path, method, oneway ? 0 : request_id, this};
  std::vector<std::byte> reply;
  Writer w(reply);
  if (!oneway) {
    reply.reserve(64);
    w.u8(static_cast<std::uint8_t>(RmiCode::reply));
    w.u32(request_id);
  }
  try {
    auto pending = call.run(method, r, oneway ? nullptr : &w, current);
    if (pending) {
      finish_async(c, oneway, request_id, std::string(path), std::string(method),
                   std::move(*pending), std::move(call));
      return;
    }
  } catch (...) {
    call = {};
    report_failure(c, oneway, request_id, path, method, std::current_exception());
    return;
  }
  call = {};  // the servant is done: remove() of its path may return
  if (oneway) return;
  send_reply(c, request_id, path, std::move(reply));
}

void Communicator::finish_async(const std::shared_ptr<Connection>& c, bool oneway,
                                std::uint32_t request_id, std::string path, std::string method,
                                Servant::AsyncResult work, ObjectAdapter::Dispatch call) {
  asio::co_spawn(*io_, std::move(work),
                 [this, c, oneway, request_id, path = std::move(path), method = std::move(method),
                  call = std::move(call)](std::exception_ptr e,
                                          std::vector<std::byte> result) mutable {
                   call = {};  // the coroutine has finished: remove() of its path may return
                   if (e) {
                     report_failure(c, oneway, request_id, path, method, e);
                     return;
                   }
                   if (oneway) return;
                   std::vector<std::byte> reply;
                   reply.reserve(5 + result.size());
                   Writer w(reply);
                   w.u8(static_cast<std::uint8_t>(RmiCode::reply));
                   w.u32(request_id);
                   w.raw(result);
                   send_reply(c, request_id, path, std::move(reply));
                 });
}

// Sends a REPLY; when it cannot be queued (too large, queue full), the caller gets an ERROR
// saying so instead of waiting for its deadline.
void Communicator::send_reply(const std::shared_ptr<Connection>& c, std::uint32_t request_id,
                              std::string_view path, std::vector<std::byte> reply) {
  try {
    c->send(std::move(reply));
  } catch (const Error& e) {
    log_->warn("reply to request {} on '{}' not sent: {}", request_id, path, e.what());
    if (e.kind() == ErrorKind::overloaded) {
      send_error(c, request_id, ErrorKind::overloaded, "planet::ReplyNotSent", e.message());
    }
  }
}

// Answers a failed request with ERROR (a failed NOTIFY is only logged).
void Communicator::report_failure(const std::shared_ptr<Connection>& c, bool oneway,
                                  std::uint32_t request_id, std::string_view path,
                                  std::string_view method, const std::exception_ptr& failure) {
  ErrorKind kind = ErrorKind::failed;
  std::string type = "unknown";
  std::string message = "the servant threw a non-standard exception";
  Properties properties;
  try {
    std::rethrow_exception(failure);
  } catch (const RemoteException& e) {
    type = e.type_id();
    message = e.remote_message();
    properties = e.properties();
  } catch (const Error& e) {
    kind = e.kind();
    type = kind == ErrorKind::unimplemented ? "planet::NoSuchMethod"
           : kind == ErrorKind::bad_data    ? "planet::BadData"
                                            : "planet::Error";
    message = e.message();
  } catch (const std::exception& e) {
    type = "std::exception";
    message = e.what();
  } catch (...) {
  }
  if (oneway) {
    log_->warn("one-way '{}' on '{}' failed: {}: {}", method, path, type, message);
  } else {
    send_error(c, request_id, kind, type, message, properties);
  }
}

void Communicator::send_error(const std::shared_ptr<Connection>& c, std::uint32_t request_id,
                              ErrorKind kind, const std::string& type_id,
                              const std::string& message, const Properties& properties) {
  std::vector<std::byte> out;
  Writer w(out);
  w.u8(static_cast<std::uint8_t>(RmiCode::error));
  w.u32(request_id);
  w.u8(static_cast<std::uint8_t>(kind));
  w.str(type_id);
  w.str(message);
  properties.encode(w);
  try {
    c->send(std::move(out));
  } catch (const Error& e) {
    log_->warn("error reply to request {} not sent: {}", request_id, e.what());
  }
}

void Communicator::on_message_refused(const std::shared_ptr<Connection>& c,
                                      std::span<const std::byte> first,
                                      const std::string& reason) {
  try {
    Reader r(first);
    if (static_cast<RmiCode>(r.u8()) != RmiCode::call) return;
    send_error(c, r.u32(), ErrorKind::overloaded, "planet::MessageTooLarge", reason);
  } catch (const Error&) {
    // Too little of the message arrived to name the request; the caller's deadline ends it.
  }
}

void Communicator::on_open(const std::shared_ptr<Connection>&) {}

void Communicator::on_close(const std::shared_ptr<Connection>& c, const Error& reason) {
  streams_->on_close(*c, reason);
  std::vector<Completion> failed;
  {
    std::lock_guard lock(pending_mutex_);
    for (auto it = pending_.begin(); it != pending_.end();) {
      if (it->second.connection_id != c->id()) {
        ++it;
      } else if (it->second.retry_over && !closing_) {
        // Idempotent: waits for the Peer's next connection (resend_waiting).
        it->second.connection_id = 0;
        ++it;
      } else {
        failed.push_back(std::move(it->second.done));
        it = pending_.erase(it);
      }
    }
  }
  if (failed.empty()) return;
  const Error error(ErrorKind::disconnected,
                    fmt::format("connection to {} lost: {}", c->describe(), reason.what()));
  for (auto& done : failed) done(std::make_exception_ptr(error), nullptr);
}

}  // namespace icars::planet
