// A recorded trace opened for replay: records by index, and a broken file refused at its line.
#include "icars/dashboard/trace_file.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

namespace icars::dashboard {
namespace {

std::filesystem::path write(const std::string& name, const std::string& text) {
  const auto p = std::filesystem::temp_directory_path() / ("icars-trace-file-" + name);
  std::ofstream(p) << text;
  return p;
}

TEST(TraceFile, FindsRecordsByIndexWithoutKeepingThem) {
  std::string text;
  for (int i = 0; i < 12'000; ++i) text += "{\"t\":" + std::to_string(1000 + i) + ",\"kind\":\"note\"}\n";
  const auto p = write("ok.jsonl", text);
  const TraceFile trace(p);
  EXPECT_EQ(trace.size(), 12'000u);
  EXPECT_EQ(trace.first_ms(), 1000);
  EXPECT_EQ(trace.last_ms(), 12'999);
  const auto page = trace.read(11'998, 5);
  ASSERT_EQ(page.size(), 2u);
  EXPECT_EQ(page[0], "{\"t\":12998,\"kind\":\"note\"}");
  EXPECT_TRUE(trace.read(20'000, 5).empty());
  const auto source = trace.source();
  EXPECT_EQ(source.total(), 12'000u);
  EXPECT_EQ(source.read(0, 1).at(0), "{\"t\":1000,\"kind\":\"note\"}");
  std::filesystem::remove(p);
}

TEST(TraceFile, ABrokenTraceIsRefusedAtItsLine) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"{\"t\":1}\nnot json\n", ":2: not a JSON object"},
      {"{\"kind\":\"note\"}\n", ":1: a record without its time"},
      {"", ":0: the trace has no records"},
      {"{\"t\":1}\n{\"t\":\"late\"}\n", ":2: a record without its time"},
  };
  for (const auto& [text, expected] : cases) {
    const auto p = write("bad.jsonl", text);
    try {
      TraceFile trace(p);
      ADD_FAILURE() << "accepted: " << text;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
    std::filesystem::remove(p);
  }
  EXPECT_THROW(TraceFile("/nonexistent/trace.jsonl"), std::runtime_error);
}

}  // namespace
}  // namespace icars::dashboard
