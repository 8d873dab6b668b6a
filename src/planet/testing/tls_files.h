// Certificates for tests, made the way a user makes them: scripts/make-certs.sh writes a home's
// certificate authority (ca.pem), a server certificate (server.pem/.key) and one certificate per
// client name (<name>.pem/.key) into a directory.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "icars/planet/security.h"

namespace planet_test {

// Runs scripts/make-certs.sh DIR [--client NAME]...; throws std::runtime_error when it fails.
void make_certificates(const std::filesystem::path& dir, const std::vector<std::string>& clients = {});

// A TLS listener with `dir`'s server certificate, trusting `dir`'s authority.
icars::planet::TlsOptions server_tls(const std::filesystem::path& dir);

// A TLS client trusting `ca_dir`'s authority; with `certificate`, presenting <certificate>.pem
// from `cert_dir` (default: `ca_dir`).
icars::planet::TlsOptions client_tls(const std::filesystem::path& ca_dir, const std::string& certificate = {},
                                     const std::filesystem::path& cert_dir = {});

}  // namespace planet_test
