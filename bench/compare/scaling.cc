#include "scaling.h"

#include <fmt/format.h>

#include <algorithm>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <vector>

#include "percentile.h"

namespace icars::bench {
namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

constexpr const char* kHost = "127.0.0.1";

// The calls of one client thread in one phase (warm-up or measurement).
struct ThreadCalls {
  std::vector<double> us;
  std::string error;
};

// Runs `threads` threads, thread t calling connections t, t + threads, ... in turn until `end`;
// returns what each did. A thread stops at its first failure.
std::vector<ThreadCalls> call_round_robin(std::vector<std::unique_ptr<Client>>& clients,
                                          int threads, Clock::time_point end) {
  std::vector<ThreadCalls> results(static_cast<std::size_t>(threads));
  std::vector<std::thread> pool;
  pool.reserve(results.size());
  const std::size_t n = clients.size();
  for (std::size_t t = 0; t < results.size(); ++t) {
    pool.emplace_back([&, t] {
      ThreadCalls& mine = results[t];
      mine.us.reserve(1u << 16);
      std::size_t next = t;
      for (std::int32_t x = 0;; ++x) {
        const auto start = Clock::now();
        if (start >= end) break;
        try {
          const std::int32_t got = clients[next]->call(x);
          if (got != x) {
            throw std::runtime_error(fmt::format("echo_int({}) answered {}", x, got));
          }
        } catch (const std::exception& e) {
          mine.error = fmt::format("call {} of thread {} on connection {}: {}", mine.us.size() + 1,
                                   t, next, e.what());
          return;
        }
        mine.us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - start).count());
        next += results.size();
        if (next >= n) next = t;
      }
    });
  }
  for (auto& thread : pool) thread.join();
  for (const auto& r : results) {
    if (!r.error.empty()) throw std::runtime_error(r.error);
  }
  return results;
}

// Opens connection `i` (of `of`) and calls echo_int on it once, so that both ends have set it up.
void open_and_call(System& system, std::uint16_t port, int i, int of,
                   std::vector<std::unique_ptr<Client>>& clients) {
  try {
    clients.push_back(system.connect(kHost, port));
    if (clients.back()->call(i) != i) throw std::runtime_error("echo_int answered another value");
  } catch (const std::exception& e) {
    throw std::runtime_error(fmt::format("connection {} of {}: {}", i + 1, of, e.what()));
  }
}

}  // namespace

std::string connections_calls_key(int connections) {
  return fmt::format("conn{}_calls_s", connections);
}

std::string connections_p99_key(int connections) {
  return fmt::format("conn{}_p99_us", connections);
}

std::string fan_out_key(int subscribers) {
  return fmt::format("fanout{}_deliveries_s", subscribers);
}

int client_threads(int connections) {
  const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  return std::max(1, std::min(connections, 2 * cores));
}

ConnectionsResult drive_connections(System& system, std::uint16_t port, int connections,
                                    std::chrono::milliseconds duration, Opened& opened) {
  auto& clients = opened.clients;
  for (int i = 0; i < connections; ++i) open_and_call(system, port, i, connections, clients);
  ConnectionsResult result;
  result.threads = client_threads(connections);
  call_round_robin(clients, result.threads, Clock::now() + duration / 10);  // warm-up
  const auto start = Clock::now();
  const auto measured = call_round_robin(clients, result.threads, start + duration);
  const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
  std::vector<double> us;
  for (const auto& r : measured) us.insert(us.end(), r.us.begin(), r.us.end());
  result.calls = static_cast<std::int64_t>(us.size());
  result.calls_per_second = static_cast<double>(us.size()) / elapsed;
  result.p99_us = percentile(std::move(us), 0.99);
  return result;
}

double resident_kib(pid_t pid) {
  const std::string path = fmt::format("/proc/{}/status", pid);
  std::ifstream status(path);
  for (std::string line; std::getline(status, line);) {
    if (line.starts_with("VmRSS:")) {
      std::istringstream fields(line.substr(6));
      double kib = 0;
      if (fields >> kib) return kib;
    }
  }
  throw std::runtime_error("no VmRSS in " + path + " (has the server exited?)");
}

IdleMemoryResult measure_idle_memory(System& system, std::uint16_t port, pid_t server, int idle,
                                     Opened& opened) {
  IdleMemoryResult result;
  result.idle = idle;
  result.fresh_kib = resident_kib(server);
  open_and_call(system, port, 0, idle + 1, opened.clients);
  std::this_thread::sleep_for(1s);
  result.one_kib = resident_kib(server);
  for (int i = 1; i <= idle; ++i) open_and_call(system, port, i, idle + 1, opened.clients);
  std::this_thread::sleep_for(1s);
  result.idle_kib = resident_kib(server);
  return result;
}

double fan_out_to(System& system, std::uint16_t port, int subscribers, std::int64_t deliveries,
                  std::chrono::milliseconds timeout, Opened& opened) {
  constexpr std::size_t kPayload = 64;
  opened.subscribers = system.subscribe(kHost, port, subscribers);
  Subscribers& subscribed = *opened.subscribers;
  const int events = static_cast<int>(std::max<std::int64_t>(1, deliveries / subscribers));
  subscribed.publish_and_wait(std::max(1, events / 10), kPayload, timeout);  // warm-up
  const auto start = Clock::now();
  subscribed.publish_and_wait(events, kPayload, timeout);
  const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
  return static_cast<double>(events) * subscribers / elapsed;
}

}  // namespace icars::bench
