// planet-idl parser: reads an IDL file and the files it includes into a checked AST.
//
// A recursive-descent parser over the lexer's tokens. Names are resolved while parsing, so
// everything must be defined before it is used (like C++); an interface may name itself. The
// semantic rules (docs/idl.md, "Rules") are checked at the point where they are broken, so the
// CompileError points at the offending token: unknown or misused types, duplicate names,
// oneway operations with results or raises, raises naming non-exceptions, C++ keywords and
// reserved names as identifiers, enum values out of range or repeated, include cycles and
// nesting deeper than the PLANET serializer allows.
#pragma once

#include <cstddef>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ast.h"

namespace icars::planet::idl {

// Where the parser gets file contents from; tests supply files from memory.
class SourceReader {
 public:
  virtual ~SourceReader() = default;
  // The file's contents, or nullopt when there is no readable file at `path`.
  virtual std::optional<std::string> read(const std::filesystem::path& path) = 0;
  // A key that is equal for two paths naming the same file (used to detect include cycles).
  virtual std::string identity(const std::filesystem::path& path);
};

class FileSystemReader final : public SourceReader {
 public:
  std::optional<std::string> read(const std::filesystem::path& path) override;
  std::string identity(const std::filesystem::path& path) override;
};

struct ParseOptions {
  // Searched in order for `include "x.idl"` after the including file's own directory.
  std::vector<std::filesystem::path> import_dirs;
};

// Limits that keep hostile input from exhausting the stack; the type limit matches the
// serializer's kMaxTypeDepth.
inline constexpr std::size_t kMaxModuleDepth = 32;
inline constexpr std::size_t kMaxSequenceDepth = 32;
inline constexpr std::size_t kMaxIncludeDepth = 32;

// Every file read for one main file, includes before the files that include them.
struct Program {
  std::vector<std::unique_ptr<SourceFile>> files;
  const SourceFile* main = nullptr;
};

// Parses `path` and everything it includes. Throws CompileError at the first error, including
// when `path` itself cannot be read.
Program parse_program(const std::filesystem::path& path, const ParseOptions& options,
                      SourceReader& reader);

}  // namespace icars::planet::idl
