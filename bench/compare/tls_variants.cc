#include "tls_variants.h"

#include <fmt/format.h>
#include <stdlib.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <filesystem>
#include <stdexcept>
#include <string_view>
#include <system_error>

#include "tls_files.h"

namespace icars::bench {
namespace {

namespace fs = std::filesystem;

constexpr std::string_view kSuffix = "-tls";

// Where a variant's figures stand next to its plain system's.
bool compared_by_tls_cost(const Metric& metric) {
  return metric.group == "small call" || metric.group == "upload";
}

}  // namespace

bool is_tls_variant(const std::string& system) { return system.ends_with(kSuffix); }

std::string plain_system(const std::string& variant) {
  return is_tls_variant(variant) ? variant.substr(0, variant.size() - kSuffix.size()) : variant;
}

std::vector<std::string> tls_workloads() { return {"small", "upload"}; }

RunCertificates::RunCertificates() {
  std::string dir = (fs::temp_directory_path() / "icars-compare-certs-XXXXXX").string();
  if (::mkdtemp(dir.data()) == nullptr) {
    throw std::runtime_error(fmt::format("cannot make a directory {} for the TLS certificates: {}",
                                         dir, std::generic_category().message(errno)));
  }
  files_.dir = dir;
  try {
    planet_test::make_certificates(files_.dir);
  } catch (const std::exception& e) {
    fs::remove_all(files_.dir);
    throw std::runtime_error(fmt::format(
        "the TLS variants need certificates: {} (scripts/make-certs.sh needs the openssl "
        "command; or leave the -tls systems out of --systems)",
        e.what()));
  }
}

RunCertificates::~RunCertificates() {
  std::error_code ignored;
  fs::remove_all(files_.dir, ignored);
}

void print_tls_cost(const Report& report, std::ostream& out) {
  const auto& systems = report.systems;
  std::vector<std::string> variants;
  for (const auto& s : systems) {
    if (is_tls_variant(s) &&
        std::find(systems.begin(), systems.end(), plain_system(s)) != systems.end()) {
      variants.push_back(s);
    }
  }
  if (variants.empty()) return;
  out << "\nWhat TLS costs (each TLS variant's median / its plain system's, same run):\n\n";
  std::size_t width = 8;
  for (const auto& m : metrics()) width = std::max(width, m.label.size());
  std::string head = fmt::format("{:{}} {:>13}", "workload", width, "unit");
  for (const auto& v : variants) head += " " + v + "/" + plain_system(v);
  out << head << "\n" << std::string(head.size(), '-') << "\n";
  for (const auto& m : metrics()) {
    if (!compared_by_tls_cost(m)) continue;
    std::string row = fmt::format("{:{}} {:>13}", m.label, width, m.unit);
    bool measured = false;
    for (const auto& v : variants) {
      const double ratio = report.median_of(v, m.key) / report.median_of(plain_system(v), m.key);
      measured = measured || std::isfinite(ratio);
      row += fmt::format(" {:>{}}", std::isfinite(ratio) ? fmt::format("{:.2f}", ratio) : "-",
                         v.size() + 1 + plain_system(v).size());  // under its heading
    }
    if (measured) out << row << "\n";
  }
  const double planet =
      report.median_of("planet-tls", "small_p50_us") / report.median_of("planet", "small_p50_us");
  if (std::isfinite(planet)) {
    out << fmt::format(
        "\nPLANET's small call p50 with TLS is {:.2f}x its plain one (target <= {}x: {})\n", planet,
        kPlanetTlsSmallCallTarget, planet <= kPlanetTlsSmallCallTarget ? "met" : "not met");
  }
}

}  // namespace icars::bench
