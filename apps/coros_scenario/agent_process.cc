#include "agent_process.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace icars::coros_scenario {

namespace {

constexpr std::size_t kMaxLine = 1 << 20;  // a longer "line" is not an event: cut it

}  // namespace

AgentProcess::AgentProcess(std::string id, const std::vector<std::string>& argv,
                           const std::filesystem::path& log_file)
    : id_(std::move(id)) {
  if (argv.empty()) throw std::invalid_argument("AgentProcess: empty command");
  // Everything the child needs is prepared before fork: after it, only async-signal-safe calls.
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  int out[2];
  if (::pipe2(out, O_CLOEXEC) != 0) {
    throw std::runtime_error(std::string("cannot create a pipe: ") + std::strerror(errno));
  }
  const int log = ::open(log_file.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  const int null = ::open("/dev/null", O_RDONLY | O_CLOEXEC);
  if (log < 0 || null < 0) {
    const int error = errno;
    for (int fd : {out[0], out[1], log, null}) {
      if (fd >= 0) ::close(fd);
    }
    throw std::runtime_error("cannot open " + log_file.string() + ": " + std::strerror(error));
  }
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (::getppid() != parent) ::_exit(127);  // the parent died before prctl
    ::signal(SIGPIPE, SIG_DFL);
    ::dup2(null, STDIN_FILENO);
    ::dup2(out[1], STDOUT_FILENO);
    ::dup2(log, STDERR_FILENO);
    ::execv(args[0], args.data());
    const char* why = std::strerror(errno);
    const char prefix[] = "icars-coros: cannot execute the agent: ";
    [[maybe_unused]] auto w1 = ::write(STDERR_FILENO, prefix, sizeof prefix - 1);
    [[maybe_unused]] auto w2 = ::write(STDERR_FILENO, why, std::strlen(why));
    [[maybe_unused]] auto w3 = ::write(STDERR_FILENO, "\n", 1);
    ::_exit(127);
  }
  const int error = errno;
  ::close(out[1]);
  ::close(log);
  ::close(null);
  if (pid < 0) {
    ::close(out[0]);
    throw std::runtime_error("cannot start " + argv[0] + ": " + std::strerror(error));
  }
  pid_ = pid;
  stdout_fd_ = out[0];
}

AgentProcess::~AgentProcess() {
  if (pid_ > 0 && !status_) {
    ::kill(pid_, SIGKILL);
    int status = 0;
    while (::waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
    }
  }
  close_stdout();
}

void AgentProcess::close_stdout() {
  if (stdout_fd_ >= 0) ::close(stdout_fd_);
  stdout_fd_ = -1;
}

std::vector<std::string> AgentProcess::read_lines() {
  std::vector<std::string> lines;
  if (stdout_fd_ < 0) return lines;
  char chunk[65536];
  const ssize_t n = ::read(stdout_fd_, chunk, sizeof chunk);
  if (n < 0 && (errno == EINTR || errno == EAGAIN)) return lines;
  if (n > 0) buffer_.append(chunk, static_cast<std::size_t>(n));
  std::size_t begin = 0;
  for (std::size_t nl; (nl = buffer_.find('\n', begin)) != std::string::npos; begin = nl + 1) {
    lines.push_back(buffer_.substr(begin, nl - begin));
  }
  buffer_.erase(0, begin);
  if (buffer_.size() > kMaxLine) buffer_.clear();
  if (n <= 0) {  // end of file (or an error, which ends reading the same way)
    if (!buffer_.empty()) lines.push_back(std::move(buffer_));
    buffer_.clear();
    close_stdout();
  }
  return lines;
}

void AgentProcess::signal(int sig) const {
  if (pid_ > 0 && !status_) ::kill(pid_, sig);
}

bool AgentProcess::reap() {
  if (status_) return true;
  int status = 0;
  const pid_t r = ::waitpid(pid_, &status, WNOHANG);
  if (r == pid_) status_ = status;
  return status_.has_value();
}

std::string describe_wait_status(int status) {
  if (WIFEXITED(status)) return "exit code " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return "signal " + std::to_string(WTERMSIG(status));
  return "wait status " + std::to_string(status);
}

}  // namespace icars::coros_scenario
