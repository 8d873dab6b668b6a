// The TLS variants of the compared systems ("planet-tls", "grpc-tls", "ice-tls"): which systems
// are one, the certificates a run makes for them, and what TLS costs each system in a run's
// results. A variant runs only the small call and the upload: what TLS changes is the cost of a
// round trip and of moving bytes (docs/performance.md).
#pragma once

#include <ostream>
#include <string>
#include <vector>

#include "report.h"
#include "system.h"

namespace icars::bench {

// True for "planet-tls" and the like.
bool is_tls_variant(const std::string& system);
// The system a variant adds TLS to: "planet" for "planet-tls".
std::string plain_system(const std::string& variant);
// The workloads a variant runs.
std::vector<std::string> tls_workloads();

// PLANET's target: its small call p50 with TLS at most this many times its plain one.
constexpr double kPlanetTlsSmallCallTarget = 1.3;

// A fresh directory under the system's temporary directory holding a CA and a server
// certificate made by scripts/make-certs.sh, removed with everything in it when this goes.
// Throws std::runtime_error when the script fails (it needs the openssl command).
class RunCertificates {
 public:
  RunCertificates();
  ~RunCertificates();
  RunCertificates(const RunCertificates&) = delete;
  RunCertificates& operator=(const RunCertificates&) = delete;

  const TlsFiles& files() const { return files_; }

 private:
  TlsFiles files_;
};

// For every TLS variant in `report` whose plain system is there too: its small call and upload
// medians over the plain system's, and whether PLANET's TLS small call p50 is within
// kPlanetTlsSmallCallTarget of its plain one. Prints nothing when there is no such pair.
void print_tls_cost(const Report& report, std::ostream& out);

}  // namespace icars::bench
