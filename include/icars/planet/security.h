// PLANET security: TLS on connections, authentication of peers in CONNECT, and authorization of
// the servant paths each authenticated peer may call.
//
// A mediating server in a home decides who may connect (a token per device manager or agent, or
// a TLS client certificate signed by the home's CA) and what each one may call (a device manager
// may register its devices and deliver events; only an operator may call the rest). Links to and
// listeners on non-loopback addresses use TLS by default, with the peer's certificate verified
// against the configured CA. docs/security.md has the threat model and the configuration.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace icars::planet {

enum class TlsMode : std::uint8_t {
  // TLS on links to non-loopback hosts, and on a listener for clients from non-loopback
  // addresses; plaintext on loopback (a listener on a non-loopback address needs a certificate)
  automatic,
  on,         // TLS on every link, loopback included
  off,        // plaintext everywhere: only for a network where every host is trusted
};

struct TlsOptions {
  TlsMode mode = TlsMode::automatic;
  std::string ca_file;           // PEM: the CA certificates that peers' certificates must chain to
  std::string certificate_file;  // PEM: this endpoint's certificate chain (a TLS listener needs one)
  std::string private_key_file;  // PEM: its private key
  // Server: clients must present a certificate signed by `ca_file` (mutual TLS); its common name
  // then names the client (AccessPolicy, Principal::certificate_name).
  bool require_client_certificate = false;
  // Client: the name the server's certificate must carry (subject alternative name or common
  // name); empty: the host given to connect().
  std::string server_name;

  // Throws std::invalid_argument naming the missing or unreadable file.
  void validate() const;
};

// An authenticated peer: who it is and which servant paths it may call.
struct Principal {
  std::string name;
  std::string token_sha256;      // lower-case hex SHA-256 of the token it sends in CONNECT
  std::string certificate_name;  // the common name of its TLS client certificate
  // Path patterns: an exact path ("/sf/registry"), a prefix ending in "/*" ("/devices/*"
  // matches "/devices/tv/remote" and anything deeper), or "*" (every path).
  std::vector<std::string> may_call;
  // Device id patterns this principal may register with a device registry: an exact id ("tv"),
  // a prefix ending in '*' ("robot1_*"), or "*". Empty: none (an operator or an agent).
  std::vector<std::string> devices{};
  // Devices it may hold registered at once; a registration beyond it is refused.
  std::size_t max_devices = 64;

  bool may_call_path(std::string_view path) const;
  bool may_register(std::string_view device_id) const;
  // The same credentials and permissions (a reloaded access file keeps such a principal's links).
  bool operator==(const Principal&) const = default;
};

// The server's list of principals. Without an AccessPolicy a Communicator admits every client
// and lets it call every servant (fit for loopback and tests only). With one, a client is
// admitted only when its token or its verified certificate names a principal, and each request
// is checked against that principal's `may_call` patterns. Immutable once shared; thread-safe.
class AccessPolicy {
 public:
  // Throws std::invalid_argument: an empty or duplicate name, neither token nor certificate, a
  // malformed token hash, or a malformed path pattern.
  void add(Principal principal);
  const std::vector<Principal>& principals() const { return principals_; }

  // The principal named `name`, or null.
  const Principal* find(std::string_view name) const;

  // Reads an access file (JSON, docs/security.md). Throws std::runtime_error "<file>: <what>".
  static AccessPolicy load(const std::string& file);
  static AccessPolicy parse(std::string_view text, const std::string& file_name);

  // The principal a CONNECT's token or a verified client certificate's name identifies; null
  // when neither matches (the caller denies the connection).
  const Principal* authenticate(std::string_view token, std::string_view certificate_name) const;

 private:
  std::vector<Principal> principals_;
};

class ConnectionManager;
// Puts `next` in force for `manager`'s listeners (an access file reloaded on SIGHUP): the live
// links of principals that `previous` had and `next` removes or changes are closed ("access
// revoked"), so a removed principal is out at once and a changed one reconnects under its new
// entry; links of unchanged principals stay up. Returns the names of the principals removed or
// changed. Thread-safe.
std::vector<std::string> reload_access_policy(ConnectionManager& manager, const AccessPolicy& previous,
                                              std::shared_ptr<const AccessPolicy> next);

bool matches_path_pattern(std::string_view pattern, std::string_view path);
// Device id patterns: "*", "prefix*" or an exact id.
bool matches_device_pattern(std::string_view pattern, std::string_view device_id);
// Lower-case hex SHA-256 of `text`: what an access file stores instead of a token.
std::string sha256_hex(std::string_view text);
// A random token of `bytes` random bytes, hex-encoded (for `icars token`).
std::string random_token(std::size_t bytes = 32);
// True for 127.0.0.0/8, ::1, "localhost" and IPv4-mapped loopback; false for anything else,
// including 0.0.0.0 and :: (every interface).
bool is_loopback_host(std::string_view host);

}  // namespace icars::planet
