// Test support: the error a broken fixture (a house or a policy under testdata/bad) must give,
// read from its first line, <!-- expect LINE: MESSAGE -->.
#pragma once

#include <cstddef>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>

namespace icars_test {

struct FixtureExpectation {
  std::size_t line = 0;  // 0: the fixture has no expect line
  std::string message;
};

inline FixtureExpectation expectation_of(const std::filesystem::path& file) {
  std::ifstream in(file);
  std::string first;
  std::getline(in, first);
  static const std::regex pattern(R"(<!-- expect (\d+): (.*) -->)");
  std::smatch m;
  if (!std::regex_search(first, m, pattern)) return {};
  return {std::stoul(m[1].str()), m[2].str()};
}

}  // namespace icars_test
