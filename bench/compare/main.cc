// icars-compare: the same workloads over raw TCP, PLANET, gRPC, ZeroC Ice and Cap'n Proto, client
// and server in separate processes on loopback, repeated; prints the medians and the ratios to
// raw TCP and to PLANET, and writes them as JSON, CSV and PNG plots (gnuplot). docs/performance.md
// explains every workload and the results.
//
//   icars-compare run [--systems raw-tcp,planet,grpc,ice,capnp] [--reps 5] [--out DIR] [--quick]
//                     [--scaling connections,memory,fanout|all|none] [--scaling-only]
//   icars-compare plot --from DIR/compare.json --out DIR   (the table and plots of a saved run)
//   icars-compare serve --system S --port P [--certs DIR]   (started by `run`)
//   icars-compare client --system S --port P --workloads small,pipeline,... [--certs DIR]
//   The TLS variants (planet-tls, grpc-tls, ice-tls) run the small call and the upload only,
//   with certificates that `run` makes for them (tls_variants.h).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <thread>

#include "child_process.h"
#include "percentile.h"
#include "plots.h"
#include "report.h"
#include "scaling.h"
#include "system.h"
#include "tls_variants.h"

namespace icars::bench {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using json = nlohmann::json;
using namespace std::chrono_literals;

constexpr double kMiB = 1024.0 * 1024.0;

std::vector<std::string> available_systems() {
  std::vector<std::string> names = {"raw-tcp", "planet"};
#ifdef ICARS_BENCH_WITH_GRPC
  names.emplace_back("grpc");
#endif
#ifdef ICARS_BENCH_WITH_ICE
  names.emplace_back("ice");
#endif
#ifdef ICARS_BENCH_WITH_CAPNP
  names.emplace_back("capnp");  // no TLS variant
#endif
  names.emplace_back("planet-tls");  // after the plaintext systems: their columns come first
#ifdef ICARS_BENCH_WITH_GRPC
  names.emplace_back("grpc-tls");
#endif
#ifdef ICARS_BENCH_WITH_ICE
  names.emplace_back("ice-tls");
#endif
  return names;
}

// A TLS variant needs `tls`, the certificates (--certs).
std::unique_ptr<System> make_system(const std::string& name, const std::optional<TlsFiles>& tls) {
  const auto certificates = [&] {
    if (!tls) throw std::invalid_argument("system '" + name + "' needs certificates: --certs DIR");
    return tls;
  };
  if (name == "raw-tcp") return make_raw_tcp();
  if (name == "planet") return make_planet();
  if (name == "planet-tls") return make_planet(certificates());
#ifdef ICARS_BENCH_WITH_GRPC
  if (name == "grpc") return make_grpc();
  if (name == "grpc-tls") return make_grpc(certificates());
#endif
#ifdef ICARS_BENCH_WITH_ICE
  if (name == "ice") return make_ice();
  if (name == "ice-tls") return make_ice(certificates());
#endif
#ifdef ICARS_BENCH_WITH_CAPNP
  if (name == "capnp") return make_capnp();
#endif
  throw std::invalid_argument("system '" + name + "' is not built into this icars-compare");
}

std::int64_t now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch())
      .count();
}

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

Bytes pattern(std::size_t size) {
  Bytes data(size);
  for (std::size_t i = 0; i < size; ++i) data[i] = static_cast<std::byte>((i * 131 + 7) & 0xFF);
  return data;
}

// --- The client side: one process runs a list of workloads and prints one JSON line each ----

struct Sizes {
  int small_calls = 20000;
  std::int64_t pipelined_calls = 200000;
  std::vector<std::size_t> uploads = {1u << 20, 64u << 20};
  std::size_t hol_echo = 256u << 20;
  int subscribers = 100;
  int events = 2000;

  static Sizes quick() {
    Sizes s;
    s.small_calls = 2000;
    s.pipelined_calls = 20000;
    s.uploads = {1u << 20, 8u << 20};
    s.hol_echo = 16u << 20;
    s.subscribers = 20;
    s.events = 200;
    return s;
  }
};

void emit(const json& result) { std::cout << result.dump() << std::endl; }

void small_calls(Client& client, const Sizes& sizes) {
  for (int i = 0; i < sizes.small_calls / 10; ++i) client.call(i);  // warm-up
  std::vector<double> us;
  us.reserve(static_cast<std::size_t>(sizes.small_calls));
  for (int i = 0; i < sizes.small_calls; ++i) {
    const auto start = Clock::now();
    if (client.call(i) != i) throw std::runtime_error("echo_int returned a different value");
    us.push_back(seconds_since(start) * 1e6);
  }
  emit({{"workload", "small"}, {"small_p50_us", percentile(us, 0.5)},
        {"small_p99_us", percentile(us, 0.99)}});
}

void pipelined(System& system, std::uint16_t port, int clients, const Sizes& sizes) {
  std::vector<std::unique_ptr<Client>> connections;
  for (int i = 0; i < clients; ++i) connections.push_back(system.connect("127.0.0.1", port));
  const std::int64_t each = sizes.pipelined_calls / clients;
  for (auto& c : connections) c->pipeline(each / 20, 32);  // warm-up
  const auto start = Clock::now();
  std::vector<std::thread> threads;
  std::vector<std::string> errors(static_cast<std::size_t>(clients));
  for (std::size_t i = 0; i < connections.size(); ++i) {
    threads.emplace_back([&, i] {
      try {
        connections[i]->pipeline(each, 32);
      } catch (const std::exception& e) {
        errors[i] = e.what();
      }
    });
  }
  for (auto& t : threads) t.join();
  const double elapsed = seconds_since(start);
  for (const auto& e : errors) {
    if (!e.empty()) throw std::runtime_error(e);
  }
  emit({{"workload", fmt::format("pipeline{}", clients)},
        {fmt::format("pipeline{}_calls_s", clients),
         static_cast<double>(each * clients) / elapsed}});
}

void uploads(Client& client, const Sizes& sizes) {
  json result = {{"workload", "upload"}};
  for (const std::size_t size : sizes.uploads) {
    const Bytes data = pattern(size);
    const int runs = size <= (1u << 20) ? 200 : 5;
    client.upload(data);  // warm-up
    std::vector<double> mib_s;
    for (int i = 0; i < runs; ++i) {
      const auto start = Clock::now();
      if (client.upload(data) != size) throw std::runtime_error("size_of answered another size");
      mib_s.push_back(static_cast<double>(size) / kMiB / seconds_since(start));
    }
    result[fmt::format("upload_{}mib_mib_s", size >> 20)] = median(mib_s);
  }
  emit(result);
}

// Small calls back to back on the connection that carries a large echo, from a second thread;
// only the calls that start and finish while the echo is in progress count. Raw TCP has no
// multiplexing: there the echo runs alone.
//
// The echo is made twice. The first, alone, meets every buffer of the transfer for the first time
// on both sides (a page fault per 4 KiB of each: `hol_echo_cold_ms`); the second, the measured
// one, runs in the memory a process that moves large messages keeps, as the uploads' warm-up
// call leaves it for theirs.
void head_of_line(System& system, Client& client, const Sizes& sizes) {
  const Bytes big = pattern(sizes.hol_echo);
  client.prepare(big);
  const auto cold_start = Clock::now();
  if (client.echo(big) != big) throw std::runtime_error("the first large echo came back different");
  const double cold_s = seconds_since(cold_start);
  std::atomic<bool> echoing{false};
  std::atomic<bool> done{false};
  std::vector<double> us;
  double worst_us = 0;
  double worst_at_ms = 0;  // when the slowest small call started, from the start of the echo
  const Clock::time_point echo_start = Clock::now();
  std::string small_error;
  std::thread small;
  const bool multiplexed = system.name() != "raw-tcp";
  if (multiplexed) {
    small = std::thread([&] {
      try {
        while (!echoing.load()) std::this_thread::yield();
        for (std::int32_t i = 0; !done.load(); ++i) {
          const auto start = Clock::now();
          const std::int32_t got = client.call(i);
          const double took = seconds_since(start) * 1e6;
          if (got != i) throw std::runtime_error("echo_int returned a different value");
          if (!done.load()) {
            us.push_back(took);
            if (took > worst_us) {
              worst_us = took;
              worst_at_ms = std::chrono::duration<double, std::milli>(start - echo_start).count();
            }
          }
        }
      } catch (const std::exception& e) {
        small_error = e.what();
      }
    });
  }
  echoing = true;
  const Bytes back = client.echo(big);
  const double echo_s = seconds_since(echo_start);
  done = true;
  if (small.joinable()) small.join();
  if (back != big) throw std::runtime_error("the large echo came back different");
  if (!small_error.empty()) throw std::runtime_error(small_error);
  json result = {{"workload", "hol"},
                 {"hol_echo_ms", echo_s * 1e3},
                 {"hol_echo_cold_ms", cold_s * 1e3},
                 {"hol_small_calls", static_cast<double>(us.size())}};
  if (multiplexed && !us.empty()) {
    result["hol_small_p50_us"] = percentile(us, 0.5);
    result["hol_small_p99_us"] = percentile(us, 0.99);
    result["hol_small_max_ms"] = percentile(us, 1.0) / 1e3;
    result["hol_small_max_at_ms"] = worst_at_ms;
  }
  emit(result);
}

void fan_out(System& system, std::uint16_t port, const Sizes& sizes) {
  auto subscribers = system.subscribe("127.0.0.1", port, sizes.subscribers);
  subscribers->publish_and_wait(sizes.events / 10, 64, 120s);  // warm-up
  const auto start = Clock::now();
  subscribers->publish_and_wait(sizes.events, 64, 120s);
  const double elapsed = seconds_since(start);
  emit({{"workload", "fanout"},
        {"fanout_deliveries_s",
         static_cast<double>(sizes.events) * sizes.subscribers / elapsed}});
}

// Calls until the server goes away, then until it answers again; the driver restarts it and
// subtracts the time its new server reported being ready.
void reconnect(Client& client) {
  emit({{"workload", "reconnect-connected"}});
  while (client.try_call()) {
  }
  const std::int64_t down = now_ns();
  while (!client.try_call()) std::this_thread::sleep_for(200us);
  emit({{"workload", "reconnect"}, {"down_ns", down}, {"up_ns", now_ns()}});
}

// --- The scaling workloads (scaling.h): one point per client process ------------------------

void connections_point(System& system, std::uint16_t port, int connections, bool quick,
                       Opened& opened) {
  const auto r = drive_connections(system, port, connections, quick ? 300ms : 2000ms, opened);
  emit({{"workload", "connections"},
        {fmt::format("conn{}_threads", connections), r.threads},
        {fmt::format("conn{}_calls", connections), r.calls},
        {connections_calls_key(connections), r.calls_per_second},
        {connections_p99_key(connections), r.p99_us}});
}

void idle_memory_point(System& system, std::uint16_t port, pid_t server, Opened& opened) {
  if (server <= 0) throw std::invalid_argument("idle-memory needs --server-pid");
  const auto r = measure_idle_memory(system, port, server, kIdleConnections, opened);
  emit({{"workload", "idle-memory"},
        {"server_rss_fresh_kib", r.fresh_kib},
        {"server_rss_one_kib", r.one_kib},
        {"server_rss_idle_kib", r.idle_kib},
        {"idle_connections", r.idle},
        {kIdleConnectionKey, r.per_connection_kib()}});
}

void fan_out_point(System& system, std::uint16_t port, int subscribers, bool quick,
                   Opened& opened) {
  const std::int64_t deliveries = quick ? 20000 : 200000;
  emit({{"workload", "fanout-scaling"},
        {fan_out_key(subscribers), fan_out_to(system, port, subscribers, deliveries, 60s, opened)}});
}

// What the driver tells a client process besides its workloads.
struct ClientSettings {
  bool quick = false;
  int connections = 0;  // of the "connections" point
  int subscribers = 0;  // of the "fanout-scaling" point
  pid_t server = 0;     // the server process, whose memory "idle-memory" reads
  // The certificates of a TLS variant.
  std::optional<TlsFiles> tls;
};

// Prints one JSON line per workload; a workload that fails prints {"workload", "error"} and
// ends the process.
int run_client(const std::string& system_name, std::uint16_t port,
               const std::vector<std::string>& workloads, const ClientSettings& settings) {
  const Sizes sizes = settings.quick ? Sizes::quick() : Sizes{};
  auto system = make_system(system_name, settings.tls);
  // The connection the basic workloads share, made at the first that needs it: a scaling point
  // opens exactly the connections it counts.
  std::unique_ptr<Client> shared;
  const auto client = [&]() -> Client& {
    if (!shared) shared = system->connect("127.0.0.1", port);
    return *shared;
  };
  Opened opened;  // never closed: the process ends with std::_Exit
  std::string current;
  try {
    for (const auto& w : workloads) {
      current = w;
      if (w == "small") {
        small_calls(client(), sizes);
      } else if (w == "pipeline") {
        pipelined(*system, port, 1, sizes);
      } else if (w == "pipeline8") {
        pipelined(*system, port, 8, sizes);
      } else if (w == "upload") {
        uploads(client(), sizes);
      } else if (w == "hol") {
        head_of_line(*system, client(), sizes);
      } else if (w == "fanout") {
        fan_out(*system, port, sizes);
      } else if (w == "reconnect") {
        reconnect(client());
      } else if (w == "connections") {
        connections_point(*system, port, settings.connections, settings.quick, opened);
      } else if (w == "idle-memory") {
        idle_memory_point(*system, port, settings.server, opened);
      } else if (w == "fanout-scaling") {
        fan_out_point(*system, port, settings.subscribers, settings.quick, opened);
      } else {
        throw std::invalid_argument("unknown workload '" + w + "'");
      }
    }
  } catch (const std::exception& e) {
    emit({{"workload", current}, {"error", e.what()}});
    std::_Exit(1);
  }
  std::cout.flush();
  std::_Exit(0);  // skip the libraries' teardown: the measurements are out
}

int run_server(const std::string& system_name, std::uint16_t port,
               const std::optional<TlsFiles>& tls) {
  auto system = make_system(system_name, tls);
  system->serve(port, [] { std::cout << "ready " << now_ns() << std::endl; });
  return 0;
}

// --- The driver ------------------------------------------------------------------------------

std::uint16_t free_tcp_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t length = sizeof addr;
  if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &length) != 0) {
    throw std::runtime_error("no free TCP port");
  }
  ::close(fd);
  return ntohs(addr.sin_port);
}

// The scaling series a run includes (--scaling).
struct ScalingSeries {
  bool connections = false;
  bool memory = false;
  bool fan_out = false;
};

// One point of a scaling series: a fresh server and a client process of its own.
struct ScalingPoint {
  std::string what;                    // e.g. "1,000 connections", for messages
  std::string workload;                // the client's
  std::vector<std::string> arguments;  // to the client, besides the workload
  std::vector<std::string> keys;       // the metrics it yields
};

std::vector<ScalingPoint> scaling_points(const ScalingSeries& series) {
  std::vector<ScalingPoint> points;
  if (series.connections) {
    for (const int n : kConnectionPoints) {
      points.push_back({fmt::format("{} connections", n), "connections",
                        {"--connections", std::to_string(n)},
                        {connections_calls_key(n), connections_p99_key(n)}});
    }
  }
  if (series.memory) {
    points.push_back({fmt::format("{} idle connections", kIdleConnections), "idle-memory", {},
                      {kIdleConnectionKey}});
  }
  if (series.fan_out) {
    for (const int n : kSubscriberPoints) {
      points.push_back({fmt::format("fan-out to {} subscribers", n), "fanout-scaling",
                        {"--subscribers", std::to_string(n)}, {fan_out_key(n)}});
    }
  }
  return points;
}

std::string describe_wait_status(int status) {
  if (WIFEXITED(status)) return fmt::format("exit code {}", WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return fmt::format("signal {} ({})", WTERMSIG(status), strsignal(WTERMSIG(status)));
  return fmt::format("wait status {}", status);
}

class Driver {
 public:
  Driver(std::string self, bool quick, std::chrono::seconds timeout,
         std::chrono::seconds point_timeout, std::optional<TlsFiles> tls)
      : self_(std::move(self)),
        quick_(quick),
        timeout_(timeout),
        point_timeout_(point_timeout),
        tls_(std::move(tls)) {}

  // The basic workloads and the reconnection; a TLS variant's own few (tls_workloads()).
  void basic(const std::string& system, Report& report) {
    if (is_tls_variant(system)) {
      run_workloads(system, tls_workloads(), report.samples);
      return;
    }
    run_workloads(system, {"small", "pipeline", "pipeline8", "upload", "hol", "fanout"},
                  report.samples);
    run_reconnect(system, report.samples);
  }

  // Every point of the series; a point that fails or takes longer than the point timeout is
  // recorded as missing, with the reason, and the next point runs. None for a TLS variant.
  void scaling(const std::string& system, const ScalingSeries& series, Report& report) {
    if (is_tls_variant(system)) return;
    for (const auto& point : scaling_points(series)) run_point(system, point, report);
  }

 private:
  struct Server {
    std::unique_ptr<planet_test::ChildProcess> process;
    std::int64_t ready_ns = 0;
  };

  Server start_server(const std::string& system, std::uint16_t port) {
    Server s;
    std::vector<std::string> argv = {self_, "serve", "--system", system, "--port",
                                     std::to_string(port)};
    add_certificates(system, argv);
    s.process = std::make_unique<planet_test::ChildProcess>(argv);
    const auto line = s.process->read_line(30s);
    if (!line || line->rfind("ready ", 0) != 0) {
      throw std::runtime_error(system + " server did not start");
    }
    s.ready_ns = std::stoll(line->substr(6));
    return s;
  }

  std::unique_ptr<planet_test::ChildProcess> start_client(
      const std::string& system, std::uint16_t port, const std::string& workloads,
      const std::vector<std::string>& extra = {}) {
    std::vector<std::string> argv = {self_, "client", "--system", system, "--port",
                                     std::to_string(port), "--workloads", workloads};
    argv.insert(argv.end(), extra.begin(), extra.end());
    if (quick_) argv.emplace_back("--quick");
    add_certificates(system, argv);
    return std::make_unique<planet_test::ChildProcess>(argv);
  }

  void add_certificates(const std::string& system, std::vector<std::string>& argv) const {
    if (is_tls_variant(system) && tls_) argv.insert(argv.end(), {"--certs", tls_->dir.string()});
  }

  json next_result(planet_test::ChildProcess& client, const std::string& system) {
    const auto line = client.read_line(timeout_);
    if (!line) throw std::runtime_error(system + " client stopped or timed out");
    json result = json::parse(*line);
    if (result.contains("error")) {
      throw std::runtime_error(fmt::format("{} {}: {}", system, result.value("workload", ""),
                                           result["error"].get<std::string>()));
    }
    return result;
  }

  static void record(const json& result, const std::string& system, Samples& samples) {
    for (const auto& [key, value] : result.items()) {
      if (value.is_number()) samples[system][key].push_back(value.get<double>());
    }
  }

  void run_workloads(const std::string& system, const std::vector<std::string>& workloads,
                     Samples& samples) {
    const std::uint16_t port = free_tcp_port();
    Server server = start_server(system, port);
    std::string list;
    for (const auto& w : workloads) list += (list.empty() ? "" : ",") + w;
    auto client = start_client(system, port, list);
    for (std::size_t i = 0; i < workloads.size(); ++i) {
      const json result = next_result(*client, system);
      std::cerr << fmt::format("  {:8} {}\n", system, result.dump());
      record(result, system, samples);
    }
  }

  void run_reconnect(const std::string& system, Samples& samples) {
    const std::uint16_t port = free_tcp_port();
    Server server = start_server(system, port);
    auto client = start_client(system, port, "reconnect");
    next_result(*client, system);  // connected and calling
    server.process.reset();        // SIGKILL, reaped
    server = start_server(system, port);
    const json result = next_result(*client, system);
    const double ms =
        static_cast<double>(result.at("up_ns").get<std::int64_t>() - server.ready_ns) / 1e6;
    std::cerr << fmt::format("  {:8} reconnect {:.2f} ms after the new server was ready\n",
                             system, ms);
    samples[system]["reconnect_ms"].push_back(ms);
  }

  void run_point(const std::string& system, const ScalingPoint& point, Report& report) {
    try {
      const std::uint16_t port = free_tcp_port();
      Server server = start_server(system, port);
      std::vector<std::string> arguments = point.arguments;
      arguments.insert(arguments.end(),
                       {"--server-pid", std::to_string(server.process->pid())});
      auto client = start_client(system, port, point.workload, arguments);
      const auto line = client->read_line(point_timeout_);
      if (!line) {
        const auto status = client->wait_for(0ms);
        throw std::runtime_error(
            status ? "the client ended without a result: " + describe_wait_status(*status)
                   : fmt::format("no result within {} s (--point-timeout)",
                                 point_timeout_.count()));
      }
      const json result = json::parse(*line);
      if (result.contains("error")) throw std::runtime_error(result["error"].get<std::string>());
      std::cerr << fmt::format("  {:8} {}\n", system, result.dump());
      record(result, system, report.samples);
    } catch (const std::exception& e) {
      std::cerr << fmt::format("  {:8} {}: not measured: {}\n", system, point.what, e.what());
      for (const auto& key : point.keys) report.record_missing(system, key, e.what());
    }
  }

  std::string self_;
  bool quick_;
  std::chrono::seconds timeout_;
  std::chrono::seconds point_timeout_;
  std::optional<TlsFiles> tls_;  // the certificates of the TLS variants
};

// Writes compare.{json,csv} and the plots into `out_dir` and says what it wrote.
void write_results(const Report& report, const fs::path& out_dir) {
  fs::create_directories(out_dir);
  std::ofstream(out_dir / "compare.json") << report.to_json().dump(2) << "\n";
  report.write_csv(out_dir / "compare.csv");
  std::string files = "compare.json, compare.csv";
  std::string failed;
  const auto draw = [&](bool (*plot)(const Report&, const fs::path&), const std::string& name) {
    const fs::path png = fs::absolute(out_dir / name);
    fs::remove(png);  // a plot of an earlier run must not pass for this one's
    if (!plot(report, png)) {
      failed += " " + name;
    } else if (fs::exists(png)) {
      files += ", " + name;
    }
  };
  draw(plot_advantage, "compare.png");
  draw(plot_connections, "scaling_connections.png");
  draw(plot_fan_out, "scaling_fanout.png");
  std::cout << fmt::format("\nresults: {}/{{{}}}{}\n", out_dir.string(), files,
                           failed.empty() ? "" : " (not plotted, gnuplot failed or missing:" +
                                                     failed + ")");
}

struct RunSettings {
  std::vector<std::string> systems;
  int reps = 5;
  fs::path out_dir = "bench-results";
  bool quick = false;
  int timeout_s = 600;
  int point_timeout_s = 120;
  bool basic = true;  // the workloads before the scaling series
  ScalingSeries scaling;
};

int run_driver(RunSettings settings) {
  auto& systems = settings.systems;
  if (systems.empty()) systems = available_systems();
  // The TLS variants' certificates, made for this run and removed after it.
  std::optional<RunCertificates> certificates;
  if (std::any_of(systems.begin(), systems.end(), is_tls_variant)) certificates.emplace();
  const auto tls = certificates ? std::optional(certificates->files()) : std::nullopt;
  for (const auto& s : systems) make_system(s, tls);  // rejects a system not built in
  const std::string self = fs::read_symlink("/proc/self/exe").string();
  Driver driver(self, settings.quick, std::chrono::seconds(settings.timeout_s),
                std::chrono::seconds(settings.point_timeout_s), tls);
  Report report;
  report.systems = systems;
  report.repetitions = settings.reps;
  for (int r = 1; r <= settings.reps; ++r) {
    std::cerr << fmt::format("repetition {}/{}\n", r, settings.reps);
    for (const auto& s : systems) {
      if (settings.basic) driver.basic(s, report);
      driver.scaling(s, settings.scaling, report);
    }
  }
  report.print(std::cout);
  print_tls_cost(report, std::cout);
  write_results(report, settings.out_dir);
  return 0;
}

// The table and plots of a saved run (its compare.json), e.g. after the plots changed.
int run_plot(const fs::path& from, const fs::path& out_dir) {
  std::ifstream in(from);
  if (!in) throw std::runtime_error("cannot read " + from.string());
  const Report report = Report::from_json(json::parse(in));
  report.print(std::cout);
  print_tls_cost(report, std::cout);
  write_results(report, out_dir);
  return 0;
}

// Thousands of connections need thousands of descriptors: the soft limit goes up to the hard one
// (the children inherit it; each process raises its own as well).
void raise_descriptor_limit() {
  rlimit limit{};
  if (::getrlimit(RLIMIT_NOFILE, &limit) != 0 || limit.rlim_cur == limit.rlim_max) return;
  limit.rlim_cur = limit.rlim_max;
  if (::setrlimit(RLIMIT_NOFILE, &limit) != 0) {
    std::cerr << "icars-compare: cannot raise the descriptor limit (RLIMIT_NOFILE) to "
              << limit.rlim_max << "; points with many connections may be missing\n";
  }
}

}  // namespace
}  // namespace icars::bench

int main(int argc, char** argv) {
  using namespace icars::bench;
  std::signal(SIGPIPE, SIG_IGN);
  raise_descriptor_limit();
  CLI::App app{"icars-compare: PLANET, raw TCP, gRPC and ZeroC Ice side by side"};
  app.require_subcommand(1);

  RunSettings settings;
  std::string out_dir = settings.out_dir.string();
  std::vector<std::string> scaling;
  bool scaling_only = false;
  auto* run = app.add_subcommand("run", "run every workload over every system, repeated");
  run->add_option("--systems", settings.systems,
                  "systems to compare (default: every one built in)")
      ->delimiter(',');
  run->add_option("--reps", settings.reps, "repetitions (medians are reported)")
      ->check(CLI::Range(1, 100));
  run->add_option("--out", out_dir, "directory for compare.json, compare.csv and the plots");
  run->add_flag("--quick", settings.quick, "small sizes (a smoke run, not a measurement)");
  run->add_option("--timeout", settings.timeout_s, "seconds a client may take for one workload");
  run->add_option("--scaling", scaling,
                  "scaling series: connections, memory, fanout, all or none (default: all; "
                  "none with --quick)")
      ->delimiter(',')
      ->check(CLI::IsMember({"connections", "memory", "fanout", "all", "none"}));
  run->add_flag("--scaling-only", scaling_only,
                "run only the scaling series, not the other workloads");
  run->add_option("--point-timeout", settings.point_timeout_s,
                  "seconds one scaling point may take before it is reported missing")
      ->check(CLI::Range(1, 3600));

  std::string from;
  auto* plot = app.add_subcommand("plot", "print the table and draw the plots of a saved run");
  plot->add_option("--from", from, "the run's compare.json")->required();
  plot->add_option("--out", out_dir, "directory for compare.json, compare.csv and the plots");

  std::string system;
  int port = 0;
  std::vector<std::string> workloads;
  ClientSettings client_settings;
  std::string certs;
  auto* serve = app.add_subcommand("serve", "serve one system (started by run)");
  serve->add_option("--system", system)->required();
  serve->add_option("--port", port)->required()->check(CLI::Range(1, 65535));
  serve->add_option("--certs", certs, "a TLS variant's certificates (scripts/make-certs.sh DIR)")
      ->check(CLI::ExistingDirectory);
  auto* client = app.add_subcommand("client", "run workloads as a client (started by run)");
  client->add_option("--system", system)->required();
  client->add_option("--port", port)->required()->check(CLI::Range(1, 65535));
  client->add_option("--workloads", workloads)->required()->delimiter(',');
  client->add_flag("--quick", client_settings.quick);
  client->add_option("--connections", client_settings.connections)->check(CLI::Range(1, 100000));
  client->add_option("--subscribers", client_settings.subscribers)->check(CLI::Range(1, 100000));
  client->add_option("--server-pid", client_settings.server);
  client->add_option("--certs", certs, "a TLS variant's certificates (scripts/make-certs.sh DIR)")
      ->check(CLI::ExistingDirectory);

  CLI11_PARSE(app, argc, argv);
  try {
    if (run->parsed()) {
      settings.out_dir = out_dir;
      const auto chosen = [&](const char* series) {
        if (scaling.empty()) return scaling_only || !settings.quick;
        return std::find(scaling.begin(), scaling.end(), series) != scaling.end() ||
               std::find(scaling.begin(), scaling.end(), "all") != scaling.end();
      };
      settings.scaling = {chosen("connections"), chosen("memory"), chosen("fanout")};
      settings.basic = !scaling_only;
      return run_driver(settings);
    }
    if (plot->parsed()) return run_plot(from, out_dir);
    const auto tls = certs.empty() ? std::nullopt : std::optional(TlsFiles{certs});
    if (serve->parsed()) return run_server(system, static_cast<std::uint16_t>(port), tls);
    client_settings.tls = tls;
    return run_client(system, static_cast<std::uint16_t>(port), workloads, client_settings);
  } catch (const std::exception& e) {
    std::cerr << "icars-compare: " << e.what() << "\n";
    return 1;
  }
}
