#include "icars/planet/security.h"

#include <spdlog/spdlog.h>

#include <fmt/format.h>
#include <openssl/evp.h>
#include <openssl/rand.h>

#include <algorithm>
#include <asio/ip/address.hpp>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>

#include "icars/planet/connection_manager.h"

namespace icars::planet {

namespace {

void check_readable(const std::string& file, const char* what) {
  if (file.empty()) return;
  std::ifstream in(file);
  if (!in) throw std::invalid_argument(fmt::format("tls.{}: cannot read '{}'", what, file));
}

bool is_hex_digest(std::string_view s) {
  return s.size() == 64 && std::all_of(s.begin(), s.end(), [](char c) {
           return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
         });
}

void check_pattern(std::string_view pattern, const std::string& principal) {
  const bool ok = pattern == "*" ||
                  (pattern.starts_with('/') && pattern.find('*') == std::string_view::npos) ||
                  (pattern.starts_with('/') && pattern.ends_with("/*") &&
                   pattern.find('*') == pattern.size() - 1);
  if (!ok) {
    throw std::invalid_argument(fmt::format(
        "principal '{}': path pattern '{}' must be \"*\", a path starting with '/', or such a "
        "path ending in \"/*\"",
        principal, pattern));
  }
}

void check_device_pattern(std::string_view pattern, const std::string& principal) {
  const auto star = pattern.find('*');
  if (pattern.empty() || (star != std::string_view::npos && star != pattern.size() - 1)) {
    throw std::invalid_argument(fmt::format(
        "principal '{}': device pattern '{}' must be \"*\", a device id, or an id prefix ending "
        "in '*'",
        principal, pattern));
  }
}

}  // namespace

void TlsOptions::validate() const {
  check_readable(ca_file, "ca_file");
  check_readable(certificate_file, "certificate_file");
  check_readable(private_key_file, "private_key_file");
  if (certificate_file.empty() != private_key_file.empty()) {
    throw std::invalid_argument("tls.certificate_file and tls.private_key_file go together");
  }
  if (require_client_certificate && ca_file.empty()) {
    throw std::invalid_argument(
        "tls.require_client_certificate needs tls.ca_file: the CA that signs client certificates");
  }
}

bool matches_path_pattern(std::string_view pattern, std::string_view path) {
  if (pattern == "*") return true;
  if (pattern.ends_with("/*")) {
    const std::string_view prefix = pattern.substr(0, pattern.size() - 1);  // keeps the '/'
    return path.size() > prefix.size() && path.starts_with(prefix);
  }
  return pattern == path;
}

bool Principal::may_call_path(std::string_view path) const {
  return std::any_of(may_call.begin(), may_call.end(),
                     [&](const std::string& p) { return matches_path_pattern(p, path); });
}

bool matches_device_pattern(std::string_view pattern, std::string_view device_id) {
  if (pattern.ends_with('*')) return device_id.starts_with(pattern.substr(0, pattern.size() - 1));
  return pattern == device_id;
}

bool Principal::may_register(std::string_view device_id) const {
  return std::any_of(devices.begin(), devices.end(),
                     [&](const std::string& p) { return matches_device_pattern(p, device_id); });
}

std::vector<std::string> reload_access_policy(ConnectionManager& manager, const AccessPolicy& previous,
                                              std::shared_ptr<const AccessPolicy> next) {
  std::vector<std::string> changed;
  for (const auto& p : previous.principals()) {
    const Principal* now = next ? next->find(p.name) : nullptr;
    if (!now || !(*now == p)) changed.push_back(p.name);
  }
  manager.set_access_policy(std::move(next));
  for (const auto& c : manager.connections()) {
    const auto principal = c->principal();
    if (principal && std::find(changed.begin(), changed.end(), principal->name) != changed.end()) {
      manager.log().warn("closing {}: access of principal '{}' revoked or changed", c->describe(),
                         principal->name);
      c->close(fmt::format("access of principal '{}' revoked or changed", principal->name));
    }
  }
  return changed;
}

const Principal* AccessPolicy::find(std::string_view name) const {
  for (const auto& p : principals_) {
    if (p.name == name) return &p;
  }
  return nullptr;
}

void AccessPolicy::add(Principal principal) {
  if (principal.name.empty()) throw std::invalid_argument("a principal needs a name");
  for (const auto& p : principals_) {
    if (p.name == principal.name) {
      throw std::invalid_argument(fmt::format("principal '{}' is defined twice", principal.name));
    }
  }
  if (principal.token_sha256.empty() && principal.certificate_name.empty()) {
    throw std::invalid_argument(fmt::format(
        "principal '{}' needs a token_sha256 or a certificate name to be recognised by",
        principal.name));
  }
  if (!principal.token_sha256.empty() && !is_hex_digest(principal.token_sha256)) {
    throw std::invalid_argument(fmt::format(
        "principal '{}': token_sha256 must be 64 lower-case hex digits (`icars token` prints it)",
        principal.name));
  }
  for (const auto& p : principal.may_call) check_pattern(p, principal.name);
  for (const auto& d : principal.devices) check_device_pattern(d, principal.name);
  if (principal.max_devices == 0 && !principal.devices.empty()) {
    throw std::invalid_argument(fmt::format(
        "principal '{}': max_devices is 0 but it lists devices it may register", principal.name));
  }
  principals_.push_back(std::move(principal));
}

AccessPolicy AccessPolicy::load(const std::string& file) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error(fmt::format("{}: cannot read the access file", file));
  std::stringstream text;
  text << in.rdbuf();
  return parse(text.str(), file);
}

AccessPolicy AccessPolicy::parse(std::string_view text, const std::string& file_name) {
  using nlohmann::json;
  AccessPolicy policy;
  try {
    const json doc = json::parse(text.begin(), text.end());
    if (!doc.is_object() || !doc.contains("principals") || !doc["principals"].is_array()) {
      throw std::invalid_argument("expected an object with a \"principals\" array");
    }
    for (const auto& entry : doc["principals"]) {
      if (!entry.is_object()) throw std::invalid_argument("each principal must be an object");
      for (const auto& [key, value] : entry.items()) {
        if (key != "name" && key != "token_sha256" && key != "certificate" && key != "may_call" &&
            key != "devices" && key != "max_devices") {
          throw std::invalid_argument(fmt::format(
              "unknown key \"{}\" in a principal (expected name, token_sha256, certificate, "
              "may_call, devices, max_devices)",
              key));
        }
      }
      Principal p;
      p.name = entry.value("name", "");
      p.token_sha256 = entry.value("token_sha256", "");
      p.certificate_name = entry.value("certificate", "");
      if (entry.contains("may_call")) {
        p.may_call = entry["may_call"].get<std::vector<std::string>>();
      }
      if (entry.contains("devices")) p.devices = entry["devices"].get<std::vector<std::string>>();
      if (entry.contains("max_devices")) {
        const auto& max = entry["max_devices"];
        if (!max.is_number_unsigned()) {
          throw std::invalid_argument(fmt::format(
              "principal '{}': max_devices must be a non-negative integer", p.name));
        }
        p.max_devices = max.get<std::size_t>();
      }
      policy.add(std::move(p));
    }
  } catch (const json::exception& e) {
    throw std::runtime_error(fmt::format("{}: {}", file_name, e.what()));
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(fmt::format("{}: {}", file_name, e.what()));
  }
  return policy;
}

const Principal* AccessPolicy::authenticate(std::string_view token,
                                            std::string_view certificate_name) const {
  if (!certificate_name.empty()) {
    for (const auto& p : principals_) {
      if (p.certificate_name == certificate_name) return &p;
    }
  }
  if (!token.empty()) {
    const std::string digest = sha256_hex(token);
    for (const auto& p : principals_) {
      if (!p.token_sha256.empty() && p.token_sha256 == digest) return &p;
    }
  }
  return nullptr;
}

std::string sha256_hex(std::string_view text) {
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int length = 0;
  if (EVP_Digest(text.data(), text.size(), digest, &length, EVP_sha256(), nullptr) != 1) {
    throw std::runtime_error("SHA-256 failed (OpenSSL EVP_Digest)");
  }
  std::string hex;
  hex.reserve(2 * length);
  for (unsigned int i = 0; i < length; ++i) hex += fmt::format("{:02x}", digest[i]);
  return hex;
}

std::string random_token(std::size_t bytes) {
  std::vector<unsigned char> raw(bytes);
  if (RAND_bytes(raw.data(), static_cast<int>(raw.size())) != 1) {
    throw std::runtime_error("the random generator failed (OpenSSL RAND_bytes)");
  }
  std::string hex;
  hex.reserve(2 * bytes);
  for (unsigned char c : raw) hex += fmt::format("{:02x}", c);
  return hex;
}

bool is_loopback_host(std::string_view host) {
  if (host == "localhost") return true;
  std::error_code ec;
  const auto address = asio::ip::make_address(std::string(host), ec);
  if (ec) return false;
  if (address.is_v6() && address.to_v6().is_v4_mapped()) {
    return asio::ip::make_address_v4(asio::ip::v4_mapped, address.to_v6()).is_loopback();
  }
  return address.is_loopback();
}

}  // namespace icars::planet
