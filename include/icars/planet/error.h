// PLANET errors: the few fixed kinds of failure that travel across the middleware.
//
// Every failure a PLANET user sees is an `icars::planet::Error` carrying one of a small fixed
// set of kinds (in the spirit of Cap'n Proto's failed/overloaded/disconnected/unimplemented)
// and a message that names the input and what went wrong. Remote exceptions thrown by a
// servant arrive at the caller as `RemoteException`, a subclass that also carries the
// exception's type id and properties.
#pragma once

#include <cstdint>
#include <exception>
#include <stdexcept>
#include <string>
#include <string_view>

namespace icars::planet {

enum class ErrorKind : std::uint8_t {
  failed = 1,         // The operation failed; the servant raised an exception.
  overloaded = 2,     // A bounded queue is full; retry later (flow control said no).
  disconnected = 3,   // The link to the peer is down or went down while waiting.
  unimplemented = 4,  // No servant at that path, or the servant has no such method.
  timeout = 5,        // No reply within the call's deadline.
  bad_data = 6,       // A message could not be decoded (wrong types, truncated, garbage).
  refused = 7,        // The server denied the connection (CONNECT_ACK 0xFF + reason).
  denied = 8,         // The peer may not call that servant path (its access policy).
};

std::string_view to_string(ErrorKind kind) noexcept;

class Error : public std::runtime_error {
 public:
  Error(ErrorKind kind, const std::string& message);
  ErrorKind kind() const noexcept { return kind_; }
  const std::string& message() const noexcept { return message_; }  // without the kind prefix

 private:
  ErrorKind kind_;
  std::string message_;
};

// What went wrong, for a log line or an error message: an exception's what(), "unknown error"
// for anything else thrown, "" for a null pointer.
std::string describe(const std::exception_ptr& error);

}  // namespace icars::planet
