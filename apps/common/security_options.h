// Command-line options for PLANET security shared by the ICARS programs (docs/security.md):
// TLS files and mode, the access file of a server, and the token file of a client.
#pragma once

#include <CLI/CLI.hpp>

#include <string>
#include <vector>

#include "icars/planet/security.h"

namespace icars::app {

enum class Side { server, client };

// --tls auto|on|off, --tls-ca, --tls-cert, --tls-key; a server also gets
// --require-client-cert, a client --tls-server-name.
void add_tls_options(CLI::App& app, planet::TlsOptions& tls, Side side);

// The token in `file` (its first line, surrounding whitespace removed). Throws
// std::runtime_error naming the file when it is unreadable, empty or longer than 256 bytes.
std::string read_token_file(const std::string& file);

// The servant paths a device manager calls on the mediating server: the device registry, and the
// listeners through which its devices deliver events.
std::vector<std::string> device_manager_paths();

// `principal` as one line of an access file's "principals" array (JSON).
std::string access_entry(const planet::Principal& principal);

}  // namespace icars::app
