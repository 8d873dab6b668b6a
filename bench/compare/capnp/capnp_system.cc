// Cap'n Proto RPC 0.9 behind the icars-compare contract (system.h), written as a Cap'n Proto user
// would: the interfaces of bench.capnp; a server of one KJ event loop (EzRpcServer) offering
// Bench as its bootstrap capability; on the client side one KJ event loop per process, on a
// thread of its own, carrying every connection (KJ's event loops are single-threaded, and the
// contract's callers are several threads), which the callers hand their calls to with
// kj::Executor::executeSync; pipelined calls as promise chains; events as calls the server makes
// on the Subscriber capability each subscriber passed to it over its own connection. Cap'n Proto
// has no reconnection: try_call connects again when the connection is lost, as a user would.
#include <capnp/ez-rpc.h>
#include <capnp/message.h>
#include <capnp/rpc-twoparty.h>
#include <compare_capnp/bench.capnp.h>
#include <kj/async-io.h>
#include <kj/async.h>
#include <kj/exception.h>
#include <kj/time.h>
#include <kj/timer.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <functional>
#include <future>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "system.h"

namespace icars::bench {
namespace {

namespace schema = ::icars::compare_capnp;
using VatId = capnp::rpc::twoparty::VatId;

// Capability::Server, the base of every server class, has no virtual destructor by design: a
// server object is owned through kj::Own only, whose disposer destroys it as the type kj::heap
// made it with. GCC's -Wnon-virtual-dtor would flag each server class of this file.
#pragma GCC diagnostic ignored "-Wnon-virtual-dtor"

// What a TwoPartyVatNetwork accepts, on both ends. Cap'n Proto's default traversal limit, 8 Mi
// words (64 MiB), bounds the size of a message received and, in 0.9, of one sent (the network
// refuses to send what its own limit would reject); the 256 MiB echo needs more. 1 GiB is twice
// the largest Data blob Cap'n Proto can hold (2^29 bytes).
capnp::ReaderOptions reader_options() {
  capnp::ReaderOptions options;
  options.traversalLimitInWords = (std::uint64_t{1} << 30) / sizeof(capnp::word);
  return options;
}

std::string address(const std::string& host, std::uint16_t port) {
  return host + ":" + std::to_string(port);
}

std::string describe(const kj::Exception& e) { return e.getDescription().cStr(); }

// A failure inside the event loop, as KJ reports one.
[[noreturn]] void fail(const std::string& message) {
  kj::throwFatalException(kj::Exception(kj::Exception::Type::FAILED, __FILE__, __LINE__,
                                        kj::heapString(message.c_str(), message.size())));
}

capnp::Data::Reader as_data(const Bytes& bytes) {
  return {reinterpret_cast<const kj::byte*>(bytes.data()), bytes.size()};
}

Bytes to_bytes(capnp::Data::Reader data) {
  const auto* first = reinterpret_cast<const std::byte*>(data.begin());
  return Bytes(first, first + data.size());
}

// ---------------------------------------------------------------------------------------------
// Server

// The subscribers the server publishes to; one is dropped when a call to it fails (its
// connection is gone).
class EventHub final : private kj::TaskSet::ErrorHandler {
 public:
  void add(schema::Subscriber::Client subscriber) {
    subscribers_.emplace(next_id_++, kj::mv(subscriber));
  }

  // Sends the calls; their answers arrive later, each settling one task.
  void publish(std::int32_t count, std::uint32_t payload_size) {
    for (std::int32_t i = 0; i < count; ++i) {
      const std::uint64_t seq = next_seq_++;
      for (auto& [id, subscriber] : subscribers_) {
        auto request = subscriber.eventRequest();
        request.setSeq(seq);
        request.initPayload(payload_size);
        deliveries_.add(request.send().ignoreResult().catch_(
            [this, id = id](kj::Exception&&) { subscribers_.erase(id); }));
      }
    }
  }

 private:
  void taskFailed(kj::Exception&& exception) override {
    // Every delivery catches its own failure: this is a bug.
    kj::throwFatalException(kj::mv(exception));
  }

  std::map<std::uint64_t, schema::Subscriber::Client> subscribers_;
  std::uint64_t next_id_ = 0;
  std::uint64_t next_seq_ = 0;
  kj::TaskSet deliveries_{*this};
};

class BenchServer final : public schema::Bench::Server {
 protected:
  kj::Promise<void> echoInt(EchoIntContext context) override {
    context.getResults().setX(context.getParams().getX());
    return kj::READY_NOW;
  }

  kj::Promise<void> sizeOf(SizeOfContext context) override {
    context.getResults().setSize(context.getParams().getData().size());
    return kj::READY_NOW;
  }

  kj::Promise<void> echoBytes(EchoBytesContext context) override {
    context.getResults().setData(context.getParams().getData());
    context.releaseParams();  // the request's bytes, now copied into the answer
    return kj::READY_NOW;
  }

  kj::Promise<void> subscribe(SubscribeContext context) override {
    hub_.add(context.getParams().getSubscriber());
    return kj::READY_NOW;
  }

  kj::Promise<void> publish(PublishContext context) override {
    const auto params = context.getParams();
    if (params.getCount() < 0) fail("publish: negative event count");
    hub_.publish(params.getCount(), params.getPayloadSize());
    return kj::READY_NOW;
  }

 private:
  EventHub hub_;
};

// ---------------------------------------------------------------------------------------------
// Client

// A KJ event loop on a thread of its own, carrying the client side of a process: every Cap'n
// Proto object of a connection is made, used and destroyed on this thread. Other threads hand it
// work with run(), which blocks them until the work is done; several may do so at once.
class EventLoopThread {
 public:
  EventLoopThread() {
    std::promise<void> started;
    auto running = started.get_future();
    thread_ = std::thread([this, &started] { loop(started); });
    try {
      running.get();
    } catch (...) {
      thread_.join();
      throw;
    }
  }

  ~EventLoopThread() {
    executor_->executeSync([this] {
      stop_->fulfill();
      stop_ = nullptr;
    });
    thread_.join();
  }

  EventLoopThread(const EventLoopThread&) = delete;
  EventLoopThread& operator=(const EventLoopThread&) = delete;

  // Runs f() on the loop's thread and waits for it and, when it returns a promise, for that
  // promise; returns its result. A failure becomes std::runtime_error naming `what`.
  template <class F>
  auto run(const std::string& what, F&& f) {
    try {
      return executor_->executeSync(std::forward<F>(f));
    } catch (const kj::Exception& e) {
      throw std::runtime_error("capnp: " + what + ": " + describe(e));
    }
  }

  // On the loop's thread only.
  kj::AsyncIoProvider& io() const { return *io_; }

 private:
  void loop(std::promise<void>& started) {
    bool running = false;
    try {
      auto io = kj::setupAsyncIo();
      auto stop = kj::newPromiseAndFulfiller<void>();
      io_ = io.provider.get();
      stop_ = kj::mv(stop.fulfiller);
      executor_ = kj::getCurrentThreadExecutor().addRef();
      running = true;
      started.set_value();  // `started` is gone after this
      stop.promise.wait(io.waitScope);
    } catch (...) {
      if (running) throw;  // a bug: nothing in the loop throws out of it
      started.set_exception(std::current_exception());
    }
  }

  std::thread thread_;
  kj::Own<const kj::Executor> executor_;  // outlives the loop: usable until joined
  kj::AsyncIoProvider* io_ = nullptr;
  kj::Own<kj::PromiseFulfiller<void>> stop_;  // loop thread only
};

// One connection to a server, on the event-loop thread: the stream, its two-party network, an
// RPC system of the client side, and the server's Bench (its bootstrap capability). What
// TwoPartyClient holds, written out because in 0.9 TwoPartyClient takes no ReaderOptions (and
// EzRpcClient also makes an event loop of its own for its thread).
struct Connection {
  explicit Connection(kj::Own<kj::AsyncIoStream> connected)
      : stream(kj::mv(connected)),
        network(*stream, capnp::rpc::twoparty::Side::CLIENT, reader_options()),
        rpc(capnp::makeRpcClient(network)),
        bench(bootstrap()),
        watch(network.onDisconnect().then([this] { lost = true; }).eagerlyEvaluate(nullptr)) {}

  schema::Bench::Client bootstrap() {
    capnp::MallocMessageBuilder message;
    auto server = message.initRoot<VatId>();
    server.setSide(capnp::rpc::twoparty::Side::SERVER);
    return rpc.bootstrap(server).castAs<schema::Bench>();
  }

  kj::Own<kj::AsyncIoStream> stream;
  capnp::TwoPartyVatNetwork network;
  capnp::RpcSystem<VatId> rpc;
  schema::Bench::Client bench;
  bool lost = false;  // the peer disconnected: calls fail, a new connection is needed
  kj::Promise<void> watch;
};

// Connects to host:port; resolves once the server has answered for its bootstrap capability, so
// that connecting is not timed as the first call. On the event-loop thread.
kj::Promise<kj::Own<Connection>> connect(kj::AsyncIoProvider& io, const std::string& host,
                                         std::uint16_t port) {
  return io.getNetwork()
      .parseAddress(host.c_str(), port)
      .then([](kj::Own<kj::NetworkAddress> server) {
        return server->connect().attach(kj::mv(server));
      })
      .then([](kj::Own<kj::AsyncIoStream> stream) {
        auto connection = kj::heap<Connection>(kj::mv(stream));
        auto answered = connection->bench.whenResolved();
        return answered.then(
            [connection = kj::mv(connection)]() mutable { return kj::mv(connection); });
      });
}

// `count` echoInt calls with at most `window` unanswered: `window` chains of calls, each issuing
// its next call when its last is answered, all drawing on one counter. On the event-loop thread.
class EchoPipeline {
 public:
  static kj::Promise<void> run(schema::Bench::Client bench, std::int64_t count, int window) {
    auto pipeline = kj::heap<EchoPipeline>(kj::mv(bench), count);
    const auto chains = std::min<std::int64_t>(window, count);
    auto calls = kj::heapArrayBuilder<kj::Promise<void>>(static_cast<std::size_t>(chains));
    for (std::int64_t i = 0; i < chains; ++i) calls.add(pipeline->next());
    return kj::joinPromises(calls.finish()).attach(kj::mv(pipeline));
  }

  EchoPipeline(schema::Bench::Client bench, std::int64_t count)
      : bench_(kj::mv(bench)), count_(count) {}

 private:
  kj::Promise<void> next() {
    if (issued_ == count_) return kj::READY_NOW;
    const auto x = static_cast<std::int32_t>(issued_++ % std::numeric_limits<std::int32_t>::max());
    auto request = bench_.echoIntRequest();
    request.setX(x);
    return request.send().then([this, x](capnp::Response<schema::Bench::EchoIntResults> reply) {
      if (reply.getX() != x) {
        fail("pipelined echoInt(" + std::to_string(x) + ") answered " +
             std::to_string(reply.getX()));
      }
      return next();
    });
  }

  schema::Bench::Client bench_;
  const std::int64_t count_;
  std::int64_t issued_ = 0;
};

class CapnpClient final : public Client {
 public:
  CapnpClient(std::shared_ptr<EventLoopThread> loop, std::string host, std::uint16_t port)
      : loop_(std::move(loop)), host_(std::move(host)), port_(port) {
    loop_->run("connect to " + address(host_, port_) + " (is the server running?)",
               [this] { return reconnect(); });
  }

  ~CapnpClient() noexcept override {
    loop_->run("disconnect", [this] { connection_ = nullptr; });
  }

  CapnpClient(const CapnpClient&) = delete;
  CapnpClient& operator=(const CapnpClient&) = delete;

  std::int32_t call(std::int32_t x) override {
    return loop_->run("echoInt", [this, x] {
      auto request = bench().echoIntRequest();
      request.setX(x);
      return request.send().then(
          [](capnp::Response<schema::Bench::EchoIntResults> reply) { return reply.getX(); });
    });
  }

  std::uint64_t upload(const Bytes& data) override {
    return loop_->run("sizeOf", [this, &data] {
      auto request = bench().sizeOfRequest();
      request.setData(as_data(data));
      return request.send().then(
          [](capnp::Response<schema::Bench::SizeOfResults> reply) { return reply.getSize(); });
    });
  }

  Bytes echo(const Bytes& data) override {
    return loop_->run("echoBytes", [this, &data] {
      auto request = bench().echoBytesRequest();
      request.setData(as_data(data));
      return request.send().then([](capnp::Response<schema::Bench::EchoBytesResults> reply) {
        return to_bytes(reply.getData());
      });
    });
  }

  void pipeline(std::int64_t count, int window) override {
    if (count < 0 || window < 1) {
      throw std::invalid_argument("capnp pipeline: count must be >= 0 and window >= 1");
    }
    loop_->run("pipeline", [this, count, window] {
      return EchoPipeline::run(bench(), count, window);
    });
  }

  bool try_call() noexcept override {
    try {
      return loop_->run("try_call", [this] {
        return loop_->io().getTimer().timeoutAfter(1 * kj::SECONDS, attempt());
      });
    } catch (const std::exception&) {
      return false;
    }
  }

 private:
  // The rest runs on the event-loop thread.

  schema::Bench::Client& bench() {
    if (!connection_) fail("not connected to " + address(host_, port_));
    return connection_->bench;
  }

  // Replaces the connection (none, or a lost one) with a new one.
  kj::Promise<void> reconnect() {
    connection_ = nullptr;
    return connect(loop_->io(), host_, port_).then([this](kj::Own<Connection> connection) {
      connection_ = kj::mv(connection);
    });
  }

  // One echoInt, over a new connection when the last one is lost.
  kj::Promise<bool> attempt() {
    auto connected =
        connection_ && !connection_->lost ? kj::Promise<void>(kj::READY_NOW) : reconnect();
    return connected.then([this] {
      auto request = bench().echoIntRequest();
      request.setX(17);
      return request.send().then(
          [](capnp::Response<schema::Bench::EchoIntResults> reply) { return reply.getX() == 17; });
    });
  }

  std::shared_ptr<EventLoopThread> loop_;  // first member: the loop outlives the connection
  std::string host_;
  std::uint16_t port_;
  kj::Own<Connection> connection_;  // null after a failed reconnection
};

// What the subscriber capabilities count, shared by all of them.
struct EventTally {
  std::mutex mutex;
  std::condition_variable all_in;
  std::vector<std::int64_t> received;  // per subscriber
  std::int64_t expected = 0;           // per subscriber, over all publishes so far
  std::size_t complete = 0;            // subscribers that have received `expected`
  // Of the events of the current publish; unchecked after a timeout, when events of the earlier
  // publish may still arrive.
  std::optional<std::size_t> payload;
  std::string error;
};

class EventCounter final : public schema::Subscriber::Server {
 public:
  EventCounter(std::shared_ptr<EventTally> tally, std::size_t index)
      : tally_(std::move(tally)), index_(index) {}

 protected:
  kj::Promise<void> event(EventContext context) override {
    const auto params = context.getParams();
    const std::size_t size = params.getPayload().size();
    const std::lock_guard lock(tally_->mutex);
    if (tally_->payload && size != *tally_->payload && tally_->error.empty()) {
      tally_->error = "event " + std::to_string(params.getSeq()) + " carried " +
                      std::to_string(size) + " bytes instead of " +
                      std::to_string(*tally_->payload);
    }
    if (++tally_->received[index_] == tally_->expected &&
        ++tally_->complete == tally_->received.size()) {
      tally_->all_in.notify_all();
    }
    return kj::READY_NOW;
  }

 private:
  std::shared_ptr<EventTally> tally_;
  std::size_t index_;
};

class CapnpSubscribers final : public Subscribers {
 public:
  CapnpSubscribers(std::shared_ptr<EventLoopThread> loop, std::string host, std::uint16_t port)
      : loop_(std::move(loop)), host_(std::move(host)), port_(port) {}

  ~CapnpSubscribers() noexcept override {
    loop_->run("disconnect", [this] {
      subscribers_.clear();
      publisher_ = nullptr;
    });
  }

  CapnpSubscribers(const CapnpSubscribers&) = delete;
  CapnpSubscribers& operator=(const CapnpSubscribers&) = delete;

  // Subscribes `count` connections, each passing a Subscriber of its own; returns once the server
  // has registered them all (subscribe is answered once registered).
  void subscribe(int count) {
    const auto n = static_cast<std::size_t>(std::max(count, 0));
    tally_->received.assign(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
      loop_->run("subscribe to " + address(host_, port_), [this, i] {
        return connect(loop_->io(), host_, port_).then([this, i](kj::Own<Connection> connection) {
          auto request = connection->bench.subscribeRequest();
          request.setSubscriber(kj::heap<EventCounter>(tally_, i));
          subscribers_.push_back(kj::mv(connection));
          return request.send().ignoreResult();
        });
      });
    }
    loop_->run("connect to " + address(host_, port_), [this] {
      return connect(loop_->io(), host_, port_).then([this](kj::Own<Connection> connection) {
        publisher_ = kj::mv(connection);
      });
    });
  }

  void publish_and_wait(int events, std::size_t payload,
                        std::chrono::milliseconds timeout) override {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    if (events < 0 || payload > std::numeric_limits<std::uint32_t>::max()) {
      throw std::invalid_argument("capnp publish_and_wait: events < 0 or payload over 4 GiB");
    }
    {
      const std::lock_guard lock(tally_->mutex);
      tally_->expected += events;
      if (!timed_out_) {
        tally_->payload = payload;
      }
      tally_->complete = static_cast<std::size_t>(
          std::count_if(tally_->received.begin(), tally_->received.end(),
                        [&](std::int64_t r) { return r >= tally_->expected; }));
    }
    loop_->run("publish", [&] {
      auto request = publisher_->bench.publishRequest();
      request.setCount(events);
      request.setPayloadSize(static_cast<std::uint32_t>(payload));
      return request.send().ignoreResult();
    });

    std::unique_lock lock(tally_->mutex);
    const bool done = tally_->all_in.wait_until(lock, deadline, [&] {
      return tally_->complete == tally_->received.size() || !tally_->error.empty();
    });
    if (!tally_->error.empty()) {
      throw std::runtime_error("capnp: subscriber: " + tally_->error);
    }
    if (!done) {
      timed_out_ = true;
      tally_->payload.reset();
      throw std::runtime_error("capnp: " + std::to_string(tally_->complete) + " of " +
                               std::to_string(tally_->received.size()) +
                               " subscribers received all " + std::to_string(events) +
                               " events within " + std::to_string(timeout.count()) + " ms");
    }
  }

 private:
  std::shared_ptr<EventLoopThread> loop_;  // first member: the loop outlives the connections
  std::string host_;
  std::uint16_t port_;
  std::shared_ptr<EventTally> tally_ = std::make_shared<EventTally>();
  std::vector<kj::Own<Connection>> subscribers_;  // event-loop thread only
  kj::Own<Connection> publisher_;                 // event-loop thread only
  bool timed_out_ = false;
};

// ---------------------------------------------------------------------------------------------

class CapnpSystem final : public System {
 public:
  std::string name() const override { return "capnp"; }

  void serve(std::uint16_t port, const std::function<void()>& ready) override {
    const auto where = address("127.0.0.1", port);
    try {
      capnp::EzRpcServer server(kj::heap<BenchServer>(), "127.0.0.1", port, reader_options());
      auto& wait_scope = server.getWaitScope();
      server.getPort().wait(wait_scope);  // throws when it cannot listen
      ready();
      kj::NEVER_DONE.wait(wait_scope);  // serves until the process is killed
    } catch (const kj::Exception& e) {
      throw std::runtime_error("capnp: serve on " + where + ": " + describe(e));
    }
  }

  std::unique_ptr<Client> connect(const std::string& host, std::uint16_t port) override {
    return std::make_unique<CapnpClient>(loop(), host, port);
  }

  std::unique_ptr<Subscribers> subscribe(const std::string& host, std::uint16_t port,
                                         int count) override {
    auto subscribers = std::make_unique<CapnpSubscribers>(loop(), host, port);
    subscribers->subscribe(count);  // on failure, the destructor cleans up
    return subscribers;
  }

 private:
  // The client side's event loop, started at the first connection: a server process never
  // starts it.
  std::shared_ptr<EventLoopThread> loop() {
    const std::lock_guard lock(mutex_);
    if (!loop_) loop_ = std::make_shared<EventLoopThread>();
    return loop_;
  }

  std::mutex mutex_;
  std::shared_ptr<EventLoopThread> loop_;
};

}  // namespace

std::unique_ptr<System> make_capnp() { return std::make_unique<CapnpSystem>(); }

}  // namespace icars::bench
