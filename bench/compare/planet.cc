// PLANET, as an ICARS user writes it: an interface of typed operations, a servant, Proxy calls
// (synchronous and async_call), and events fanned out by a Publisher to listeners passed by
// reference. The limits are raised for the 256 MiB echo (the defaults refuse messages over
// 64 MiB and queue at most 128 MiB per connection) and for the 5,000 subscribers of the fan-out
// scaling series (the defaults admit 1,024 connections and 1,024 subscribers to a publisher);
// everything else is the default. "planet-tls" is the same with TLS on every link (options()).
#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <condition_variable>
#include <map>
#include <mutex>
#include <optional>
#include <semaphore>
#include <stdexcept>
#include <thread>

#include "icars/planet/communicator.h"
#include "icars/planet/proxy.h"
#include "icars/planet/publisher.h"
#include "system.h"
#include "test_interfaces.h"

namespace icars::bench {
namespace {

namespace p = icars::planet;
using namespace std::chrono_literals;
using planet_test::Tick;
using planet_test::TickListener;

struct Bench {
  static constexpr std::string_view type_id = "bench::Bench";
  static constexpr p::Operation<std::int32_t(std::int32_t)> echo_int{"echo_int"};
  static constexpr p::Operation<std::int64_t(p::Binary)> size_of{"size_of"};
  static constexpr p::Operation<p::Binary(p::Binary)> echo_bytes{"echo_bytes"};
  static constexpr p::Operation<void(std::int32_t, std::int32_t)> publish{"publish"};
  static constexpr p::Operation<void(p::Ref<TickListener>)> subscribe{"subscribe"};
};

constexpr std::size_t kLargest = 320u << 20;  // room for the 256 MiB echo
constexpr std::size_t kMostConnections = 8192;  // room for 5,000 subscribers

enum class Side { server, client };

// With `tls`, TLS on every link, loopback included (the default mode, automatic, leaves loopback
// in plaintext): the server presents its certificate, the client checks it against the CA and
// the host it connects to (TlsFiles).
p::CommunicatorOptions options(const std::string& name, const std::optional<TlsFiles>& tls,
                               Side side) {
  p::CommunicatorOptions o;
  if (tls) {
    o.tls.mode = p::TlsMode::on;
    if (side == Side::server) {
      o.tls.certificate_file = tls->certificate();
      o.tls.private_key_file = tls->private_key();
    } else {
      o.tls.ca_file = tls->ca();
    }
  }
  o.connection.max_message_size = kLargest;
  o.connection.send_queue_limit = 2 * kLargest;
  o.connection.receive_budget = 2 * kLargest;
  // Every client of the benchmark is on 127.0.0.1, up to 5,000 at once (the fan-out scaling
  // series; the default admits 1,024), and one echo is as large as the budget.
  o.connection.max_connections = kMostConnections;
  o.connection.max_connections_per_address = kMostConnections;
  o.connection.total_receive_budget = 4 * kLargest;
  o.call_timeout = 60s;
  o.name = name;
  o.logger = std::make_shared<spdlog::logger>(
      name, std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  o.logger->set_level(spdlog::level::warn);
  return o;
}

class PlanetClient final : public Client {
 public:
  PlanetClient(p::Communicator& communicator, const std::string& host, std::uint16_t port)
      : peer_(communicator.connect(host, port)), bench_(communicator, peer_, "/bench") {
    if (!peer_->wait_connected(10s)) {
      throw std::runtime_error("planet: cannot connect: " + peer_->last_error());
    }
  }
  ~PlanetClient() override { peer_->stop(); }

  std::int32_t call(std::int32_t x) override { return bench_.call(Bench::echo_int, x); }

  std::uint64_t upload(const Bytes& data) override {
    return static_cast<std::uint64_t>(bench_.call(Bench::size_of, as_binary(data)));
  }

  Bytes echo(const Bytes& data) override {
    return std::move(bench_.call(Bench::echo_bytes, as_binary(data)).bytes);
  }

  void pipeline(std::int64_t count, int window) override {
    std::counting_semaphore<> slots(window);
    std::atomic<std::int64_t> failures{0};
    for (std::int64_t i = 0; i < count; ++i) {
      slots.acquire();
      const auto value = static_cast<std::int32_t>(i);
      bench_.async_call(Bench::echo_int, {value},
                        [&slots, &failures, value](std::exception_ptr e, std::int32_t got) {
                          if (e || got != value) failures.fetch_add(1);
                          slots.release();
                        });
    }
    for (int i = 0; i < window; ++i) slots.acquire();  // the last answers
    if (failures.load() != 0) {
      throw std::runtime_error("planet: " + std::to_string(failures.load()) +
                               " pipelined calls failed");
    }
  }

  void prepare(const Bytes& data) override { (void)as_binary(data); }

  bool try_call() noexcept override {
    try {
      return bench_.with_timeout(1s).call(Bench::echo_int, 7) == 7;
    } catch (const std::exception&) {
      return false;
    }
  }

 private:
  // The workloads send the same buffer again and again; a PLANET application holds its data as a
  // Binary, so the conversion from the driver's buffer is made once per buffer, not per call.
  const p::Binary& as_binary(const Bytes& data) {
    std::lock_guard lock(binary_mutex_);
    auto& blob = binaries_[data.data()];
    if (blob.bytes.size() != data.size()) blob.bytes = data;
    return blob;
  }

  std::mutex binary_mutex_;
  std::map<const std::byte*, p::Binary> binaries_;
  std::shared_ptr<p::Peer> peer_;
  p::Proxy bench_;
};

// `count` listeners, each a servant reached over its own connection.
class PlanetSubscribers final : public Subscribers {
 public:
  PlanetSubscribers(p::Communicator& communicator, const std::string& host, std::uint16_t port,
                    int count)
      : communicator_(communicator),
        publisher_(communicator, host, port),
        counts_(static_cast<std::size_t>(count), 0) {
    p::Communicator& c = communicator_;
    for (int i = 0; i < count; ++i) {
      const std::string path = "/listener/" + std::to_string(next_id_.fetch_add(1));
      auto listener = std::make_shared<p::Servant>(std::string(TickListener::type_id));
      const auto index = static_cast<std::size_t>(i);
      listener->implement(TickListener::on_tick, [this, index](const Tick&) { on_event(index); });
      c.adapter().add(path, listener);
      paths_.push_back(path);
      auto peer = c.connect(host, port);
      if (!peer->wait_connected(10s)) {
        throw std::runtime_error(fmt::format("planet: subscriber {} of {} cannot connect: {}",
                                             i + 1, count, peer->last_error()));
      }
      p::Proxy(c, peer, "/bench").call(Bench::subscribe, c.reference<TickListener>(path));
      peers_.push_back(std::move(peer));
    }
  }
  ~PlanetSubscribers() override {
    for (auto& peer : peers_) peer->stop();
    for (const auto& path : paths_) communicator_.adapter().remove(path);
  }

  void publish_and_wait(int events, std::size_t payload,
                        std::chrono::milliseconds timeout) override {
    {
      std::lock_guard lock(mutex_);
      std::fill(counts_.begin(), counts_.end(), 0);
      target_ = events;
      complete_ = 0;
    }
    publisher_.call(events, static_cast<std::int32_t>(payload));
    std::unique_lock lock(mutex_);
    if (!done_.wait_for(lock, timeout, [this] { return complete_ == counts_.size(); })) {
      throw std::runtime_error("planet: not every subscriber received every event");
    }
  }

 private:
  void on_event(std::size_t index) {
    std::lock_guard lock(mutex_);
    if (++counts_[index] == target_ && ++complete_ == counts_.size()) done_.notify_all();
  }

  // The publish request goes over a connection of its own.
  class Publisher {
   public:
    Publisher(p::Communicator& communicator, const std::string& host, std::uint16_t port)
        : peer_(communicator.connect(host, port)), bench_(communicator, peer_, "/bench") {}
    ~Publisher() { peer_->stop(); }
    void call(std::int32_t events, std::int32_t payload) {
      bench_.call(Bench::publish, events, payload);
    }

   private:
    std::shared_ptr<p::Peer> peer_;
    p::Proxy bench_;
  };

  static inline std::atomic<int> next_id_{0};
  p::Communicator& communicator_;
  Publisher publisher_;
  std::vector<std::shared_ptr<p::Peer>> peers_;
  std::vector<std::string> paths_;
  std::mutex mutex_;
  std::condition_variable done_;
  std::vector<int> counts_;
  int target_ = 0;
  std::size_t complete_ = 0;
};

class Planet final : public System {
 public:
  explicit Planet(std::optional<TlsFiles> tls) : tls_(std::move(tls)) {}

  std::string name() const override { return tls_ ? "planet-tls" : "planet"; }

  void serve(std::uint16_t port, const std::function<void()>& ready) override {
    p::Communicator communicator(options("bench-server", tls_, Side::server));
    // A fast publisher is expected to outrun its subscribers' sockets for a moment.
    p::Publisher<Tick> ticks(TickListener::on_tick, {.max_backlog_bytes = 256u << 20,
                                                     .stall_timeout = 60s,
                                                     .max_subscribers = kMostConnections});
    auto bench = std::make_shared<p::Servant>(std::string(Bench::type_id));
    bench->implement(Bench::echo_int, [](std::int32_t x) { return x; });
    bench->implement(Bench::size_of,
                     [](const p::Binary& b) { return static_cast<std::int64_t>(b.bytes.size()); });
    bench->implement(Bench::echo_bytes, [](p::Binary b) { return b; });
    bench->implement(Bench::publish, [&ticks](std::int32_t count, std::int32_t size) {
      Tick tick{0, p::Binary{Bytes(static_cast<std::size_t>(size), std::byte{0x5A})}};
      for (std::int32_t i = 0; i < count; ++i) {
        tick.seq = i;
        ticks.publish(tick);
      }
    });
    bench->implement(Bench::subscribe,
                     [&communicator, &ticks](p::Ref<TickListener> listener, const p::Current& c) {
                       ticks.subscribe(p::Proxy(communicator, c.connection, listener.object()));
                     });
    communicator.adapter().add("/bench", bench);
    communicator.listen("127.0.0.1", port);
    ready();
    for (;;) std::this_thread::sleep_for(1h);
  }

  std::unique_ptr<Client> connect(const std::string& host, std::uint16_t port) override {
    return std::make_unique<PlanetClient>(client_communicator(), host, port);
  }

  std::unique_ptr<Subscribers> subscribe(const std::string& host, std::uint16_t port,
                                         int count) override {
    return std::make_unique<PlanetSubscribers>(client_communicator(), host, port, count);
  }

 private:
  // One Communicator (one io thread) for all the clients and subscribers of a process, as a
  // PLANET application has; made at the first connection, so a server process has none.
  p::Communicator& client_communicator() {
    std::call_once(client_made_, [this] {
      client_ = std::make_unique<p::Communicator>(options("bench-client", tls_, Side::client));
    });
    return *client_;
  }

  std::optional<TlsFiles> tls_;
  std::once_flag client_made_;
  std::unique_ptr<p::Communicator> client_;  // outlives the clients: the System is made first
};

}  // namespace

std::unique_ptr<System> make_planet(std::optional<TlsFiles> tls) {
  return std::make_unique<Planet>(std::move(tls));
}

}  // namespace icars::bench
