// Test support: child processes with a piped stdout, and waiting on conditions with bounds.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <cstdint>
#include <memory>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace planet_test {

class ChildProcess {
 public:
  // Starts argv[0] with the given arguments; its stdout is readable with read_line().
  explicit ChildProcess(const std::vector<std::string>& argv);
  ~ChildProcess();  // SIGKILL and reap, if still running
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  pid_t pid() const { return pid_; }
  void signal(int sig) const;
  // SIGSTOP, returning once the process is really stopped (a signal is delivered asynchronously,
  // so a busy process may run on for a moment after kill() returns).
  void freeze();
  void thaw() const;  // SIGCONT
  // The next line of stdout, or nullopt at EOF or after the timeout.
  std::optional<std::string> read_line(std::chrono::milliseconds timeout);
  // Waits for exit and returns the raw wait status.
  int wait();
  // Like wait(), but gives up after `timeout` (nullopt: still running).
  std::optional<int> wait_for(std::chrono::milliseconds timeout);

 private:
  pid_t pid_ = -1;
  int stdout_fd_ = -1;
  std::string buffer_;
  bool reaped_ = false;
};

// Starts the PLANET test server (src/planet/testing/test_server.cc) and returns it with the
// port it reported. Extra arguments are passed through.
struct TestServer {
  std::unique_ptr<ChildProcess> process;
  std::uint16_t port = 0;
};
TestServer start_test_server(std::vector<std::string> extra_args = {});

// The path of the subscriber process of the publish/subscribe tests (event_subscriber.cc).
std::string event_subscriber_path();

// Polls `condition` until it holds or `timeout` passes; returns its last value.
bool wait_until(const std::function<bool()>& condition,
                std::chrono::milliseconds timeout = std::chrono::seconds(20));

}  // namespace planet_test
