// Behavior subtrees placed on another server (remote_tree.h, idl/behavior.idl) against the same
// subtree in the placing server's own tree, measured side by side in one run (a plain program
// printing medians).
//
//   distribution_bench [--runs 5] [--round-trips 10000] [--warmup 50] [--lifecycles 1000]
//
// Server A is this process: one behavior Runtime on a WallClock, the generic behaviors, a PLANET
// communicator with RemoteHosts. Server B is a second process (this program again, started with
// --host-b as a child process, planet_test::ChildProcess) serving a SubtreeHost on 127.0.0.1; A
// places subtrees on it over loopback PLANET. Each measured subtree is built either in A's tree
// (control::build_tree of the node's XML: "in-process") or as the placeholder that starts it on B
// (RemoteHosts::make: "host B"), from the same XML. Every time is wall time
// (std::chrono::steady_clock, CLOCK_MONOTONIC, which both processes share), taken on the
// runtime thread of the server where the moment happens.
//
//   event round trip   tree Pair = concurrent(first) of Sibling, a leaf of this program, and
//                      Far = <when event="Ping"><behavior type="Emit" event="Pong"/></when>.
//                      The bench thread posts "Sibling, ping" (an input, as a sensor event would
//                      be); the time runs from Sibling propagating Ping (to its parent and to
//                      Far) until Sibling hears the Pong that Far's Emit propagated, which
//                      reached Far's parent and siblings through Far. One Ping in flight;
//                      --warmup untimed round trips first, then --round-trips timed ones.
//   start              node Far = <sequential><Emit Started/><Wait 1h/></sequential>, the root
//                      of a tree at "Lifecycle/Far". From Far.start() on A's runtime until
//                      (a) the subtree's root started on its server (its "started" trace record:
//                      on A in-process, on B remote, which prints the moment on its stdout) and
//                      (b) its first event, Started, reached the tree's owner on A.
//   halt               from Far.halt() on A's runtime (once Started came back) until the
//                      subtree's root is halted on its server, children first (its "halted"
//                      trace record). --lifecycles starts and halts per placement and run.
// Each run measures the four cases (in-process then remote, round trips then starts and halts)
// and takes each one's median and p95; printed: the median over --runs of those, the minimum
// and maximum of the runs' medians, and the ratios remote / in-process.
#include <fmt/format.h>
#include <signal.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <sys/prctl.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "bench_util.h"
#include "child_process.h"
#include "icars/behavior/composite.h"
#include "icars/behavior/registry.h"
#include "icars/clock/wall_clock.h"
#include "icars/control/remote_tree.h"
#include "icars/control/tree_builder.h"
#include "icars/planet/communicator.h"
#include "icars/service/service_container.h"

namespace {

namespace b = icars::behavior;
namespace c = icars::control;
namespace p = icars::planet;
using Steady = std::chrono::steady_clock;
using Us = std::chrono::duration<double, std::micro>;
using namespace std::chrono_literals;

// The bound on any one step; a step that takes longer is an error.
constexpr std::chrono::seconds kBound = 20s;

// The measured subtrees, as a policy writes them (docs/policy.md).
constexpr const char* kReplyXml =
    R"(<when name="Far" event="Ping"><behavior type="Emit" event="Pong"/></when>)";
constexpr const char* kLifecycleXml =
    R"(<sequential name="Far"><behavior type="Emit" event="Started"/>)"
    R"(<behavior type="Wait" duration="1h"/></sequential>)";
constexpr const char* kLifecyclePrefix = "Lifecycle";
constexpr const char* kLifecyclePath = "Lifecycle/Far";  // the subtree root's path on either server

std::int64_t to_ns(Steady::time_point t) {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
}
Steady::time_point from_ns(std::int64_t ns) {
  return Steady::time_point(
      std::chrono::duration_cast<Steady::duration>(std::chrono::nanoseconds(ns)));
}

std::shared_ptr<spdlog::logger> quiet_logger(const std::string& name) {
  auto log = std::make_shared<spdlog::logger>(
      name, std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  log->set_level(spdlog::level::warn);
  return log;
}

// One server's behavior side, as a mediating server has it. Gone in reverse order: the
// communicator's io thread first, then the runtime's thread, then what their handlers use.
struct Server {
  Server() : runtime(clock), env{runtime, services, trace} {
    b::register_generic_behaviors(registry);
  }

  static p::CommunicatorOptions options() {
    p::CommunicatorOptions o;
    o.name = "icars";
    o.logger = quiet_logger("icars");
    return o;
  }

  icars::WallClock clock;
  icars::service::ServiceContainer services;
  b::Trace trace;
  b::Runtime runtime;
  b::Environment env;
  b::BehaviorRegistry registry;
  p::Communicator communicator{options()};
};

// --- Host B: the second process ------------------------------------------------------------------

// Serves a SubtreeHost on 127.0.0.1 until SIGTERM. Prints "port N", then for every start and
// halt of the measured subtree's root "start NS" / "halt NS" (steady-clock nanoseconds, taken
// on its runtime thread when the trace records it).
int run_host(pid_t parent) {
  ::prctl(PR_SET_PDEATHSIG, SIGTERM);  // gone with the benchmark, however it ends
  if (::getppid() != parent) return 1;
  sigset_t stop;
  sigemptyset(&stop);
  sigaddset(&stop, SIGTERM);
  sigaddset(&stop, SIGINT);
  pthread_sigmask(SIG_BLOCK, &stop, nullptr);  // before any thread starts: every thread inherits it

  Server server;
  server.trace.add_sink([](const b::TraceRecord& r) {
    if (r.kind != "behavior" || r.source != kLifecyclePath) return;
    const auto event = r.field("event");
    if (event != "start" && event != "halt") return;
    const auto now = to_ns(Steady::now());
    std::printf("%s %lld\n", event.c_str(), static_cast<long long>(now));
    std::fflush(stdout);
  });
  auto host = std::make_shared<c::SubtreeHost>(server.env, server.registry, server.communicator);
  server.communicator.adapter().add(std::string(c::kBehaviorHostPath), host);
  const auto port = server.communicator.listen("127.0.0.1", 0);
  std::printf("port %u\n", static_cast<unsigned>(port));
  std::fflush(stdout);

  int signal = 0;
  sigwait(&stop, &signal);
  server.communicator.adapter().remove(std::string(c::kBehaviorHostPath));
  host.reset();  // halts what still runs, on the runtime
  return 0;
}

// The host process, as this server's side sees it: its port and the moments it prints.
class HostB {
 public:
  HostB() {
    const auto self = std::filesystem::read_symlink("/proc/self/exe").string();
    process_ = std::make_unique<planet_test::ChildProcess>(
        std::vector<std::string>{self, "--host-b", std::to_string(::getpid())});
    const auto line = process_->read_line(kBound);
    unsigned value = 0;
    if (!line || std::sscanf(line->c_str(), "port %u", &value) != 1 || value == 0 ||
        value > 65535) {
      throw std::runtime_error("host B (" + self +
                               " --host-b) did not print its port: " + line.value_or("nothing"));
    }
    port_ = static_cast<std::uint16_t>(value);
  }
  ~HostB() {
    process_->signal(SIGTERM);
    process_->wait_for(10s);  // else the ChildProcess kills it
  }
  HostB(const HostB&) = delete;
  HostB& operator=(const HostB&) = delete;

  std::uint16_t port() const { return port_; }
  pid_t pid() const { return process_->pid(); }

  // When the measured subtree's root did `what` ("start" or "halt") on B: the next line it prints.
  Steady::time_point moment(const std::string& what) {
    const auto line = process_->read_line(kBound);
    char event[16] = {};
    long long ns = 0;
    if (!line || std::sscanf(line->c_str(), "%15s %lld", event, &ns) != 2 || what != event) {
      throw std::runtime_error(
          fmt::format("host B did not report the subtree's {} within {} s (it printed: {})", what,
                      kBound.count(), line.value_or("nothing")));
    }
    return from_ns(ns);
  }

 private:
  std::unique_ptr<planet_test::ChildProcess> process_;  // SIGKILLed and reaped at destruction
  std::uint16_t port_ = 0;
};

// --- Server A: the measured trees ----------------------------------------------------------------

// What happened on A's runtime thread that the bench thread waits for: named moments (the first
// of each since reset), Pongs heard and their latencies, and a tree's failure.
class Watch {
 public:
  void reset() {
    std::lock_guard lock(mutex_);
    moments_.clear();
    failure_.clear();
  }
  void moment(const std::string& what, Steady::time_point t) {
    std::lock_guard lock(mutex_);
    if (moments_.emplace(what, t).second) changed_.notify_all();
  }
  void pong(Steady::duration latency) {
    std::lock_guard lock(mutex_);
    latencies_.push_back(Us(latency).count());
    changed_.notify_all();
  }
  void failed(std::string why) {
    std::lock_guard lock(mutex_);
    failure_ = std::move(why);
    changed_.notify_all();
  }

  Steady::time_point wait_moment(const std::string& what) {
    std::unique_lock lock(mutex_);
    wait(lock, what, [&] { return moments_.contains(what); });
    return moments_.at(what);
  }
  // Waits for the n-th Pong since the tree started.
  void wait_pongs(std::size_t n) {
    std::unique_lock lock(mutex_);
    wait(lock, fmt::format("Pong #{}", n), [&] { return latencies_.size() >= n; });
  }
  std::vector<double> take_latencies() {
    std::lock_guard lock(mutex_);
    return std::exchange(latencies_, {});
  }

 private:
  template <class Pred>
  void wait(std::unique_lock<std::mutex>& lock, const std::string& what, Pred done) {
    if (!changed_.wait_for(lock, kBound, [&] { return done() || !failure_.empty(); })) {
      throw std::runtime_error(fmt::format("no {} within {} s", what, kBound.count()));
    }
    if (!done()) {
      throw std::runtime_error(fmt::format("waiting for {}: the tree {}", what, failure_));
    }
  }

  std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::string, Steady::time_point> moments_;
  std::vector<double> latencies_;
  std::string failure_;
};

// The owner of a measured tree's root, as a task would be: notes when Started reaches the top
// and when the tree completes (it never should).
class Top final : public b::Owner {
 public:
  explicit Top(Watch& watch) : watch_(watch) {}
  void child_event(b::Behavior&, const b::Event& e) override {
    if (e.type() == "Started") watch_.moment("Started", Steady::now());
  }
  void child_done(b::Behavior& root) override {
    watch_.failed(fmt::format("{}: {}", b::to_string(root.status()), root.failure_reason()));
  }

 private:
  Watch& watch_;
};

// The sibling of the measured subtree: propagates Ping when told (ping(), on the runtime) and
// times the Pong it hears back.
class Sibling final : public b::Behavior {
 public:
  explicit Sibling(Watch& watch) : watch_(watch) {}
  void ping() {
    sent_ = Steady::now();
    propagate(b::Event("Ping"));
  }

 protected:
  void handle_event(const b::Event& e) override {
    if (e.type() == "Pong") watch_.pong(Steady::now() - sent_);
  }

 private:
  Watch& watch_;
  Steady::time_point sent_{};
};

// Placing server A: its runtime, the hosts it knows (B), and the moments of its own trace.
class PlacingServer {
 public:
  explicit PlacingServer(std::uint16_t b_port) {
    hosts_ = std::make_unique<c::RemoteHosts>(server_.communicator);
    hosts_->add("B", "127.0.0.1", b_port);
    if (!hosts_->wait_connected("B", kBound)) throw std::runtime_error("no link to host B");
    server_.trace.add_sink([this](const b::TraceRecord& r) {
      if (r.kind != "behavior" || r.source != kLifecyclePath) return;
      const auto event = r.field("event");
      if (event == "start" || event == "halt") watch_.moment(event, Steady::now());
    });
  }
  ~PlacingServer() { hosts_.reset(); }  // before the communicator it uses

  // The node `xml` as a node of A's tree, or placed on B.
  std::unique_ptr<b::Behavior> node(const std::string& xml, bool remote) {
    if (remote) return hosts_->make("B", "Far", xml);
    return c::build_tree(c::parse_subtree(xml, server_.registry), server_.registry);
  }
  b::Runtime& runtime() { return server_.runtime; }
  b::Environment& env() { return server_.env; }
  Watch& watch() { return watch_; }

 private:
  Watch watch_;  // outlives the server, whose trace notes into it
  Server server_;
  std::unique_ptr<c::RemoteHosts> hosts_;
};

// Halts and destroys `root` on the runtime when it goes, also when a measurement throws.
class TreeOnRuntime {
 public:
  TreeOnRuntime(b::Runtime& runtime, std::unique_ptr<b::Behavior> root)
      : runtime_(runtime), root_(std::move(root)) {}
  ~TreeOnRuntime() {
    runtime_.run([this] {
      if (root_->running()) root_->halt();
      root_.reset();
    });
  }
  TreeOnRuntime(const TreeOnRuntime&) = delete;
  TreeOnRuntime& operator=(const TreeOnRuntime&) = delete;
  b::Behavior& operator*() const { return *root_; }

 private:
  b::Runtime& runtime_;
  std::unique_ptr<b::Behavior> root_;
};

// Round trips Sibling -> Far -> Sibling, µs each (the timed ones).
std::vector<double> round_trips(PlacingServer& a, bool remote, int warmup, int count) {
  auto& watch = a.watch();
  watch.take_latencies();
  Top top(watch);
  auto pair = std::make_unique<b::ConcurrentBehavior>(b::Completion::first);
  pair->set_identity("concurrent", "Pair");
  auto sibling = std::make_unique<Sibling>(watch);
  sibling->set_identity("Sibling", "Sibling");
  auto* pinger = sibling.get();
  pair->add_child(std::move(sibling));
  pair->add_child(a.node(kReplyXml, remote));
  TreeOnRuntime tree(a.runtime(), std::move(pair));
  a.runtime().run([&] {
    (*tree).attach(a.env(), top, "");
    (*tree).start();
  });
  const auto total = static_cast<std::size_t>(warmup + count);
  for (std::size_t i = 1; i <= total; ++i) {
    a.runtime().post([pinger] { pinger->ping(); });
    watch.wait_pongs(i);
  }
  auto latencies = watch.take_latencies();
  latencies.erase(latencies.begin(), latencies.begin() + warmup);
  return latencies;
}

struct Lifecycle {
  std::vector<double> started_there, first_event, halted_there;  // µs each
};

// `count` starts and halts of Far, one after another.
Lifecycle lifecycles(PlacingServer& a, HostB& host, bool remote, int count) {
  Lifecycle out;
  auto& watch = a.watch();
  for (int i = 0; i < count; ++i) {
    watch.reset();
    Top top(watch);
    TreeOnRuntime far(a.runtime(), a.node(kLifecycleXml, remote));
    const auto there = [&](const std::string& what) {
      return remote ? host.moment(what) : watch.wait_moment(what);
    };
    const auto started = a.runtime().run([&] {
      const auto t = Steady::now();
      (*far).attach(a.env(), top, kLifecyclePrefix);
      (*far).start();
      return t;
    });
    out.first_event.push_back(Us(watch.wait_moment("Started") - started).count());
    out.started_there.push_back(Us(there("start") - started).count());
    const auto halted = a.runtime().run([&] {
      const auto t = Steady::now();
      (*far).halt();
      return t;
    });
    out.halted_there.push_back(Us(there("halt") - halted).count());
  }
  return out;
}

// --- Output --------------------------------------------------------------------------------------

// The q-quantile of a non-empty sample (nearest rank).
double quantile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  const auto rank = static_cast<std::size_t>(std::ceil(q * static_cast<double>(v.size())));
  return v[std::clamp<std::size_t>(rank, 1, v.size()) - 1];
}

// One measure's runs, per placement: each run's median and p95.
struct Row {
  std::string measure;
  std::vector<double> median[2], p95[2];  // [0] in-process, [1] host B
  void add(bool remote, const std::vector<double>& sample) {
    median[remote].push_back(quantile(sample, 0.5));
    p95[remote].push_back(quantile(sample, 0.95));
  }
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "behavior subtrees on a second server process against the same subtree in one process"};
  int runs = 5;
  int round_trip_count = 10000;
  int warmup = 50;
  int lifecycle_count = 1000;
  pid_t host_parent = 0;
  app.add_option("--runs", runs, "repetitions; printed: the median of the runs' medians and p95s")
      ->check(CLI::Range(1, 1000));
  app.add_option("--round-trips", round_trip_count, "timed event round trips per placement and run")
      ->check(CLI::Range(1, 10000000));
  app.add_option("--warmup", warmup, "untimed event round trips before them")
      ->check(CLI::Range(0, 1000000));
  app.add_option("--lifecycles", lifecycle_count, "starts and halts per placement and run")
      ->check(CLI::Range(1, 1000000));
  app.add_option("--host-b", host_parent,
                 "run as server B for the benchmark process PID (it starts it so)")
      ->group("");
  CLI11_PARSE(app, argc, argv);

  try {
    if (host_parent != 0) return run_host(host_parent);

    HostB host;
    std::vector<Row> rows = {{"event round trip: Sibling -> Far -> Sibling", {}, {}},
                             {"start -> subtree root started on its server", {}, {}},
                             {"start -> first event (Started) back at the top", {}, {}},
                             {"halt -> subtree halted on its server", {}, {}}};
    {
      PlacingServer a(host.port());
      for (int r = 0; r < runs; ++r) {
        for (const bool remote : {false, true}) {
          rows[0].add(remote, round_trips(a, remote, warmup, round_trip_count));
        }
        for (const bool remote : {false, true}) {
          const auto l = lifecycles(a, host, remote, lifecycle_count);
          rows[1].add(remote, l.started_there);
          rows[2].add(remote, l.first_event);
          rows[3].add(remote, l.halted_there);
        }
      }
    }

    fmt::print(
        "server A: this process; host B: a second process (pid {}) on 127.0.0.1:{}, "
        "PLANET over loopback\n",
        host.pid(), host.port());
    fmt::print(
        "{} runs, wall clock; per run and placement: {} event round trips (after {} untimed), "
        "{} starts and halts\n",
        runs, round_trip_count, warmup, lifecycle_count);
    fmt::print(
        "us: the median over runs of each run's median and p95; [min, max] of the runs' medians; "
        "ratio: host B / in-process\n\n");
    fmt::print("{:<48} {:<11} {:>9} {:>9}  {:>21}\n", "measure", "placement", "median", "p95",
               "[min, max] of medians");
    for (const auto& row : rows) {
      double median[2], p95[2];
      for (const int remote : {0, 1}) {
        const auto m = icars::bench::stats(row.median[remote]);
        median[remote] = m.median;
        p95[remote] = icars::bench::stats(row.p95[remote]).median;
        fmt::print("{:<48} {:<11} {:>9.1f} {:>9.1f}  [{:>9.1f}, {:>9.1f}]\n",
                   remote ? "" : row.measure, remote ? "host B" : "in-process", median[remote],
                   p95[remote], m.min, m.max);
      }
      fmt::print("{:<48} {:<11} {:>8.1f}x {:>8.1f}x\n", "", "ratio", median[1] / median[0],
                 p95[1] / p95[0]);
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "distribution_bench: {}\n", e.what());
    return 1;
  }
  return 0;
}
