#include "traced_run.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
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

std::vector<std::string> example_policies(const std::string& source, const std::string& prefix) {
  std::vector<std::string> out;
  for (const auto& entry : std::filesystem::directory_iterator(source + "/examples/policies")) {
    const auto name = entry.path().filename().string();
    if (name.starts_with(prefix) && name.ends_with(".xml")) out.push_back(entry.path().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

std::string element_text(const std::string& text, const std::string& element) {
  const auto at = text.find("<" + element);
  if (at == std::string::npos) return {};
  const auto open = text.rfind('\n', at) + 1;
  const auto closing = "</" + element + ">";
  const auto close = text.find(closing, at);
  if (close == std::string::npos) return {};
  return text.substr(open, close + closing.size() - open);
}

void expect_documented_and_valid(const std::string& icars, const std::string& source, const std::string& example,
                                 const std::string& shown_element, const std::string& house) {
  const auto doc = read_file(source + "/docs/policy.md");
  const std::filesystem::path path(example);
  EXPECT_NE(doc.find("examples/policies/" + path.filename().string()), std::string::npos)
      << "docs/policy.md does not name " << example;
  const auto shown = element_text(read_file(example), shown_element);
  EXPECT_FALSE(shown.empty()) << example << " has no <" << shown_element << ">";
  EXPECT_NE(doc.find(shown), std::string::npos) << "docs/policy.md does not show, verbatim:\n" << shown;
  const auto validated = run_program(icars, "validate " + example + " --world " + house, 120);
  EXPECT_EQ(validated.exit_code, 0) << validated.output;
  EXPECT_NE(validated.output.find(example + ": ok: policy " + path.stem().string()), std::string::npos)
      << validated.output;
  EXPECT_NE(validated.output.find(", 0 warnings"), std::string::npos) << validated.output;
}

std::vector<nlohmann::json> run_policy(const std::string& icars, const std::string& policy, const std::string& house,
                                       const std::string& until, std::string& output) {
  auto r = run_traced(icars, "run " + policy + " --world " + house + " --until " + until + " --speed max --quiet", 300);
  output = r.run.output;
  EXPECT_EQ(r.run.exit_code, 0) << r.run.output;
  return std::move(r.trace);
}

}  // namespace icars_test
