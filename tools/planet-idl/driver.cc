#include "driver.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <fstream>
#include <ostream>
#include <sstream>
#include <stdexcept>
#include <system_error>

#include "cpp_generator.h"
#include "diagnostic.h"
#include "events_doc.h"
#include "parser.h"

namespace icars::planet::idl {

namespace {

namespace fs = std::filesystem;

std::string escape_for_make(const std::string& path) {
  std::string out;
  for (const char c : path) {
    if (c == ' ' || c == '#') out += '\\';
    if (c == '$') out += '$';
    out += c;
  }
  return out;
}

// Compiles one input; adds the files it wrote (or left unchanged) and read to the lists.
Program compile_one(const fs::path& input, const DriverOptions& options,
                    std::vector<std::string>& outputs, std::vector<std::string>& inputs_read) {
  FileSystemReader reader;
  Program program = parse_program(input, ParseOptions{options.import_dirs}, reader);
  for (const auto& file : program.files) inputs_read.push_back(file->path);
  if (options.output_dir.empty()) return program;
  const GeneratedCpp cpp = generate_cpp(*program.main);
  const fs::path header = options.output_dir / cpp.header_name;
  const fs::path source = options.output_dir / cpp.source_name;
  write_if_changed(header, cpp.header);
  write_if_changed(source, cpp.source);
  outputs.push_back(header.string());
  outputs.push_back(source.string());
  return program;
}

void write_events_doc(const DriverOptions& options, const std::vector<Program>& programs,
                      std::vector<std::string>& outputs) {
  std::vector<const SourceFile*> mains;
  for (const Program& p : programs) mains.push_back(p.main);
  write_if_changed(options.events_doc, generate_events_doc(mains));
  outputs.push_back(options.events_doc.string());
}

void write_depfile(const DriverOptions& options, const std::vector<std::string>& outputs,
                   std::vector<std::string> inputs_read) {
  std::sort(inputs_read.begin(), inputs_read.end());
  inputs_read.erase(std::unique(inputs_read.begin(), inputs_read.end()), inputs_read.end());
  write_if_changed(options.depfile, make_dependency_rule(outputs, inputs_read));
}

}  // namespace

bool write_if_changed(const fs::path& path, std::string_view content) {
  {
    std::ifstream in(path, std::ios::binary);
    if (in) {
      std::ostringstream existing;
      existing << in.rdbuf();
      if (existing.str() == content) return false;
    }
  }
  std::error_code ec;
  if (path.has_parent_path()) fs::create_directories(path.parent_path(), ec);
  // Unique per process, so two compilers writing the same output cannot mix their bytes.
  const fs::path temporary = fmt::format("{}.{}.tmp", path.string(), ::getpid());
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out.write(content.data(), static_cast<std::streamsize>(content.size()));
    if (!out) throw std::runtime_error(fmt::format("cannot write '{}'", temporary.string()));
  }
  fs::rename(temporary, path, ec);  // atomic: a concurrent reader sees old or new, never half
  if (ec)
    throw std::runtime_error(fmt::format("cannot write '{}': {}", path.string(), ec.message()));
  return true;
}

std::string make_dependency_rule(const std::vector<std::string>& targets,
                                 const std::vector<std::string>& dependencies) {
  std::string out;
  for (const std::string& t : targets) {
    if (!out.empty()) out += ' ';
    out += escape_for_make(t);
  }
  out += ":";
  for (const std::string& d : dependencies) {
    out += " \\\n  ";
    out += escape_for_make(d);
  }
  return out + "\n";
}

int run_driver(const DriverOptions& options, std::ostream& errors) {
  std::vector<std::string> outputs;
  std::vector<std::string> inputs_read;
  std::vector<Program> programs;
  int status = 0;
  for (const fs::path& input : options.inputs) {
    try {
      programs.push_back(compile_one(input, options, outputs, inputs_read));
    } catch (const CompileError& e) {
      errors << e.what() << '\n';
      status = 1;
    } catch (const std::exception& e) {
      errors << fmt::format("{}: error: {}, expected a writable output directory\n", input.string(),
                            e.what());
      status = 1;
    }
  }
  if (status == 0 && !options.events_doc.empty()) {
    try {
      write_events_doc(options, programs, outputs);
    } catch (const std::exception& e) {
      errors << fmt::format("planet-idl: error: {}\n", e.what());
      status = 1;
    }
  }
  if (status == 0 && !options.depfile.empty()) {
    try {
      write_depfile(options, outputs, inputs_read);
    } catch (const std::exception& e) {
      errors << fmt::format("planet-idl: error: {}\n", e.what());
      status = 1;
    }
  }
  return status;
}

}  // namespace icars::planet::idl
