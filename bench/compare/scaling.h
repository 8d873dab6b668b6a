// How cost grows: the scaling workloads of icars-compare, client side (docs/performance.md,
// "How cost grows"). Each point runs in a client process of its own against a fresh server, so
// that no point inherits another's connections, lapsed subscribers or freed memory; the driver
// (main.cc) bounds each point with a timeout and reports a point that fails as missing. All of
// it goes through the System contract (system.h), so every system runs it unchanged.
#pragma once

#include <sys/types.h>

#include <array>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "system.h"

namespace icars::bench {

// The points of the three series.
inline constexpr std::array<int, 4> kConnectionPoints = {1, 10, 100, 1000};
inline constexpr int kIdleConnections = 1000;
inline constexpr std::array<int, 4> kSubscriberPoints = {10, 100, 1000, 5000};

// The result keys of the points (the metric table, report.cc, lists the same keys).
std::string connections_calls_key(int connections);  // calls/s
std::string connections_p99_key(int connections);    // us
inline constexpr const char* kIdleConnectionKey = "idle_conn_kib";
std::string fan_out_key(int subscribers);  // deliveries/s

// Client threads that drive `connections` connections: min(connections, 2 x cores). A thread
// of synchronous calls waits for the server about half of the time, so two per core keep the
// client's share of the cores busy; more would measure the scheduler, not the system, and the
// points from 10 connections up then differ only in the number of connections.
int client_threads(int connections);

// What a point opened. The client process exits without closing it (std::_Exit, as after every
// workload), so that no point waits for thousands of connections to be torn down.
struct Opened {
  std::vector<std::unique_ptr<Client>> clients;
  std::unique_ptr<Subscribers> subscribers;
};

struct ConnectionsResult {
  int threads = 0;
  std::int64_t calls = 0;
  double calls_per_second = 0;
  double p99_us = 0;
};

// Opens `connections` Clients to one server and calls echo_int once on each; then
// client_threads(connections) threads each call their share of the connections round-robin
// (thread t: connections t, t + threads, ...), one synchronous call at a time, for `duration`
// after a warm-up of a tenth of it. Every call is timed. Throws the first failure, naming it.
ConnectionsResult drive_connections(System& system, std::uint16_t port, int connections,
                                    std::chrono::milliseconds duration, Opened& opened);

struct IdleMemoryResult {
  double fresh_kib = 0;  // the server's VmRSS before any connection
  double one_kib = 0;    // with one connection that has called
  double idle_kib = 0;   // with that one and `idle` more, each having called once, all idle
  int idle = 0;
  // What one more idle connection costs the server, past what its first connection set up.
  double per_connection_kib() const { return (idle_kib - one_kib) / idle; }
};

// Reads the server's resident memory (VmRSS of /proc/<server>/status, the server being a
// process on this machine) with one connection and then with `idle` more connections open,
// each of which has made one call, after letting the server settle for a second each time.
IdleMemoryResult measure_idle_memory(System& system, std::uint16_t port, pid_t server, int idle,
                                     Opened& opened);

// Subscribes `subscribers` connections, publishes a tenth of the events as a warm-up, then
// publishes `deliveries / subscribers` events (at least one) of 64 bytes and returns the
// deliveries per second until every subscriber has all of them. `timeout` bounds each publish.
double fan_out_to(System& system, std::uint16_t port, int subscribers, std::int64_t deliveries,
                  std::chrono::milliseconds timeout, Opened& opened);

// VmRSS of process `pid` in KiB; throws when /proc/<pid>/status cannot be read.
double resident_kib(pid_t pid);

}  // namespace icars::bench
