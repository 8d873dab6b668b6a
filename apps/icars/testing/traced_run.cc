#include "traced_run.h"

#include <cstdio>
#include <fstream>
#include <iterator>

namespace icars_test {

TracedRun run_traced(const std::string& program, const std::string& args, int timeout_s) {
  const auto path = temp_path("traced_run", "trace.jsonl");
  TracedRun r;
  r.run = run_program(program, args + " --trace " + path, timeout_s);
  r.trace = read_json_lines(path);
  std::remove(path.c_str());
  return r;
}

std::string read_file(const std::string& path) {
  std::ifstream in(path);
  return {std::istreambuf_iterator<char>(in), {}};
}

}  // namespace icars_test
