// `icars run ... --trace FILE` run to its end and its JSON-lines trace read back: the end-to-end
// tests read a run as its user reads it (docs/trace.md).
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

#include "house_processes.h"  // read_json_lines, str
#include "program_run.h"

namespace icars_test {

struct TracedRun {
  ProgramRun run;
  std::vector<nlohmann::json> trace;  // every record, in the order written
};

// Runs `program args --trace <a temporary file>`, reads the trace and removes the file.
TracedRun run_traced(const std::string& program, const std::string& args, int timeout_s = 600);

std::string read_file(const std::string& path);  // "" when it cannot be read

}  // namespace icars_test
