// Command-line options for PLANET security shared by the ICARS programs (docs/security.md):
// TLS files and mode, the access file of a server, and the token file of a client.
#pragma once

#include <CLI/CLI.hpp>

#include <csignal>

#include <string>
#include <vector>

#include "icars/planet/security.h"

namespace icars::app {

enum class Side { server, client };

// --tls auto|on|off, --tls-ca, --tls-cert, --tls-key; a server also gets
// --require-client-cert, a client --tls-server-name.
void add_tls_options(CLI::App& app, planet::TlsOptions& tls, Side side);

// A device manager's options for its link to the mediating server: --tls* (client side) and
// --token-file.
struct DeviceManagerSecurity {
  planet::TlsOptions tls;
  std::string token_file;
};
void add_device_manager_options(CLI::App& app, DeviceManagerSecurity& security);

// Blocks SIGINT and SIGTERM in the calling thread and the threads it starts afterwards, so that
// the program takes them with sigwait/sigtimedwait on the returned set. Call before any thread
// starts.
sigset_t block_stop_signals();

// The token in `file` (its first line, surrounding whitespace removed). Throws
// std::runtime_error naming the file when it is unreadable, empty or longer than 256 bytes.
std::string read_token_file(const std::string& file);

// The servant paths a device manager calls on the mediating server: the device registry, and the
// listeners through which its devices deliver events.
std::vector<std::string> device_manager_paths();

// `principal` as one line of an access file's "principals" array (JSON).
std::string access_entry(const planet::Principal& principal);

}  // namespace icars::app
