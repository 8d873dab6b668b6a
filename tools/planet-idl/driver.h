// planet-idl driver: compiles IDL files to C++ files on disk, as the command line asks.
//
// Each input file is parsed with its includes and generated into `<output_dir>/<stem>.planet.h`
// and `.planet.cc`, and/or documented in one Markdown page of its events (events_doc.h). A
// file is rewritten only when its content changes, so builds that depend on the generated
// files do not redo work for an unchanged IDL file.
#pragma once

#include <filesystem>
#include <iosfwd>
#include <string>
#include <string_view>
#include <vector>

namespace icars::planet::idl {

struct DriverOptions {
  std::vector<std::filesystem::path> inputs;
  std::vector<std::filesystem::path> import_dirs;
  std::filesystem::path output_dir;  // empty: no C++
  std::filesystem::path depfile;  // empty: none; else a Makefile-style list of the files read
  std::filesystem::path events_doc;  // empty: none; else the Markdown page of the inputs' events
};

// Compiles every input; reports the first error of each failing input on `errors` (as
// `file:line:column: error: ...`) and returns the process exit code: 0, or 1 when any failed.
// The events page is written only when every input compiled, and names the inputs as given.
int run_driver(const DriverOptions& options, std::ostream& errors);

// Writes `content` to `path` unless it already holds exactly that. Returns whether it wrote;
// throws std::runtime_error naming the path when the file cannot be written.
bool write_if_changed(const std::filesystem::path& path, std::string_view content);

// A Makefile-style dependency rule "targets: dependencies" with spaces escaped.
std::string make_dependency_rule(const std::vector<std::string>& targets,
                                 const std::vector<std::string>& dependencies);

}  // namespace icars::planet::idl
