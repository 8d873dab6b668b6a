// PLANET communicator: one process's endpoint of the middleware.
//
// A Communicator owns the event loop (one asio io_context run by one thread it starts), the
// Connection Manager (server and client roles), the ObjectAdapter that dispatches incoming
// requests to servants, and the pending-request table that matches replies to calls. Proxies
// (proxy.h) send calls through it. Everything it calls back (servants, listeners, async
// completions without their own executor) runs on its io thread, which must never block —
// except for messages larger than 1 MiB: those CALLs, NOTIFYs and REPLYs are decoded and
// dispatched on the communicator's bulk thread (started on the first one), so that copying
// hundreds of megabytes never holds up the small calls on the same connection. A NOTIFY that
// completes on a connection while a large NOTIFY of it waits on the bulk thread follows it
// there, so one-way messages (events) are handled in the order they came. A servant that
// takes large arguments may therefore run concurrently with the servants on the io thread.
#pragma once

#include <asio/io_context.hpp>
#include <asio/thread_pool.hpp>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <exception>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "icars/planet/connection.h"
#include "icars/planet/connection_manager.h"
#include "icars/planet/remote.h"
#include "icars/planet/detail/unique_function.h"
#include "icars/planet/rmi_message.h"
#include "icars/planet/security.h"
#include "icars/planet/servant.h"

namespace spdlog {
class logger;
}

namespace icars::planet {

namespace detail {
class StreamTable;
}

struct CommunicatorOptions {
  ConnectionOptions connection;
  std::chrono::milliseconds call_timeout{10000};  // default deadline of a two-way call
  std::size_t max_pending_calls = 65536;  // two-way calls awaiting replies; more fail `overloaded`
  TlsOptions tls;     // TLS for listeners and links (security.h); automatic by default
  std::string token;  // sent in CONNECT to authenticate this endpoint to servers
  // Who may connect to this endpoint's listeners and what each may call; null: anyone, anything.
  std::shared_ptr<const AccessPolicy> access;
  // PUN, the PLANET unique name: the name this endpoint announces in CONNECT (as a client) and
  // CONNECT_ACK (as a server), which the peer keeps as Connection::peer_pun(). It also names the
  // endpoint in the remote references it hands out (ObjectRef::pun), so that a receiver finds
  // the connection that leads to the object (resolve()), and a Publisher tells subscribers
  // apart by it. The ICARS paper (4.1.1) uses the abbreviation without spelling it out and
  // describes the field as the endpoint's unique identifier, "<ip>:<port>". PLANET does not
  // check that it is unique: give every endpoint its own. Empty (the default): listen() sets
  // "<address>:<port>" of the first listener; an endpoint that never listens announces its
  // socket's local "<ip>:<port>" on each connection and hands out references with an empty PUN
  // ("the sender"). At most 1008 bytes, less the token's length + 4 when a token is set
  // (docs/protocol.md 3.1).
  std::string pun;
  std::string name = "planet";                   // logger name
  std::shared_ptr<spdlog::logger> logger;        // default: a stderr logger at "info"
};

class Communicator final : private MessageHandler {
 public:
  explicit Communicator(CommunicatorOptions options = {});
  ~Communicator() override;  // closes every connection and joins the io thread
  Communicator(const Communicator&) = delete;
  Communicator& operator=(const Communicator&) = delete;

  ObjectAdapter& adapter() { return adapter_; }
  ConnectionManager& connections() { return *manager_; }
  asio::io_context& io() { return *io_; }
  const std::shared_ptr<asio::io_context>& shared_io() const { return io_; }
  asio::io_context::executor_type executor() { return io_->get_executor(); }
  bool in_io_thread() const { return io_thread_id_ == std::this_thread::get_id(); }
  spdlog::logger& log() { return *log_; }
  // The lock-step activity this endpoint reports its work to (ConnectionOptions::activity), or
  // null. Work handed from the io thread to another runs under a hold of it.
  const std::shared_ptr<Activity>& activity() const { return options_.connection.activity; }
  const CommunicatorOptions& options() const { return options_; }

  // Server role; see ConnectionManager::listen.
  std::uint16_t listen(const std::string& address, std::uint16_t port);
  // Client role; see ConnectionManager::connect.
  std::shared_ptr<Peer> connect(const std::string& host, std::uint16_t port,
                                ReconnectPolicy policy = {});

  // --- Remote references ---
  // A reference to the servant at `path` of this endpoint, to pass to a peer; its PUN is this
  // endpoint's (empty, meaning "the sender", until a PUN is configured or listen() ran).
  // Throws std::invalid_argument when no servant is registered there.
  ObjectRef reference(const std::string& path) const;
  template <class I>
  Ref<I> reference(const std::string& path) const {
    ObjectRef ref = reference(path);
    if (ref.type_id != I::type_id) {
      throw std::invalid_argument("the servant at " + path + " implements " + ref.type_id +
                                  ", not " + std::string(I::type_id));
    }
    return Ref<I>(std::move(ref));
  }
  // The link to reach the object `ref` names, given the link it arrived over: `via` itself when
  // the PUN is empty or is the PUN of via's peer; else an open connection to a peer with that
  // PUN. Throws Error(refused) otherwise: connect to that endpoint first.
  std::shared_ptr<Link> resolve(const ObjectRef& ref, const std::shared_ptr<Link>& via);

  // --- Request Manager (used by Proxy) ---
  using Completion = detail::UniqueFunction<void(std::exception_ptr, Reader*)>;
  // Assigns a request id (written into `request` at kRequestIdOffset), registers `done` in the
  // pending-request table and sends the request over `link`. `done` runs exactly once: with the
  // REPLY's reader, or with the error (disconnected, overloaded, timeout, remote exception).
  // It may run inline when the link is down. Returns the request id (0 when `done` already ran
  // because the call could not be registered or sent at all).
  //
  // With CallMode::idempotent over a Peer, a call that finds the link down, or whose connection
  // closes before the reply, stays in the table and is sent again, with the same request id,
  // each time the Peer reconnects, until it is answered, its deadline passes (timeout),
  // cancel_call ends it or the communicator is destroyed (disconnected). A late reply over an
  // earlier connection is ignored. Over any other link (a server-side Connection, which never
  // comes back) both modes fail with disconnected. Thread-safe.
  std::uint32_t start_call(const std::shared_ptr<Link>& link, std::vector<std::byte> request,
                           std::chrono::milliseconds timeout, CallMode mode, Completion done);
  // Completes a pending call (sent, or waiting for its link) with `error` if it is still
  // pending; false if it already completed. A reply that arrives later is ignored.
  bool cancel_call(std::uint32_t request_id, const Error& error);
  // A synchronous caller waiting for the reply to `request_id` reads it on its own thread when
  // the connection of `link` is idle (Connection::read_directly), so the reply does not pass
  // through the io thread; returns at once when it cannot, as soon as anything else arrives,
  // when `answered()` turns true or at `until`. The call completes as usual either way (its
  // completion runs on this thread when the reply was read here).
  void read_reply(const Link& link, std::uint32_t request_id,
                  std::chrono::steady_clock::time_point until, const std::function<bool()>& answered);
  // Sends a NOTIFY; throws Error(disconnected/overloaded) when it cannot be queued.
  void send_oneway(const Link& link, std::vector<std::byte> request);
  std::size_t pending_calls() const;  // sent and awaiting replies, or waiting for their link

  // Internal: the stream channels (stream.h).
  detail::StreamTable& stream_table() { return *streams_; }

 private:
  struct Pending {
    std::uint64_t connection_id = 0;  // where it was sent; 0 while it waits for its Peer
    std::chrono::steady_clock::time_point deadline;
    Completion done;
    std::shared_ptr<Peer> retry_over;  // idempotent calls over a Peer: re-sent on reconnection
    std::vector<std::byte> request;    // kept to be sent again (retry_over set)
  };

  void on_message(const std::shared_ptr<Connection>& c, std::span<const std::byte> m) override;
  void handle_message(const std::shared_ptr<Connection>& c, std::span<const std::byte> m);
  void handle_message(const std::shared_ptr<Connection>& c, Reader& r);
  // Hands a message, in the blocks it was assembled in, to the bulk thread (bulk_mutex_ held);
  // a NOTIFY is counted in bulk_pending_ until handled.
  void post_bulk(std::unique_lock<std::mutex>& lock, const std::shared_ptr<Connection>& c,
                 std::vector<std::vector<std::byte>> blocks, bool notify);
  void on_large_message(const std::shared_ptr<Connection>& c,
                        std::vector<std::vector<std::byte>> blocks) override;
  void on_message_refused(const std::shared_ptr<Connection>& c, std::span<const std::byte> first,
                          const std::string& reason) override;
  void on_open(const std::shared_ptr<Connection>& c) override;
  void on_close(const std::shared_ptr<Connection>& c, const Error& reason) override;

  void dispatch_request(const std::shared_ptr<Connection>& c, Reader& r, bool oneway);
  void finish_async(const std::shared_ptr<Connection>& c, bool oneway, std::uint32_t request_id,
                    std::string path, std::string method, Servant::AsyncResult work,
                    ObjectAdapter::Dispatch call);
  void report_failure(const std::shared_ptr<Connection>& c, bool oneway, std::uint32_t request_id,
                      std::string_view path, std::string_view method,
                      const std::exception_ptr& failure);
  void send_reply(const std::shared_ptr<Connection>& c, std::uint32_t request_id,
                  std::string_view path, std::vector<std::byte> reply);
  void send_error(const std::shared_ptr<Connection>& c, std::uint32_t request_id, ErrorKind kind,
                  const std::string& type_id, const std::string& message,
                  const Properties& properties = {});
  void complete(const Connection& from, std::uint32_t request_id, std::exception_ptr error,
                Reader* result);
  void sweep_deadlines();
  // Idempotent calls (Pending::retry_over): sends a waiting call if its Peer is up now; on a
  // failed send, puts it back to wait or fails it.
  void send_waiting(std::uint32_t request_id);
  void resend_waiting(const Peer& peer);
  void on_send_failed(std::uint32_t request_id, std::uint64_t connection_id, const Error& error);

  CommunicatorOptions options_;
  std::shared_ptr<spdlog::logger> log_;
  std::shared_ptr<asio::io_context> io_;
  std::unique_ptr<asio::executor_work_guard<asio::io_context::executor_type>> work_;
  std::unique_ptr<ConnectionManager> manager_;
  ObjectAdapter adapter_;
  std::unique_ptr<detail::StreamTable> streams_;
  std::unique_ptr<asio::steady_timer> sweep_timer_;

  mutable std::mutex pending_mutex_;
  std::unordered_map<std::uint32_t, Pending> pending_;
  std::uint32_t next_request_id_ = 1;
  bool closing_ = false;  // the destructor started: no call waits for its link any more

  std::thread io_thread_;
  std::thread::id io_thread_id_;

  std::mutex bulk_mutex_;
  std::unique_ptr<asio::thread_pool> bulk_;  // large messages (on_large_message); lazily started
  std::uint64_t activity_queue_ = 0;         // the io thread as a queue of the activity
  // NOTIFYs of each connection on the bulk thread, not yet handled: later NOTIFYs of that
  // connection follow them there. bulk_notifies_ is their total, read without the lock.
  std::unordered_map<const Connection*, std::size_t> bulk_pending_;
  std::atomic<std::size_t> bulk_notifies_{0};
};

}  // namespace icars::planet
