// Fuzz target: the planet-idl front end (lexer, parser, semantic checks) and the C++ generator.
//
// The input is an IDL file, "main.idl". It may carry more files for `include`: a line
// `//@file NAME` starts the file NAME (served from memory; "imports/" is an import directory),
// so include chains, cycles and definitions across files are reached too. A program that
// parses is generated to C++ as planet-idl would. The one expected failure is CompileError,
// which is what the tool prints as `file:line:column: error: ...`; anything else escapes to
// the fuzzer.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <string_view>

#include "cpp_generator.h"
#include "fuzz_util.h"
#include "diagnostic.h"
#include "parser.h"

namespace {

namespace fs = std::filesystem;
using namespace icars::planet::idl;

class MemoryReader final : public SourceReader {
 public:
  explicit MemoryReader(std::map<std::string, std::string> files) : files_(std::move(files)) {}
  std::optional<std::string> read(const fs::path& path) override {
    const auto it = files_.find(path.lexically_normal().string());
    if (it == files_.end()) return std::nullopt;
    return it->second;
  }

 private:
  std::map<std::string, std::string> files_;
};

// Splits the input at lines "//@file NAME"; the text before the first such line is main.idl.
std::map<std::string, std::string> split_files(std::string_view input) {
  static constexpr std::string_view kMarker = "//@file ";
  std::map<std::string, std::string> files;
  std::string name = "main.idl";
  std::size_t start = 0;  // of the current file's text
  std::size_t pos = 0;    // of the current line
  while (true) {
    const std::size_t eol = input.find('\n', pos);
    const std::size_t line_end = eol == std::string_view::npos ? input.size() : eol;
    const std::string_view line = input.substr(pos, line_end - pos);
    if (line.starts_with(kMarker)) {
      files.emplace(name, std::string(input.substr(start, pos - start)));
      name = fs::path(std::string(line.substr(kMarker.size()))).lexically_normal().string();
      start = eol == std::string_view::npos ? input.size() : eol + 1;
    }
    if (eol == std::string_view::npos) break;
    pos = eol + 1;
  }
  files.emplace(name, std::string(input.substr(start)));
  return files;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  MemoryReader reader(split_files(input));
  ParseOptions options;
  options.import_dirs = {"imports"};
  try {
    const Program program = parse_program("main.idl", options, reader);
    for (const auto& file : program.files) {
      const GeneratedCpp out = generate_cpp(*file);
      if (out.header.empty() || out.source.empty()) {
        std::fprintf(stderr, "idl_parser_fuzz: empty generated code for %s\n", file->path.c_str());
        std::abort();
      }
    }
  } catch (const CompileError& e) {
    icars_fuzz::note_rejected("idl_parser_fuzz", e.what());
    if (e.problem().empty()) {
      std::fprintf(stderr, "idl_parser_fuzz: error without a message: %s\n", e.what());
      std::abort();
    }
  }
  return 0;
}
