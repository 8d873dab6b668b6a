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

// --- The example policies of docs/policy.md -------------------------------------------------------

// examples/policies/<prefix>*.xml under the source tree `source`, sorted.
std::vector<std::string> example_policies(const std::string& source, const std::string& prefix);

// The first <element> of a policy's text, from its opening line to its closing tag.
std::string element_text(const std::string& text, const std::string& element);

// An example as docs/policy.md presents it: the page names the file and shows `shown` (the
// example's first <shown_element>) verbatim, and `icars validate` accepts it on `house` with
// no warning. Failures are reported with gtest's EXPECT.
void expect_documented_and_valid(const std::string& icars, const std::string& source, const std::string& example,
                                 const std::string& shown_element, const std::string& house);

// `icars run POLICY --world HOUSE --until UNTIL --speed max --quiet` with its trace; a non-zero
// exit fails the test. `output` gets what the run printed.
std::vector<nlohmann::json> run_policy(const std::string& icars, const std::string& policy, const std::string& house,
                                       const std::string& until, std::string& output);

}  // namespace icars_test
