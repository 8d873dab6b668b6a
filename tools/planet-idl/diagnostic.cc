#include "diagnostic.h"

#include <fmt/format.h>

namespace icars::planet::idl {

std::string SourceLocation::to_string() const {
  if (line == 0) return std::string(file);  // the file as a whole
  return fmt::format("{}:{}:{}", file, line, column);
}

CompileError::CompileError(const SourceLocation& where, const std::string& problem,
                           const std::string& expected)
    : std::runtime_error(
          fmt::format("{}: error: {}, expected {}", where.to_string(), problem, expected)),
      file_(where.file),
      line_(where.line),
      column_(where.column),
      problem_(problem),
      expected_(expected) {}

std::string quote(std::string_view text) {
  std::string out = "'";
  for (const char c : text) {
    const auto byte = static_cast<unsigned char>(c);
    if (byte < 0x20 || byte >= 0x7F) {
      out += fmt::format("\\x{:02x}", byte);
    } else {
      out += c;
    }
  }
  return out + "'";
}

}  // namespace icars::planet::idl
