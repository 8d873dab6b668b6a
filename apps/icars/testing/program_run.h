// One command of a program (`icars validate ...`, `icars run ... --until 19:00`) run to its end,
// as a user would from a shell: the tests of the command line and of plugins.
#pragma once

#include <string>

namespace icars_test {

struct ProgramRun {
  int exit_code = -1;  // -1 when it did not exit (killed, or past its time)
  std::string output;  // its stdout and stderr, interleaved as written
};

// Runs `program args` (args as a shell would split them) for at most `timeout_s` seconds.
ProgramRun run_program(const std::string& program, const std::string& args, int timeout_s = 600);

// A path for a temporary file of this test process: <test temp dir>/<prefix>_<pid>_<name>.
std::string temp_path(const std::string& prefix, const std::string& name);

}  // namespace icars_test
