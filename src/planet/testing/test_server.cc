// A PLANET server process for tests and benchmarks: serves the Echo servant at /echo and prints
// "READY <port>" on stdout once it listens.
#include <CLI/CLI.hpp>
#include <csignal>
#include <cstdio>
#include <iostream>
#include <thread>

#include "icars/planet/communicator.h"
#include "test_interfaces.h"

int main(int argc, char** argv) {
  CLI::App app{"PLANET test server"};
  std::uint16_t port = 0;
  int heartbeat_ms = 1000;
  int heartbeat_timeout_ms = 5000;
  std::size_t max_message = 64u << 20;
  std::string pun;
  app.add_option("--port", port, "port to listen on (0: any)");
  app.add_option("--heartbeat-ms", heartbeat_ms);
  app.add_option("--heartbeat-timeout-ms", heartbeat_timeout_ms);
  app.add_option("--max-message", max_message, "max_message_size in bytes");
  app.add_option("--pun", pun);
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
  icars::planet::Communicator communicator(options);
  communicator.adapter().add("/echo", planet_test::make_echo_servant(communicator));
  communicator.adapter().add("/streams", planet_test::make_streams_servant(communicator));
  const auto bound = communicator.listen("127.0.0.1", port);
  std::cout << "READY " << bound << std::endl;
  int sig = 0;
  sigwait(&set, &sig);
  return 0;
}
