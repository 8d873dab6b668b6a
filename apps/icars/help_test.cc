// `icars run --help` as a user reads it: every option with its default, the TLS modes by name,
// and nothing unprintable.
#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <string>

#include "program_run.h"

namespace {

TEST(IcarsHelp, RunListsEveryOptionWithItsDefault) {
  const auto r = icars_test::run_program(ICARS_BINARY, "run --help", 60);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  for (const char* shown : {"--world TEXT REQUIRED", "=1500", "--until TEXT=07:30", "=1\n", "--listen TEXT=127.0.0.1:0",
                            "--policies TEXT=examples/smart_home", "--tls {auto,on,off}=auto", "--access", "--plugin"}) {
    EXPECT_NE(r.output.find(shown), std::string::npos) << "missing \"" << shown << "\" in\n" << r.output;
  }
  EXPECT_TRUE(std::all_of(r.output.begin(), r.output.end(), [](char c) {
    return c == '\n' || std::isprint(static_cast<unsigned char>(c)) != 0;
  })) << "unprintable characters in\n" << r.output;
  const auto validate = icars_test::run_program(ICARS_BINARY, "validate --help", 60);
  EXPECT_NE(validate.output.find("--world"), std::string::npos) << validate.output;
}

}  // namespace
