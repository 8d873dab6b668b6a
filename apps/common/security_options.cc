#include "security_options.h"

#include <fmt/format.h>

#include <nlohmann/json.hpp>

#include <fstream>
#include <map>

#include "icars/planet/connection.h"

namespace icars::app {

void add_tls_options(CLI::App& app, planet::TlsOptions& tls, Side side) {
  const std::map<std::string, planet::TlsMode> modes = {
      {"auto", planet::TlsMode::automatic}, {"on", planet::TlsMode::on}, {"off", planet::TlsMode::off}};
  app.add_option("--tls", tls.mode,
                 "TLS: auto (non-loopback links only), on (every link) or off (trusted network)")
      // The modes by name: CLI11 would print the enum's values (bytes) as characters.
      ->transform(CLI::CheckedTransformer(modes, CLI::ignore_case).description(""))
      ->type_name("{auto,on,off}")
      ->default_str("auto");
  app.add_option("--tls-ca", tls.ca_file, "PEM file of the CA that peers' certificates chain to")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-cert", tls.certificate_file, "PEM file of this endpoint's certificate")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-key", tls.private_key_file, "PEM file of its private key")
      ->check(CLI::ExistingFile);
  if (side == Side::server) {
    app.add_flag("--require-client-cert", tls.require_client_certificate,
                 "clients must present a certificate signed by --tls-ca (mutual TLS)");
  } else {
    app.add_option("--tls-server-name", tls.server_name,
                   "the name the server's certificate must carry (default: the host connected to)");
  }
}

void add_device_manager_options(CLI::App& app, DeviceManagerSecurity& security) {
  add_tls_options(app, security.tls, Side::client);
  app.add_option("--token-file", security.token_file, "file holding this device manager's token (docs/security.md)")
      ->check(CLI::ExistingFile);
}

sigset_t block_stop_signals() {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  return signals;
}

std::string read_token_file(const std::string& file) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error(fmt::format("cannot read the token file '{}'", file));
  std::string token;
  std::getline(in, token);
  const auto first = token.find_first_not_of(" \t\r");
  const auto last = token.find_last_not_of(" \t\r");
  token = first == std::string::npos ? std::string() : token.substr(first, last - first + 1);
  if (token.empty()) throw std::runtime_error(fmt::format("the token file '{}' is empty", file));
  if (token.size() > planet::kMaxTokenSize) {
    throw std::runtime_error(fmt::format("the token in '{}' is longer than {} bytes", file,
                                         planet::kMaxTokenSize));
  }
  return token;
}

std::vector<std::string> device_manager_paths() {
  // device::kRegistryPath and service::SensorAdaptor::listener_path(); the scenario tests run a
  // device manager with exactly these permissions.
  return {"/sf/registry", "/sf/listeners/*"};
}

std::string access_entry(const planet::Principal& principal) {
  nlohmann::ordered_json entry;
  entry["name"] = principal.name;
  entry["token_sha256"] = principal.token_sha256;
  entry["may_call"] = principal.may_call;
  if (!principal.devices.empty()) {
    entry["devices"] = principal.devices;
    entry["max_devices"] = principal.max_devices;
  }
  return entry.dump();
}

}  // namespace icars::app
