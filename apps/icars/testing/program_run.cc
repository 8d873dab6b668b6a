#include "program_run.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>

namespace icars_test {

std::string temp_path(const std::string& prefix, const std::string& name) {
  return fmt::format("{}{}_{}_{}", ::testing::TempDir(), prefix, ::getpid(), name);
}

ProgramRun run_program(const std::string& program, const std::string& args, int timeout_s) {
  static std::atomic<int> runs{0};
  const auto out = temp_path("program", fmt::format("{}.out", runs++));
  const auto command = fmt::format("timeout {} {} {} >{} 2>&1", timeout_s, program, args, out);
  const int status = std::system(command.c_str());
  ProgramRun r;
  // timeout(1) exits 124 when the time ran out: the program did not end by itself.
  r.exit_code = WIFEXITED(status) && WEXITSTATUS(status) != 124 ? WEXITSTATUS(status) : -1;
  std::ifstream o(out);
  r.output.assign(std::istreambuf_iterator<char>(o), {});
  std::remove(out.c_str());
  return r;
}

}  // namespace icars_test
