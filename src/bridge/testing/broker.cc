#include "broker.h"

#include <netinet/in.h>
#include <pwd.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <stdexcept>

namespace bridge_test {

namespace {

namespace fs = std::filesystem;

// A port nobody listens on now (bound once and released).
int free_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  socklen_t len = sizeof a;
  if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
    if (fd >= 0) ::close(fd);
    throw std::runtime_error("broker: no free loopback port");
  }
  ::close(fd);
  return ntohs(a.sin_port);
}

bool accepts(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return false;
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
  ::close(fd);
  return ok;
}

}  // namespace

Broker::Broker(BrokerOptions options) : options_(std::move(options)) {
  char pattern[] = "/tmp/icars-broker-XXXXXX";
  if (!::mkdtemp(pattern)) throw std::runtime_error("broker: cannot make a temporary directory");
  dir_ = pattern;
  port_ = free_port();
  std::ofstream conf(dir_ + "/mosquitto.conf");
  conf << "listener " << port_ << " 127.0.0.1\n"
       << "persistence false\n"
       // Run as root, mosquitto would become user "mosquitto", who cannot read this directory.
       << "user " << (::getpwuid(::geteuid()) ? ::getpwuid(::geteuid())->pw_name : "root") << "\n"
       << "log_dest stderr\n"
       << "log_type error\n";
  if (!options_.tls_dir.empty()) {
    conf << "cafile " << options_.tls_dir << "/ca.pem\n"
         << "certfile " << options_.tls_dir << "/server.pem\n"
         << "keyfile " << options_.tls_dir << "/server.key\n";
  }
  if (options_.username.empty()) {
    conf << "allow_anonymous true\n";
  } else {
    const auto passwords = dir_ + "/passwords";
    const auto command = "mosquitto_passwd -b -c " + passwords + " '" + options_.username + "' '" +
                         options_.password + "' >/dev/null 2>&1";
    if (std::system(command.c_str()) != 0) throw std::runtime_error("broker: mosquitto_passwd failed");
    conf << "allow_anonymous false\npassword_file " << passwords << "\n";
  }
  conf.close();
  start();
}

Broker::~Broker() {
  kill();
  std::error_code ignored;
  fs::remove_all(dir_, ignored);
}

void Broker::start() {
  process_ = std::make_unique<planet_test::ChildProcess>(
      std::vector<std::string>{"/usr/sbin/mosquitto", "-c", dir_ + "/mosquitto.conf"});
  if (!planet_test::wait_until([this] { return accepts(port_); }, std::chrono::seconds(20))) {
    process_.reset();
    throw std::runtime_error("broker: mosquitto did not listen on port " + std::to_string(port_));
  }
}

void Broker::kill() {
  if (!process_) return;
  process_->signal(SIGKILL);
  process_->wait();
  process_.reset();
}

void Broker::restart() {
  kill();
  start();
}

}  // namespace bridge_test
