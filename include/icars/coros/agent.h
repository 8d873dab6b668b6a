// A COROS agent (COROS 4.2): one robot, user or monitor on the network.
//
// The Agent is the paper's server and client together (NodeServer/RobotServer with the UDP
// client), plus the knowledge base and the operators that give it its application logic:
//
//   Agent agent(config);                           // binds its sockets
//   agent.add_operator(std::make_shared<DiscoveryOperator>());
//   agent.add_operator(std::make_shared<CourierRobotOperator>(robot, map));
//   agent.start();                                 // its io_context thread runs everything
//
// Everything an agent does runs on its one io_context thread: received datagrams are decoded
// and dispatched by message code through its MessageProcessor (IMessageProcessor), timers
// fire, operators' handlers run. Operators therefore need no locks. From other threads use
// post() or call().
//
// Every datagram is signed with the fleet key and every one received is authenticated before
// decoding goes further (transport.h, authentication.h); an agent without a key refuses to be
// constructed unless its configuration says `insecure`. Datagrams that fail authentication are
// counted by reason in stats() and shown in the "stopped" event; no handler sees them.
//
// A datagram that cannot be decoded, or that a handler rejects (a CorosError or any other
// exception), is counted and reported through the event sink as {"event":"bad_datagram",...};
// it never stops the agent. Reports are aggregated per source address: the first bad datagram
// of a source is reported at once, the ones after it at most once a second in one event with
// their "count", so a flood of garbage costs a few events a second and the counts add up to
// bad_datagrams() (the rest are reported when the agent stops). A well-formed message whose code no operator of this agent
// handles (another application sharing the fleet's port) is ignored.
#pragma once

#include <asio/io_context.hpp>
#include <asio/ip/udp.hpp>
#include <asio/steady_timer.hpp>
#include <chrono>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "icars/coros/knowledge.h"
#include "icars/coros/messages.h"
#include "icars/coros/transport.h"

namespace icars::coros {

class Agent;
class BadDatagramReporter;

// Where a message came from: the sending agent's id and unicast endpoint.
struct Envelope {
  std::string sender;
  asio::ip::udp::endpoint from;
};

// Decodes datagrams and dispatches them by message code (the paper's IMessageProcessor).
class MessageProcessor {
 public:
  template <Message M>
  using Handler = std::function<void(const M&, const Envelope&)>;

  // Several handlers may listen to one code; they run in the order they were added.
  template <Message M>
  void on(Handler<M> handler) {
    handlers_[static_cast<std::uint16_t>(M::kCode)].push_back(
        [h = std::move(handler)](const Datagram& d, const Envelope& e) { h(d.body_as<M>(), e); });
  }
  bool handles(MessageCode code) const {
    return handlers_.contains(static_cast<std::uint16_t>(code));
  }
  // Throws CorosError for a body that does not decode or a code nobody handles.
  void process(const Datagram& datagram, const Envelope& envelope) const;

 private:
  std::map<std::uint16_t, std::vector<std::function<void(const Datagram&, const Envelope&)>>>
      handlers_;
};

// An agent's application logic (the paper's AgentOperator). SimpleOperator is the base for
// agents without a robot; RobotOperator (execution.h) adds one.
class Operator {
 public:
  virtual ~Operator() = default;
  // Called once on the agent's thread at start: register handlers, start timers.
  virtual void init(Agent& agent) = 0;
  // Called on the agent's thread at stop; timers are cancelled by the agent.
  virtual void shutdown() {}
};

class SimpleOperator : public Operator {
 public:
  void init(Agent& agent) override { agent_ = &agent; }

 protected:
  Agent& agent() const { return *agent_; }

 private:
  Agent* agent_ = nullptr;
};

// A repeating or one-shot wall-clock timer on the agent's thread; cancelled when destroyed.
class Timer {
 public:
  ~Timer() { cancel(); }
  void cancel();
  bool active() const { return active_; }

 private:
  friend class Agent;
class BadDatagramReporter;
  explicit Timer(asio::io_context& io) : timer_(io) {}
  asio::steady_timer timer_;
  bool active_ = true;
};

class Agent {
 public:
  using EventSink = std::function<void(const nlohmann::json&)>;

  // Binds the sockets (throws CorosError when it cannot, or when the configuration has no
  // fleet key and does not say insecure); nothing runs until start().
  explicit Agent(AgentConfiguration config);
  ~Agent();  // stop()
  Agent(const Agent&) = delete;
  Agent& operator=(const Agent&) = delete;

  void add_operator(std::shared_ptr<Operator> op);  // before start()
  void start();
  // Shuts the operators down, closes the sockets and joins the thread. Idempotent.
  void stop();

  void post(std::function<void()> fn);
  // Runs fn on the agent's thread and returns its result (rethrowing its exception).
  template <class F>
  auto call(F fn) -> decltype(fn()) {
    using R = decltype(fn());
    auto task = std::make_shared<std::packaged_task<R()>>(std::move(fn));
    auto future = task->get_future();
    post([task] { (*task)(); });
    return future.get();
  }

  // --- on the agent's thread ---
  const AgentConfiguration& config() const { return config_; }
  const std::string& id() const { return config_.id; }
  MessageProcessor& processor() { return processor_; }
  NeighborMonitor& neighbors() { return neighbors_; }
  TaskMonitor& tasks() { return tasks_; }
  UdpTransport& transport() { return *transport_; }
  asio::io_context& io() { return io_; }

  template <Message M>
  void send(const asio::ip::udp::endpoint& to, const M& message) {
    transport_->send_to(to, encode_datagram(id(), message));
  }
  template <Message M>
  void broadcast(const M& message) {
    transport_->broadcast(encode_datagram(id(), message));
  }

  // The timer runs only as long as the returned handle is kept.
  [[nodiscard]] std::shared_ptr<Timer> after(std::chrono::milliseconds delay,
                                             std::function<void()> fn);
  [[nodiscard]] std::shared_ptr<Timer> every(std::chrono::milliseconds period,
                                             std::function<void()> fn);

  // Status and load announced in HELLO; set by operators.
  void set_status(std::string status) { status_ = std::move(status); }
  const std::string& status() const { return status_; }
  void set_load(int load) { load_ = load; }
  int load() const { return load_; }
  void set_position(double x, double y) { x_ = x, y_ = y; }
  std::pair<double, double> position() const { return {x_, y_}; }

  // Machine-readable events ({"event":"awarded",...}); "time" and "agent" are added.
  void set_event_sink(EventSink sink);  // before start()
  void emit(nlohmann::json event);

  std::uint64_t bad_datagrams() const { return bad_datagrams_; }
  // What the transport sent, received and dropped, by reason; thread-safe.
  TransportStats stats() const { return transport_->stats(); }
  static double wall_seconds();  // seconds since the Unix epoch

 private:
  void on_datagram(const Datagram& datagram, const asio::ip::udp::endpoint& from);
  // Counts a bad datagram and emits what its source's aggregation says is due.
  void on_bad_datagram(const asio::ip::udp::endpoint& from, bool malformed, std::string error);
  void arm_bad_datagram_timer();
  std::shared_ptr<Timer> start_timer(std::chrono::milliseconds delay, std::function<void()> fn,
                                     bool repeat);
  void schedule(const std::shared_ptr<Timer>& timer, std::chrono::milliseconds delay,
                std::function<void()> fn, bool repeat);

  AgentConfiguration config_;
  asio::io_context io_;
  std::unique_ptr<UdpTransport> transport_;
  MessageProcessor processor_;
  NeighborMonitor neighbors_;
  TaskMonitor tasks_;
  std::vector<std::shared_ptr<Operator>> operators_;
  std::vector<std::weak_ptr<Timer>> timers_;
  EventSink sink_;
  std::string status_ = "idle";
  int load_ = 0;
  double x_ = 0, y_ = 0;
  std::uint64_t bad_datagrams_ = 0;
  std::unique_ptr<BadDatagramReporter> bad_datagram_reports_;
  asio::steady_timer bad_datagram_timer_{io_};
  bool bad_datagram_timer_armed_ = false;
  std::chrono::steady_clock::time_point started_{};
  std::thread thread_;
  bool started_flag_ = false;
  bool stopped_ = false;
};

}  // namespace icars::coros
