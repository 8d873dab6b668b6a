#include "icars/planet/error.h"

namespace icars::planet {

std::string_view to_string(ErrorKind kind) noexcept {
  switch (kind) {
    case ErrorKind::failed:
      return "failed";
    case ErrorKind::overloaded:
      return "overloaded";
    case ErrorKind::disconnected:
      return "disconnected";
    case ErrorKind::unimplemented:
      return "unimplemented";
    case ErrorKind::timeout:
      return "timeout";
    case ErrorKind::bad_data:
      return "bad_data";
    case ErrorKind::refused:
      return "refused";
    case ErrorKind::denied:
      return "denied";
  }
  return "unknown";
}

Error::Error(ErrorKind kind, const std::string& message)
    : std::runtime_error(std::string(to_string(kind)) + ": " + message), kind_(kind), message_(message) {}

std::string describe(const std::exception_ptr& error) {
  if (!error) return {};
  try {
    std::rethrow_exception(error);
  } catch (const std::exception& e) {
    return e.what();
  } catch (...) {
    return "unknown error";
  }
}

}  // namespace icars::planet
