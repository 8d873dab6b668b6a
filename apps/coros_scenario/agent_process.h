// One icars-agent child process: started with its configuration file, its stdout read line by
// line through a pipe, its stderr in a log file, stopped by signal and reaped.
//
// Children get SIGKILL when this process dies (PR_SET_PDEATHSIG), so agents never outlive the
// scenario even when it is killed itself. Not thread-safe: one thread owns all the processes
// (the scenario polls their stdout together).
#pragma once

#include <sys/types.h>

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace icars::coros_scenario {

class AgentProcess {
 public:
  // Starts `binary args...` with stdout piped to us and stderr appended to `log_file`.
  // Throws std::runtime_error naming the binary when it cannot be started.
  AgentProcess(std::string id, const std::vector<std::string>& argv,
               const std::filesystem::path& log_file);
  ~AgentProcess();  // SIGKILL and reap when still running
  AgentProcess(const AgentProcess&) = delete;
  AgentProcess& operator=(const AgentProcess&) = delete;

  const std::string& id() const { return id_; }
  pid_t pid() const { return pid_; }
  int stdout_fd() const { return stdout_fd_; }  // -1 after end of file

  // Reads what is there (call when poll() says readable) and returns the complete lines;
  // at end of file also the unterminated rest, and the descriptor is closed.
  std::vector<std::string> read_lines();

  void signal(int sig) const;  // nothing once reaped
  // Reaps the process when it has exited (never blocks); true once it has.
  bool reap();
  bool exited() const { return status_.has_value(); }
  std::optional<int> wait_status() const { return status_; }

 private:
  void close_stdout();

  std::string id_;
  pid_t pid_ = -1;
  int stdout_fd_ = -1;
  std::string buffer_;
  std::optional<int> status_;
};

// "exit code 1", "signal 9": a raw wait status in words.
std::string describe_wait_status(int status);

}  // namespace icars::coros_scenario
