// Every file in testdata/bad/ runs through the real planet-idl executable, which must exit with
// code 1 and print the error the file announces in its first line:
//   // expect: <file>:<line>:<column>: error: <message substring>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace {

namespace fs = std::filesystem;

const fs::path kBadDir = PLANET_IDL_BAD_DIR;
constexpr std::string_view kExpectPrefix = "// expect: ";

std::vector<std::string> bad_files() {
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(kBadDir)) {
    if (entry.path().extension() == ".idl") names.push_back(entry.path().filename().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

std::string read(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

struct Outcome {
  int exit_code = -1;
  std::string errors;
};

// Runs planet-idl in the fixtures' directory, so messages name files as they are written there.
Outcome compile(const std::string& name) {
  const fs::path out =
      fs::temp_directory_path() / ("planet_idl_bad_" + fs::path(name).stem().string());
  fs::create_directories(out);
  const fs::path errors = out / "stderr.txt";
  const std::string command = "cd '" + kBadDir.string() +
                              "' && '" PLANET_IDL_EXECUTABLE "' --output-dir '" + out.string() +
                              "' '" + name + "' 2> '" + errors.string() + "'";
  const int status = std::system(command.c_str());
  Outcome run;
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  run.errors = read(errors);
  fs::remove_all(out);
  return run;
}

class BadInput : public ::testing::TestWithParam<std::string> {};

TEST_P(BadInput, FailsWithTheAnnouncedError) {
  const std::string text = read(kBadDir / GetParam());
  ASSERT_EQ(text.rfind(kExpectPrefix, 0), 0u)
      << GetParam() << " must start with '" << kExpectPrefix << "'";
  const std::string expected =
      text.substr(kExpectPrefix.size(), text.find('\n') - kExpectPrefix.size());
  const Outcome run = compile(GetParam());
  EXPECT_EQ(run.exit_code, 1) << run.errors;
  EXPECT_NE(run.errors.find(expected), std::string::npos)
      << "expected: " << expected << "\nactual:   " << run.errors;
  EXPECT_EQ(std::count(run.errors.begin(), run.errors.end(), '\n'), 1) << run.errors;
}

INSTANTIATE_TEST_SUITE_P(Fixtures, BadInput, ::testing::ValuesIn(bad_files()),
                         [](const ::testing::TestParamInfo<std::string>& param) {
                           std::string name = fs::path(param.param).stem().string();
                           std::replace_if(
                               name.begin(), name.end(),
                               [](char c) { return !std::isalnum(static_cast<unsigned char>(c)); },
                               '_');
                           return name;
                         });

TEST(BadInput, SuiteCoversEveryRequiredCase) { EXPECT_GE(bad_files().size(), 17u); }

}  // namespace
