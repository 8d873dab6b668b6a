// Test support: a real Mosquitto broker (Debian's `mosquitto`) started by the test on a free
// loopback port, optionally with a password file and TLS, and killed and started again on the
// same port.
#pragma once

#include <memory>
#include <string>

#include "child_process.h"

namespace bridge_test {

struct BrokerOptions {
  std::string username{};  // set: the broker admits only this user with `password`
  std::string password{};
  // Set: the broker listens with TLS only, with this directory's server.pem and server.key,
  // signed by its ca.pem (planet_test::make_certificates).
  std::string tls_dir{};
};

class Broker {
 public:
  // Starts the broker and waits until it accepts connections (throws std::runtime_error when it
  // does not within 20 s).
  explicit Broker(BrokerOptions options = {});
  ~Broker();  // kills it and removes its files
  Broker(const Broker&) = delete;
  Broker& operator=(const Broker&) = delete;

  int port() const { return port_; }
  void kill();     // SIGKILL: clients see the connection drop
  void restart();  // starts it again on the same port (after kill())
  bool running() const { return process_ != nullptr; }

 private:
  void start();

  BrokerOptions options_;
  std::string dir_;
  int port_ = 0;
  std::unique_ptr<planet_test::ChildProcess> process_;
};

}  // namespace bridge_test
