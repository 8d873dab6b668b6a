// planet-idl diagnostics: where in an IDL file something is, and the one error the compiler
// reports.
//
// Every failure the compiler detects (lexical, syntactic, semantic or a missing file) is a
// CompileError that prints as `file:line:column: error: <what was wrong>, expected <what was
// expected>`. The compiler stops at the first error.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <string_view>

namespace icars::planet::idl {

// A position in a source file; `file` points into storage that outlives every AST node.
struct SourceLocation {
  std::string_view file;
  std::uint32_t line = 1;    // 1-based
  std::uint32_t column = 1;  // 1-based, in bytes

  std::string to_string() const;  // "file:line:column", or "file" when line is 0
};

class CompileError : public std::runtime_error {
 public:
  CompileError(const SourceLocation& where, const std::string& problem,
               const std::string& expected);

  const std::string& file() const { return file_; }
  std::uint32_t line() const { return line_; }
  std::uint32_t column() const { return column_; }
  const std::string& problem() const { return problem_; }
  const std::string& expected() const { return expected_; }

 private:
  std::string file_;
  std::uint32_t line_;
  std::uint32_t column_;
  std::string problem_;
  std::string expected_;
};

// Quotes a piece of source text for a message: 'name', with unprintable bytes as \xNN.
std::string quote(std::string_view text);

}  // namespace icars::planet::idl
