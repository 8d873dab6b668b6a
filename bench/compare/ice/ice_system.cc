// ZeroC Ice 3.7 (C++11 mapping) behind the icars-compare contract (system.h), written as an Ice
// user would: the Slice interfaces of Bench.ice, one communicator per process, one connection per
// Client (its own connection id), AMI callbacks for the pipeline, and events sent as oneway calls
// to callback servants over each subscriber's own bidirectional connection. "ice-tls" is the
// same over IceSSL's "ssl" endpoints (ice_settings).
#include <Ice/Ice.h>
#include <compare_ice/Bench.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "system.h"

namespace icars::bench {
namespace {

using ByteView = std::pair<const Ice::Byte*, const Ice::Byte*>;  // Slice ["cpp:array"]

// Ice.MessageSizeMax=0 lifts Ice's 1 MiB limit on a message (the workloads send 256 MiB). All
// else is Ice's default, in client and server alike: one thread in each of the client and server
// thread pools (dispatch of all connections, and on the client the replies and the subscriber
// callbacks, is serialized), client ACM closing a connection idle for 60 s, and
// Ice.RetryIntervals=0: one immediate retry when a connection fails (after the request was sent
// only for idempotent operations), after which the call fails; the next call reconnects.
//
// With `tls`, the IceSSL plugin (libIceSSL++11, loaded by the communicator) for "ssl" endpoints:
// the server presents server.pem (PEM files work with IceSSL's OpenSSL engine) and requests no
// client certificate (IceSSL.VerifyPeer=0); the client checks the server's certificate against
// ca.pem (IceSSL.VerifyPeer's default, 2) and its name against the host it connects to
// (IceSSL.CheckCertName=1; off by default in Ice). Protocols and ciphers are IceSSL's defaults.
enum class Side { server, client };

Ice::InitializationData ice_settings(const std::optional<TlsFiles>& tls, Side side) {
  Ice::InitializationData init;
  init.properties = Ice::createProperties();
  init.properties->setProperty("Ice.MessageSizeMax", "0");
  if (tls) {
    init.properties->setProperty("Ice.Plugin.IceSSL", "IceSSL:createIceSSL");
    if (side == Side::server) {
      init.properties->setProperty("IceSSL.CertFile", tls->certificate());
      init.properties->setProperty("IceSSL.KeyFile", tls->private_key());
      init.properties->setProperty("IceSSL.VerifyPeer", "0");
    } else {
      init.properties->setProperty("IceSSL.CAs", tls->ca());
      init.properties->setProperty("IceSSL.CheckCertName", "1");
    }
  }
  return init;
}

// The endpoint transport: Ice's "tcp", or IceSSL's "ssl".
std::string transport(const std::optional<TlsFiles>& tls) { return tls ? "ssl" : "tcp"; }

ByteView view_of(const Bytes& data) {
  const auto* first = reinterpret_cast<const Ice::Byte*>(data.data());
  return {first, first + data.size()};
}

[[noreturn]] void throw_ice_error(const std::string& what, const Ice::Exception& e) {
  throw std::runtime_error("ice: " + what + ": " + e.what());
}

// Runs f, turning an Ice exception into std::runtime_error with Ice's description of it.
template <class F>
auto ice_call(const std::string& what, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const Ice::Exception& e) {
    throw_ice_error(what, e);
  }
}

[[noreturn]] void rethrow_ice_error(const std::string& what, const std::exception_ptr& error) {
  try {
    std::rethrow_exception(error);
  } catch (const Ice::Exception& e) {
    throw_ice_error(what, e);
  }
}

// Closes a connection unless it is already gone; never blocks, never throws.
void close_gracefully(const std::shared_ptr<Ice::Connection>& connection) noexcept {
  if (connection) {
    connection->close(Ice::ConnectionClose::Gracefully);
  }
}

// ---------------------------------------------------------------------------------------------
// Server

// The subscribers the server publishes to, each a oneway proxy fixed to its own connection, and
// dropped when that connection closes.
class SubscriberList {
 public:
  void add(const std::shared_ptr<Ice::Connection>& connection,
           std::shared_ptr<icarsbench::SubscriberPrx> subscriber) {
    const std::lock_guard lock(mutex_);
    entries_.push_back({connection, std::move(subscriber)});
  }

  void remove(const std::shared_ptr<Ice::Connection>& connection) {
    const std::lock_guard lock(mutex_);
    std::erase_if(entries_, [&](const Entry& e) { return e.connection == connection; });
  }

  std::vector<std::shared_ptr<icarsbench::SubscriberPrx>> snapshot() const {
    const std::lock_guard lock(mutex_);
    std::vector<std::shared_ptr<icarsbench::SubscriberPrx>> subscribers;
    subscribers.reserve(entries_.size());
    for (const auto& e : entries_) {
      subscribers.push_back(e.subscriber);
    }
    return subscribers;
  }

 private:
  struct Entry {
    std::shared_ptr<Ice::Connection> connection;
    std::shared_ptr<icarsbench::SubscriberPrx> subscriber;
  };
  mutable std::mutex mutex_;
  std::vector<Entry> entries_;
};

class BenchServant final : public icarsbench::Bench {
 public:
  int echoInt(int x, const Ice::Current&) override { return x; }

  long long sizeOf(ByteView data, const Ice::Current&) override { return data.second - data.first; }

  EchoBytesMarshaledResult echoBytes(ByteView data, const Ice::Current& current) override {
    return {data, current};
  }

  void subscribe(std::shared_ptr<icarsbench::SubscriberPrx> subscriber,
                 const Ice::Current& current) override {
    if (!subscriber || !current.con) {
      throw std::invalid_argument("subscribe needs a subscriber proxy, called over a connection");
    }
    // The subscriber's adapter has no endpoints: it is reached over the connection it called on.
    subscribers_->add(current.con, subscriber->ice_fixed(current.con)->ice_oneway());
    current.con->setCloseCallback(
        [subscribers = subscribers_](const std::shared_ptr<Ice::Connection>& connection) {
          subscribers->remove(connection);
        });
  }

  void publish(int count, int payloadSize, const Ice::Current&) override {
    if (count < 0 || payloadSize < 0) {
      throw std::invalid_argument("publish: negative count or payload size");
    }
    const Ice::ByteSeq payload(static_cast<std::size_t>(payloadSize));
    const ByteView view{payload.data(), payload.data() + payload.size()};
    const auto subscribers = subscribers_->snapshot();
    for (int seq = 0; seq < count; ++seq) {
      for (const auto& subscriber : subscribers) {
        // An asynchronous oneway call marshals the event and queues it on the subscriber's
        // connection without blocking this dispatch thread. It fails only when that connection
        // closes, and the close callback then drops the subscriber.
        subscriber->eventAsync(seq, view, nullptr);
      }
    }
  }

 private:
  std::shared_ptr<SubscriberList> subscribers_ = std::make_shared<SubscriberList>();
};

// ---------------------------------------------------------------------------------------------
// Client

// The process's one Ice communicator for clients and subscribers: created on first use (a server
// process never starts it) and destroyed with the System and the last Client or Subscribers.
class ClientRuntime {
 public:
  explicit ClientRuntime(const std::optional<TlsFiles>& tls)
      : ice_(ice_settings(tls, Side::client)), transport_(transport(tls)) {}

  const std::shared_ptr<Ice::Communicator>& communicator() const { return ice_.communicator(); }

  // A proxy to the server's Bench object on a connection of its own, named `kind`<N>, which
  // this connects before returning.
  std::shared_ptr<icarsbench::BenchPrx> bench(const std::string& host, std::uint16_t port,
                                              const std::string& kind) {
    const auto where = "bench:" + transport_ + " -h \"" + host + "\" -p " + std::to_string(port);
    const auto id = kind + std::to_string(next_connection_.fetch_add(1));
    return ice_call("connect to " + where, [&] {
      auto bench = Ice::checkedCast<icarsbench::BenchPrx>(
          ice_.communicator()->stringToProxy(where)->ice_connectionId(id));
      if (!bench) {
        throw std::runtime_error("ice: " + where + " is not a Bench object");
      }
      return bench;
    });
  }

 private:
  Ice::CommunicatorHolder ice_;
  std::string transport_;
  std::atomic<std::uint64_t> next_connection_{0};
};

// `count` asynchronous echoInt calls on one proxy with at most `window` unanswered. Each answer
// issues the next call from the Ice client thread that delivered it, so the window stays full
// without waking the caller, who waits for the last answer.
class EchoPipeline {
 public:
  EchoPipeline(std::shared_ptr<icarsbench::BenchPrx> bench, std::int64_t count)
      : bench_(std::move(bench)), count_(count) {}

  void run(int window) {
    const std::int64_t first = std::min<std::int64_t>(window, count_);
    {
      const std::lock_guard lock(mutex_);
      next_ = first;
    }
    for (std::int64_t i = 0; i < first; ++i) {
      send(i);
    }
    // Once every issued call is answered and no more will be, no callback touches *this.
    std::unique_lock lock(mutex_);
    done_.wait(lock, [&] { return answered_ == next_; });
    if (error_) {
      rethrow_ice_error("pipeline", error_);
    }
  }

 private:
  void send(std::int64_t i) {
    const auto x = static_cast<std::int32_t>(i);
    try {
      bench_->echoIntAsync(
          x,
          [this, x](std::int32_t reply) {
            answer(reply == x ? nullptr
                              : std::make_exception_ptr(std::runtime_error(
                                    "ice: pipeline: echoInt(" + std::to_string(x) + ") answered " +
                                    std::to_string(reply))));
          },
          [this](std::exception_ptr e) { answer(std::move(e)); });
    } catch (...) {
      answer(std::current_exception());
    }
  }

  void answer(std::exception_ptr e) {
    std::int64_t more = -1;
    {
      const std::lock_guard lock(mutex_);
      if (e && !error_) {
        error_ = std::move(e);
      }
      ++answered_;
      if (!error_ && next_ < count_) {
        more = next_++;
      } else if (answered_ == next_) {
        done_.notify_one();
      }
    }
    if (more >= 0) {
      send(more);
    }
  }

  std::shared_ptr<icarsbench::BenchPrx> bench_;
  const std::int64_t count_;
  std::mutex mutex_;
  std::condition_variable done_;
  std::int64_t next_ = 0;  // calls issued
  std::int64_t answered_ = 0;
  std::exception_ptr error_;
};

class IceClient final : public Client {
 public:
  IceClient(std::shared_ptr<ClientRuntime> runtime, std::shared_ptr<icarsbench::BenchPrx> bench)
      : runtime_(std::move(runtime)),
        bench_(std::move(bench)),
        quick_bench_(bench_->ice_invocationTimeout(1000)) {}

  ~IceClient() override { close_gracefully(bench_->ice_getCachedConnection()); }

  IceClient(const IceClient&) = delete;
  IceClient& operator=(const IceClient&) = delete;

  std::int32_t call(std::int32_t x) override {
    return ice_call("echoInt", [&] { return bench_->echoInt(x); });
  }

  std::uint64_t upload(const Bytes& data) override {
    return static_cast<std::uint64_t>(
        ice_call("sizeOf", [&] { return bench_->sizeOf(view_of(data)); }));
  }

  Bytes echo(const Bytes& data) override {
    const auto reply = ice_call("echoBytes", [&] { return bench_->echoBytes(view_of(data)); });
    const auto* first = reinterpret_cast<const std::byte*>(reply.data());
    return Bytes(first, first + reply.size());
  }

  void pipeline(std::int64_t count, int window) override {
    if (window < 1) {
      throw std::invalid_argument("pipeline: window must be at least 1");
    }
    if (count > 0) {
      EchoPipeline(bench_, count).run(window);
    }
  }

  bool try_call() noexcept override {
    try {
      return quick_bench_->echoInt(1) == 1;
    } catch (...) {
      return false;
    }
  }

 private:
  std::shared_ptr<ClientRuntime> runtime_;  // first member: the communicator outlives the proxies
  std::shared_ptr<icarsbench::BenchPrx> bench_;
  std::shared_ptr<icarsbench::BenchPrx> quick_bench_;  // same connection, gives up after 1 s
};

// What the subscriber servants count, shared by all of them.
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

class EventCounter final : public icarsbench::Subscriber {
 public:
  EventCounter(std::shared_ptr<EventTally> tally, std::size_t index)
      : tally_(std::move(tally)), index_(index) {}

  void event(int seq, ByteView payload, const Ice::Current&) override {
    const auto size = static_cast<std::size_t>(payload.second - payload.first);
    const std::lock_guard lock(tally_->mutex);
    if (tally_->payload && size != *tally_->payload && tally_->error.empty()) {
      tally_->error = "event " + std::to_string(seq) + " carried " + std::to_string(size) +
                      " bytes instead of " + std::to_string(*tally_->payload);
    }
    if (++tally_->received[index_] == tally_->expected &&
        ++tally_->complete == tally_->received.size()) {
      tally_->all_in.notify_all();
    }
  }

 private:
  std::shared_ptr<EventTally> tally_;
  std::size_t index_;
};

class IceSubscribers final : public Subscribers {
 public:
  explicit IceSubscribers(std::shared_ptr<ClientRuntime> runtime)
      : runtime_(std::move(runtime)),
        // No endpoints: the servants are reached only over the subscribers' own connections.
        adapter_(ice_call("createObjectAdapter",
                          [&] { return runtime_->communicator()->createObjectAdapter(""); })) {
    adapter_->activate();
  }

  ~IceSubscribers() override {
    for (const auto& connection : connections_) {
      close_gracefully(connection);
    }
    if (publisher_) {
      close_gracefully(publisher_->ice_getCachedConnection());
    }
    adapter_->destroy();  // waits for running event dispatches, which use tally_
  }

  IceSubscribers(const IceSubscribers&) = delete;
  IceSubscribers& operator=(const IceSubscribers&) = delete;

  // Subscribes `count` connections, each with its own servant; returns once the server has
  // registered them all (subscribe is a twoway call).
  void subscribe(const std::string& host, std::uint16_t port, int count) {
    const auto n = static_cast<std::size_t>(std::max(count, 0));
    tally_->received.assign(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
      auto bench = runtime_->bench(host, port, "s");
      ice_call("subscribe", [&] {
        auto connection = bench->ice_getConnection();
        connections_.push_back(connection);
        // Once subscribed, the connection carries no calls of its own; ACM must not close it
        // as idle (bidirectional connections in the Ice manual).
        connection->setACM(Ice::nullopt, Ice::ACMClose::CloseOff, Ice::nullopt);
        connection->setAdapter(adapter_);
        bench->subscribe(Ice::uncheckedCast<icarsbench::SubscriberPrx>(
            adapter_->addWithUUID(std::make_shared<EventCounter>(tally_, i))));
      });
    }
    publisher_ = runtime_->bench(host, port, "p");
  }

  void publish_and_wait(int events, std::size_t payload,
                        std::chrono::milliseconds timeout) override {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    if (events < 0 || payload > static_cast<std::size_t>(std::numeric_limits<int>::max())) {
      throw std::invalid_argument("publish_and_wait: events < 0 or payload over 2 GiB");
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
    ice_call("publish", [&] { publisher_->publish(events, static_cast<int>(payload)); });

    std::unique_lock lock(tally_->mutex);
    const bool done = tally_->all_in.wait_until(lock, deadline, [&] {
      return tally_->complete == tally_->received.size() || !tally_->error.empty();
    });
    if (!tally_->error.empty()) {
      throw std::runtime_error("ice: subscriber: " + tally_->error);
    }
    if (!done) {
      timed_out_ = true;
      tally_->payload.reset();
      throw std::runtime_error("ice: " + std::to_string(tally_->complete) + " of " +
                               std::to_string(tally_->received.size()) +
                               " subscribers received all " + std::to_string(events) +
                               " events within " + std::to_string(timeout.count()) + " ms");
    }
  }

 private:
  std::shared_ptr<ClientRuntime> runtime_;  // first member: the communicator outlives the rest
  std::shared_ptr<Ice::ObjectAdapter> adapter_;
  std::shared_ptr<EventTally> tally_ = std::make_shared<EventTally>();
  std::vector<std::shared_ptr<Ice::Connection>> connections_;
  std::shared_ptr<icarsbench::BenchPrx> publisher_;
  bool timed_out_ = false;
};

// ---------------------------------------------------------------------------------------------

class IceSystem final : public System {
 public:
  explicit IceSystem(std::optional<TlsFiles> tls) : tls_(std::move(tls)) {}

  std::string name() const override { return tls_ ? "ice-tls" : "ice"; }

  void serve(std::uint16_t port, const std::function<void()>& ready) override {
    ice_call("serve on 127.0.0.1:" + std::to_string(port), [&] {
      const Ice::CommunicatorHolder ice(ice_settings(tls_, Side::server));
      auto adapter = ice->createObjectAdapterWithEndpoints(
          "Bench", transport(tls_) + " -h 127.0.0.1 -p " + std::to_string(port));
      adapter->add(std::make_shared<BenchServant>(), Ice::stringToIdentity("bench"));
      adapter->activate();
      ready();
      ice->waitForShutdown();  // nothing shuts it down: serves until the process is killed
    });
  }

  std::unique_ptr<Client> connect(const std::string& host, std::uint16_t port) override {
    auto ice = runtime();
    auto bench = ice->bench(host, port, "c");
    return std::make_unique<IceClient>(std::move(ice), std::move(bench));
  }

  std::unique_ptr<Subscribers> subscribe(const std::string& host, std::uint16_t port,
                                         int count) override {
    auto subscribers = std::make_unique<IceSubscribers>(runtime());
    subscribers->subscribe(host, port, count);  // on failure, the destructor cleans up
    return subscribers;
  }

 private:
  std::shared_ptr<ClientRuntime> runtime() {
    const std::lock_guard lock(mutex_);
    if (!runtime_) {
      runtime_ = ice_call("start the client communicator",
                          [&] { return std::make_shared<ClientRuntime>(tls_); });
    }
    return runtime_;
  }

  std::optional<TlsFiles> tls_;
  std::mutex mutex_;
  std::shared_ptr<ClientRuntime> runtime_;
};

}  // namespace

std::unique_ptr<System> make_ice(std::optional<TlsFiles> tls) {
  return std::make_unique<IceSystem>(std::move(tls));
}

}  // namespace icars::bench
