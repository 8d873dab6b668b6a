// The driver: files written next to each other in the output directory, rewritten only when
// their content changes, a dependency file naming every IDL file read, and errors reported as
// `file:line:column: error:` with exit code 1.
#include "driver.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <fstream>
#include <sstream>
#include <thread>

namespace icars::planet::idl {
namespace {

namespace fs = std::filesystem;

class Driver : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           fmt::format("planet_idl_driver_test_{}_{}", ::getpid(),
                       ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "in");
  }
  void TearDown() override { fs::remove_all(dir_); }

  void write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / "in" / name, std::ios::binary) << text;
  }
  std::string read(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    std::ostringstream text;
    text << in.rdbuf();
    return text.str();
  }
  DriverOptions options(std::vector<std::string> inputs) {
    DriverOptions o;
    for (const auto& i : inputs) o.inputs.push_back(dir_ / "in" / i);
    o.output_dir = dir_ / "out";
    return o;
  }

  fs::path dir_;
};

TEST_F(Driver, WritesAHeaderAndASourcePerInput) {
  write("a.idl", "module a { valued P { int x; }; }");
  write("b.idl", "include \"a.idl\";\nmodule b { valued Q { a::P p; }; }");
  std::ostringstream errors;
  EXPECT_EQ(run_driver(options({"a.idl", "b.idl"}), errors), 0);
  EXPECT_EQ(errors.str(), "");
  EXPECT_TRUE(fs::exists(dir_ / "out" / "a.planet.h"));
  EXPECT_TRUE(fs::exists(dir_ / "out" / "a.planet.cc"));
  EXPECT_NE(read(dir_ / "out" / "b.planet.h").find("#include \"a.planet.h\""), std::string::npos);
}

TEST_F(Driver, RewritesOnlyFilesWhoseContentChanged) {
  write("a.idl", "module a { valued P { int x; }; }");
  std::ostringstream errors;
  ASSERT_EQ(run_driver(options({"a.idl"}), errors), 0);
  const fs::path header = dir_ / "out" / "a.planet.h";
  const auto first = fs::last_write_time(header);
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  write("a.idl", "// only a comment changed\nmodule a { valued P { int x; }; }");
  ASSERT_EQ(run_driver(options({"a.idl"}), errors), 0);
  EXPECT_EQ(fs::last_write_time(header), first);
  write("a.idl", "module a { valued P { int y; }; }");
  ASSERT_EQ(run_driver(options({"a.idl"}), errors), 0);
  EXPECT_NE(fs::last_write_time(header), first);
  EXPECT_FALSE(write_if_changed(header, read(header)));
  EXPECT_TRUE(write_if_changed(header, "changed"));
}

TEST_F(Driver, DependencyFileNamesEveryFileRead) {
  write("a.idl", "module a { valued P { int x; }; }");
  write("b.idl", "include \"a.idl\";");
  DriverOptions o = options({"b.idl"});
  o.depfile = dir_ / "out" / "b.d";
  std::ostringstream errors;
  ASSERT_EQ(run_driver(o, errors), 0);
  const std::string out = (dir_ / "out").string();
  const std::string in = (dir_ / "in").string();
  EXPECT_EQ(read(o.depfile), out + "/b.planet.h " + out + "/b.planet.cc: \\\n  " + in +
                                 "/a.idl \\\n  " + in + "/b.idl\n");
  EXPECT_EQ(make_dependency_rule({"a b"}, {"c$"}), "a\\ b: \\\n  c$$\n");
}

TEST_F(Driver, ReportsTheFirstErrorOfEachFailingInput) {
  write("good.idl", "valued P { int x; };");
  write("bad.idl", "valued P { int x }");
  write("worse.idl", "valued Q { Nope n; };");
  std::ostringstream errors;
  EXPECT_EQ(run_driver(options({"bad.idl", "good.idl", "worse.idl"}), errors), 1);
  const std::string in = (dir_ / "in").string();
  EXPECT_EQ(errors.str(),
            in + "/bad.idl:1:18: error: unexpected '}', expected ';' after the field\n" + in +
                "/worse.idl:1:12: error: unknown type 'Nope', expected a builtin type or the name "
                "of an enum, valued, event or interface defined before this point\n");
  EXPECT_TRUE(fs::exists(dir_ / "out" / "good.planet.h"));
  EXPECT_FALSE(fs::exists(dir_ / "out" / "bad.planet.h"));
}

TEST_F(Driver, MissingInputIsAnError) {
  std::ostringstream errors;
  EXPECT_EQ(run_driver(options({"missing.idl"}), errors), 1);
  EXPECT_NE(errors.str().find("missing.idl: error: cannot read"), std::string::npos);
}

}  // namespace
}  // namespace icars::planet::idl
