#include "tls_files.h"

#include <sys/wait.h>

#include <stdexcept>

#include "child_process.h"

namespace planet_test {

namespace fs = std::filesystem;

void make_certificates(const fs::path& dir, const std::vector<std::string>& clients) {
  std::vector<std::string> argv = {"/bin/bash", ICARS_MAKE_CERTS_SCRIPT, dir.string()};
  for (const auto& client : clients) {
    argv.emplace_back("--client");
    argv.push_back(client);
  }
  ChildProcess script(argv);
  const int status = script.wait();
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || !fs::exists(dir / "server.pem")) {
    throw std::runtime_error("make-certs.sh failed for " + dir.string());
  }
}

icars::planet::TlsOptions server_tls(const fs::path& dir) {
  icars::planet::TlsOptions tls;
  tls.mode = icars::planet::TlsMode::on;
  tls.ca_file = (dir / "ca.pem").string();
  tls.certificate_file = (dir / "server.pem").string();
  tls.private_key_file = (dir / "server.key").string();
  return tls;
}

icars::planet::TlsOptions client_tls(const fs::path& ca_dir, const std::string& certificate,
                                     const fs::path& cert_dir) {
  icars::planet::TlsOptions tls;
  tls.mode = icars::planet::TlsMode::on;
  tls.ca_file = (ca_dir / "ca.pem").string();
  if (!certificate.empty()) {
    const fs::path dir = cert_dir.empty() ? ca_dir : cert_dir;
    tls.certificate_file = (dir / (certificate + ".pem")).string();
    tls.private_key_file = (dir / (certificate + ".key")).string();
  }
  return tls;
}

}  // namespace planet_test
