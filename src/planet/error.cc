#include "icars/planet/error.h"

#include "icars/planet/event.h"

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
  } catch (const RemoteException& e) {
    // A typed exception says what it means in its fields (RegistrationRefused's reason).
    std::string text = e.what();
    if (!e.remote_message().empty() || e.properties().size() == 0) return text;
    const char* separator = " ";
    for (const auto& [name, value] : e.properties().items()) {
      std::string shown;
      if (value.is<std::string>()) {
        shown = value.as<std::string>();
      } else if (value.is<std::int32_t>()) {
        shown = std::to_string(value.as<std::int32_t>());
      } else if (value.is<std::int64_t>()) {
        shown = std::to_string(value.as<std::int64_t>());
      } else if (value.is<bool>()) {
        shown = value.as<bool>() ? "true" : "false";
      } else {
        continue;
      }
      text += separator + name + "=" + shown;
      separator = ", ";
    }
    return text;
  } catch (const std::exception& e) {
    return e.what();
  } catch (...) {
    return "unknown error";
  }
}

}  // namespace icars::planet
