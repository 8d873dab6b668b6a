// icars-compare: the same workloads over raw TCP, PLANET, gRPC and ZeroC Ice, client and server
// in separate processes on loopback, repeated; prints the medians and the ratios to raw TCP and
// to PLANET, and writes them as JSON, CSV and a PNG plot (gnuplot). docs/performance.md
// explains every workload and the results.
//
//   icars-compare run [--systems raw-tcp,planet,grpc,ice] [--reps 5] [--out DIR] [--quick]
//   icars-compare serve --system S --port P       (started by `run`)
//   icars-compare client --system S --port P --workloads small,pipeline,...   (started by `run`)
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
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
#include "system.h"

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
  return names;
}

std::unique_ptr<System> make_system(const std::string& name) {
  if (name == "raw-tcp") return make_raw_tcp();
  if (name == "planet") return make_planet();
#ifdef ICARS_BENCH_WITH_GRPC
  if (name == "grpc") return make_grpc();
#endif
#ifdef ICARS_BENCH_WITH_ICE
  if (name == "ice") return make_ice();
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

double percentile(std::vector<double> values, double p) {
  if (values.empty()) return std::nan("");
  std::sort(values.begin(), values.end());
  const auto rank = static_cast<std::size_t>(std::ceil(p * static_cast<double>(values.size())));
  return values[std::min(values.size() - 1, rank == 0 ? 0 : rank - 1)];
}

double median(std::vector<double> values) { return percentile(std::move(values), 0.5); }

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
void head_of_line(System& system, Client& client, const Sizes& sizes) {
  const Bytes big = pattern(sizes.hol_echo);
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

int run_client(const std::string& system_name, std::uint16_t port,
               const std::vector<std::string>& workloads, bool quick) {
  const Sizes sizes = quick ? Sizes::quick() : Sizes{};
  auto system = make_system(system_name);
  auto client = system->connect("127.0.0.1", port);
  for (const auto& w : workloads) {
    if (w == "small") {
      small_calls(*client, sizes);
    } else if (w == "pipeline") {
      pipelined(*system, port, 1, sizes);
    } else if (w == "pipeline8") {
      pipelined(*system, port, 8, sizes);
    } else if (w == "upload") {
      uploads(*client, sizes);
    } else if (w == "hol") {
      head_of_line(*system, *client, sizes);
    } else if (w == "fanout") {
      fan_out(*system, port, sizes);
    } else if (w == "reconnect") {
      reconnect(*client);
    } else {
      throw std::invalid_argument("unknown workload '" + w + "'");
    }
  }
  std::cout.flush();
  std::_Exit(0);  // skip the libraries' teardown: the measurements are out
}

int run_server(const std::string& system_name, std::uint16_t port) {
  auto system = make_system(system_name);
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

// One metric of the table: its unit, and whether larger is better.
struct Metric {
  std::string key;
  std::string label;
  std::string unit;
  bool higher_better;
};

const std::vector<Metric>& metrics() {
  static const std::vector<Metric> all = {
      {"small_p50_us", "small call p50", "us", false},
      {"small_p99_us", "small call p99", "us", false},
      {"pipeline1_calls_s", "pipelined calls, 1 client", "calls/s", true},
      {"pipeline8_calls_s", "pipelined calls, 8 clients", "calls/s", true},
      {"upload_1mib_mib_s", "1 MiB upload", "MiB/s", true},
      {"upload_64mib_mib_s", "64 MiB upload", "MiB/s", true},
      {"upload_8mib_mib_s", "8 MiB upload", "MiB/s", true},
      {"hol_echo_ms", "large echo (HOL)", "ms", false},
      {"hol_small_p50_us", "small call p50 during echo", "us", false},
      {"hol_small_p99_us", "small call p99 during echo", "us", false},
      {"hol_small_max_ms", "small call max during echo", "ms", false},
      {"hol_small_calls", "small calls during echo", "calls", true},
      {"fanout_deliveries_s", "event fan-out", "deliveries/s", true},
      {"reconnect_ms", "reconnection", "ms", false},
  };
  return all;
}

// samples[system][metric] = one value per repetition.
using Samples = std::map<std::string, std::map<std::string, std::vector<double>>>;

class Driver {
 public:
  Driver(std::string self, bool quick, std::chrono::seconds timeout)
      : self_(std::move(self)), quick_(quick), timeout_(timeout) {}

  void repetition(const std::string& system, Samples& samples) {
    run_workloads(system, samples);
    run_reconnect(system, samples);
  }

 private:
  struct Server {
    std::unique_ptr<planet_test::ChildProcess> process;
    std::int64_t ready_ns = 0;
  };

  Server start_server(const std::string& system, std::uint16_t port) {
    Server s;
    s.process = std::make_unique<planet_test::ChildProcess>(std::vector<std::string>{
        self_, "serve", "--system", system, "--port", std::to_string(port)});
    const auto line = s.process->read_line(30s);
    if (!line || line->rfind("ready ", 0) != 0) {
      throw std::runtime_error(system + " server did not start");
    }
    s.ready_ns = std::stoll(line->substr(6));
    return s;
  }

  std::unique_ptr<planet_test::ChildProcess> start_client(const std::string& system,
                                                          std::uint16_t port,
                                                          const std::string& workloads) {
    std::vector<std::string> argv = {self_, "client", "--system", system, "--port",
                                     std::to_string(port), "--workloads", workloads};
    if (quick_) argv.emplace_back("--quick");
    return std::make_unique<planet_test::ChildProcess>(argv);
  }

  json next_result(planet_test::ChildProcess& client, const std::string& system) {
    const auto line = client.read_line(timeout_);
    if (!line) throw std::runtime_error(system + " client stopped or timed out");
    return json::parse(*line);
  }

  static void record(const json& result, const std::string& system, Samples& samples) {
    for (const auto& [key, value] : result.items()) {
      if (value.is_number()) samples[system][key].push_back(value.get<double>());
    }
  }

  void run_workloads(const std::string& system, Samples& samples) {
    const std::uint16_t port = free_tcp_port();
    Server server = start_server(system, port);
    auto client = start_client(system, port, "small,pipeline,pipeline8,upload,hol,fanout");
    for (int i = 0; i < 6; ++i) {
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

  std::string self_;
  bool quick_;
  std::chrono::seconds timeout_;
};

std::string format_value(double v) {
  if (std::isnan(v)) return "-";
  if (v >= 1e6) return fmt::format("{:.2f}M", v / 1e6);
  if (v >= 1e4) return fmt::format("{:.0f}k", v / 1e3);
  if (v >= 100) return fmt::format("{:.0f}", v);
  if (v >= 10) return fmt::format("{:.1f}", v);
  return fmt::format("{:.2f}", v);
}

struct Report {
  std::vector<std::string> systems;
  Samples samples;

  double med(const std::string& system, const std::string& key) const {
    const auto s = samples.find(system);
    if (s == samples.end()) return std::nan("");
    const auto m = s->second.find(key);
    return m == s->second.end() ? std::nan("") : median(m->second);
  }

  bool has(const std::string& key) const {
    return std::any_of(systems.begin(), systems.end(),
                       [&](const auto& s) { return !std::isnan(med(s, key)); });
  }

  void print(std::ostream& out, int reps) const {
    out << fmt::format("\nMedians of {} repetitions (client and server in separate processes on "
                       "loopback). Ratios: x/raw = system / raw TCP, x/planet = system / PLANET.\n\n",
                       reps);
    std::string head = fmt::format("{:30} {:>13}", "workload", "unit");
    for (const auto& s : systems) head += fmt::format(" {:>9}", s);
    for (const auto& s : systems) {
      if (s != "raw-tcp") head += fmt::format(" {:>11}", s + "/raw");
    }
    for (const auto& s : systems) {
      if (s != "raw-tcp" && s != "planet") head += fmt::format(" {:>12}", s + "/planet");
    }
    out << head << "\n" << std::string(head.size(), '-') << "\n";
    for (const auto& m : metrics()) {
      if (!has(m.key)) continue;
      std::string row = fmt::format("{:30} {:>13}", m.label, m.unit);
      for (const auto& s : systems) row += fmt::format(" {:>9}", format_value(med(s, m.key)));
      const double raw = med("raw-tcp", m.key);
      const double planet = med("planet", m.key);
      for (const auto& s : systems) {
        if (s != "raw-tcp") row += fmt::format(" {:>11}", format_value(med(s, m.key) / raw));
      }
      for (const auto& s : systems) {
        if (s != "raw-tcp" && s != "planet") {
          row += fmt::format(" {:>12}", format_value(med(s, m.key) / planet));
        }
      }
      out << row << "\n";
    }
    out << "\n(higher is better for calls/s, MiB/s, deliveries/s and calls; lower for the rest)\n";
  }

  json to_json(int reps) const {
    json rows = json::array();
    for (const auto& m : metrics()) {
      for (const auto& s : systems) {
        const auto sys = samples.find(s);
        if (sys == samples.end() || !sys->second.contains(m.key)) continue;
        const auto& values = sys->second.at(m.key);
        rows.push_back({{"workload", m.key},
                        {"label", m.label},
                        {"unit", m.unit},
                        {"higher_is_better", m.higher_better},
                        {"system", s},
                        {"median", median(values)},
                        {"min", *std::min_element(values.begin(), values.end())},
                        {"max", *std::max_element(values.begin(), values.end())},
                        {"runs", values},
                        {"ratio_to_raw_tcp", med(s, m.key) / med("raw-tcp", m.key)},
                        {"ratio_to_planet", med(s, m.key) / med("planet", m.key)}});
      }
    }
    return {{"repetitions", reps}, {"systems", systems}, {"rows", rows}};
  }

  void write_csv(const fs::path& file) const {
    std::ofstream out(file);
    out << "workload,unit,system,median,min,max,ratio_to_raw_tcp,ratio_to_planet\n";
    for (const auto& m : metrics()) {
      for (const auto& s : systems) {
        const auto sys = samples.find(s);
        if (sys == samples.end() || !sys->second.contains(m.key)) continue;
        const auto& v = sys->second.at(m.key);
        out << fmt::format("{},{},{},{},{},{},{},{}\n", m.key, m.unit, s, median(v),
                           *std::min_element(v.begin(), v.end()),
                           *std::max_element(v.begin(), v.end()),
                           med(s, m.key) / med("raw-tcp", m.key),
                           med(s, m.key) / med("planet", m.key));
      }
    }
  }

  // A clustered bar chart of every system's median relative to PLANET, on a log scale, each
  // workload labelled with the direction that is better.
  bool plot(const fs::path& png) const {
    const fs::path data = fs::path(png).replace_extension(".dat");
    const fs::path script = fs::path(png).replace_extension(".gp");
    {
      std::ofstream out(data);
      out << "# workload";
      for (const auto& s : systems) out << " " << s;
      out << "\n";
      for (const auto& m : metrics()) {
        if (!has(m.key) || m.key == "hol_small_calls") continue;
        out << '"' << m.label << (m.higher_better ? " (higher better)" : " (lower better)") << '"';
        for (const auto& s : systems) {
          const double r = med(s, m.key) / med("planet", m.key);
          out << " " << (std::isnan(r) || r <= 0 ? std::string("NaN") : fmt::format("{:.4f}", r));
        }
        out << "\n";
      }
    }
    {
      std::ofstream out(script);
      out << "set terminal pngcairo size 1400,700 font 'sans,10'\n"
          << "set output '" << png.string() << "'\n"
          << "set title 'icars-compare: each system relative to PLANET (= 1), medians'\n"
          << "set style data histograms\nset style histogram clustered gap 1\n"
          << "set style fill solid 0.85 border -1\nset boxwidth 0.9\n"
          << "set logscale y 10\nset grid ytics\nset ylabel 'system / PLANET (log scale)'\n"
          << "set xtics rotate by -35 left noenhanced\nset key top left\n"
          << "set bmargin 13\nset rmargin 16\n";
      out << "plot ";
      for (std::size_t i = 0; i < systems.size(); ++i) {
        out << (i ? ", " : "") << "'" << data.string() << "' using " << i + 2
            << (i == 0 ? ":xtic(1)" : "") << " title '" << systems[i] << "'";
      }
      out << "\n";
    }
    const std::string command = fmt::format("gnuplot '{}' 2>&1", script.string());
    return std::system(command.c_str()) == 0;
  }
};

int run_driver(std::vector<std::string> systems, int reps, const fs::path& out_dir, bool quick,
               int timeout_s) {
  if (systems.empty()) systems = available_systems();
  for (const auto& s : systems) make_system(s);  // rejects a system not built in
  const std::string self = fs::read_symlink("/proc/self/exe").string();
  Driver driver(self, quick, std::chrono::seconds(timeout_s));
  Report report{systems, {}};
  for (int r = 1; r <= reps; ++r) {
    std::cerr << fmt::format("repetition {}/{}\n", r, reps);
    for (const auto& s : systems) driver.repetition(s, report.samples);
  }
  report.print(std::cout, reps);
  fs::create_directories(out_dir);
  std::ofstream(out_dir / "compare.json") << report.to_json(reps).dump(2) << "\n";
  report.write_csv(out_dir / "compare.csv");
  const bool plotted = report.plot(fs::absolute(out_dir / "compare.png"));
  std::cout << fmt::format("\nresults: {}/compare.json, compare.csv{}\n", out_dir.string(),
                           plotted ? ", compare.png" : " (no plot: gnuplot failed or missing)");
  return 0;
}

}  // namespace
}  // namespace icars::bench

int main(int argc, char** argv) {
  using namespace icars::bench;
  std::signal(SIGPIPE, SIG_IGN);
  CLI::App app{"icars-compare: PLANET, raw TCP, gRPC and ZeroC Ice side by side"};
  app.require_subcommand(1);

  std::vector<std::string> systems;
  int reps = 5;
  std::string out_dir = "bench-results";
  bool quick = false;
  int timeout_s = 600;
  auto* run = app.add_subcommand("run", "run every workload over every system, repeated");
  run->add_option("--systems", systems, "systems to compare (default: every one built in)")
      ->delimiter(',');
  run->add_option("--reps", reps, "repetitions (medians are reported)")->check(CLI::Range(1, 100));
  run->add_option("--out", out_dir, "directory for compare.json, compare.csv, compare.png");
  run->add_flag("--quick", quick, "small sizes (a smoke run, not a measurement)");
  run->add_option("--timeout", timeout_s, "seconds a client may take for one workload");

  std::string system;
  int port = 0;
  std::vector<std::string> workloads;
  auto* serve = app.add_subcommand("serve", "serve one system (started by run)");
  serve->add_option("--system", system)->required();
  serve->add_option("--port", port)->required()->check(CLI::Range(1, 65535));
  auto* client = app.add_subcommand("client", "run workloads as a client (started by run)");
  client->add_option("--system", system)->required();
  client->add_option("--port", port)->required()->check(CLI::Range(1, 65535));
  client->add_option("--workloads", workloads)->required()->delimiter(',');
  client->add_flag("--quick", quick);

  CLI11_PARSE(app, argc, argv);
  try {
    if (run->parsed()) return run_driver(systems, reps, out_dir, quick, timeout_s);
    if (serve->parsed()) return run_server(system, static_cast<std::uint16_t>(port));
    return run_client(system, static_cast<std::uint16_t>(port), workloads, quick);
  } catch (const std::exception& e) {
    std::cerr << "icars-compare: " << e.what() << "\n";
    return 1;
  }
}
