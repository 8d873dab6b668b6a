// A PLANET server process for tests and benchmarks: serves the Echo servant at /echo and prints
// "READY <port>" on stdout once it listens. With --tick-every-ms it also serves a TickSource at
// /ticks and publishes a Tick (seq 0, 1, 2, ...) to its subscribers that often; with --tls-dir
// it listens with TLS.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <stop_token>
#include <csignal>
#include <cstdio>
#include <iostream>
#include <thread>

#include "icars/planet/communicator.h"
#include "icars/planet/publisher.h"
#include "test_interfaces.h"
#include "tls_files.h"

int main(int argc, char** argv) {
  CLI::App app{"PLANET test server"};
  std::uint16_t port = 0;
  int heartbeat_ms = 1000;
  int heartbeat_timeout_ms = 5000;
  std::size_t max_message = 64u << 20;
  std::string pun;
  int tick_every_ms = 0;
  app.add_option("--port", port, "port to listen on (0: any)");
  app.add_option("--tick-every-ms", tick_every_ms, "publish a Tick at /ticks this often (0: no /ticks)");
  app.add_option("--heartbeat-ms", heartbeat_ms);
  app.add_option("--heartbeat-timeout-ms", heartbeat_timeout_ms);
  app.add_option("--max-message", max_message, "max_message_size in bytes");
  app.add_option("--pun", pun);
  std::string tls_dir;
  app.add_option("--tls-dir", tls_dir, "listen with TLS: the server certificate of scripts/make-certs.sh's DIR");
  CLI11_PARSE(app, argc, argv);

  // Block the stop signals before any thread starts, so every thread inherits the mask.
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGINT);
  pthread_sigmask(SIG_BLOCK, &set, nullptr);

  icars::planet::CommunicatorOptions options;
  options.connection.heartbeat_interval = std::chrono::milliseconds(heartbeat_ms);
  options.connection.heartbeat_timeout = std::chrono::milliseconds(heartbeat_timeout_ms);
  options.connection.max_message_size = max_message;
  options.pun = pun;
  options.name = "test-server";
  if (!tls_dir.empty()) options.tls = planet_test::server_tls(tls_dir);
  icars::planet::Communicator communicator(options);
  communicator.adapter().add("/echo", planet_test::make_echo_servant(communicator));
  communicator.adapter().add("/streams", planet_test::make_streams_servant(communicator));
  icars::planet::Publisher<planet_test::Tick> ticks(planet_test::TickListener::on_tick);
  if (tick_every_ms > 0) {
    auto source = std::make_shared<icars::planet::Servant>(std::string(planet_test::TickSource::type_id));
    source->implement(planet_test::TickSource::subscribe,
                      [&](icars::planet::Ref<planet_test::TickListener> listener, const icars::planet::Current& c) {
                        ticks.subscribe(icars::planet::Proxy(communicator, c.connection, listener.object()));
                      });
    communicator.adapter().add("/ticks", source);
  }
  const auto bound = communicator.listen("127.0.0.1", port);
  std::cout << "READY " << bound << std::endl;
  // The ticker: a stopped process (SIGSTOP) publishes the tick that fell due at once when it
  // runs again.
  std::jthread ticker;
  if (tick_every_ms > 0) {
    ticker = std::jthread([&](std::stop_token stop) {
      std::int64_t seq = 0;
      auto next = std::chrono::steady_clock::now();
      while (!stop.stop_requested()) {
        ticks.publish(planet_test::Tick{seq++, {}});
        next += std::chrono::milliseconds(tick_every_ms);
        std::this_thread::sleep_until(next);
        next = std::max(next, std::chrono::steady_clock::now());
      }
    });
  }
  int sig = 0;
  sigwait(&set, &sig);
  return 0;
}
