// The trace file as a tool reads it (docs/trace.md): every record a real `icars run` writes is
// valid against docs/trace.schema.json, and so is every example of docs/trace.md. The records
// are checked by scripts/check-trace.py, which validates with python3-jsonschema in a child
// process, as a user checks a trace of their own.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "traced_run.h"

using nlohmann::json;

namespace {

using icars_test::read_file;
using icars_test::read_json_lines;
using icars_test::str;

const std::string kIcars = ICARS_BINARY;
const std::string kSource = ICARS_SOURCE_DIR;
const std::string kPython = ICARS_PYTHON3;

// `scripts/check-trace.py FILE`: exit code 0 and "FILE: N records ok (...)" when all are valid.
icars_test::ProgramRun check_trace(const std::string& path) {
  return icars_test::run_program(
      kPython,
      kSource + "/scripts/check-trace.py --schema " + kSource + "/docs/trace.schema.json " + path,
      120);
}

// A short run of `policy` on the paper house (18:00 on), its trace kept for the test.
struct TracedRun {
  icars_test::ProgramRun run;
  std::string trace_path;
  std::vector<json> trace;
};
TracedRun run_icars(const std::string& policy, const std::string& until) {
  TracedRun r;
  r.trace_path =
      icars_test::temp_path("trace_schema", policy.substr(policy.rfind('/') + 1) + ".jsonl");
  r.run = icars_test::run_program(kIcars,
                                  "run " + kSource + "/" + policy + " --world " + kSource +
                                      "/houses/paper_house.xml --speed max --until " + until +
                                      " --quiet --trace " + r.trace_path,
                                  120);
  r.trace = read_json_lines(r.trace_path);
  return r;
}

// The keys no record may have: a name mangled to avoid a clash ("_text").
void expect_no_mangled_keys(const std::vector<json>& trace) {
  for (const auto& r : trace) {
    for (const auto& [key, value] : r.items()) EXPECT_FALSE(key.starts_with("_")) << r.dump();
  }
}

}  // namespace

// The paper's policy on the paper's house, from 18:00 until the robot has reached the user on
// the sofa and served the first voice command: every kind of record a normal evening writes.
TEST(TraceSchema, EveryRecordOfThePaperHomesRunIsValid) {
  const auto r = run_icars("examples/smart_home/paper_home.xml", "18:25");
  ASSERT_EQ(r.run.exit_code, 0) << r.run.output;
  std::set<std::string> kinds;
  for (const auto& record : r.trace) kinds.insert(str(record, "kind"));
  for (const char* kind : {"policy", "state", "task", "transition", "event", "behavior", "call",
                           "note", "command", "effect", "speech", "robot", "user"}) {
    EXPECT_TRUE(kinds.contains(kind))
        << "no \"" << kind << "\" record in " << r.trace.size() << " records";
  }

  const auto check = check_trace(r.trace_path);
  EXPECT_EQ(check.exit_code, 0) << check.output;
  EXPECT_NE(check.output.find(": " + std::to_string(r.trace.size()) + " records ok"),
            std::string::npos)
      << check.output;

  // The occupancy event the Observation task turned into TimeToRest keeps its integer time_ms.
  const auto rest = std::find_if(r.trace.begin(), r.trace.end(), [](const json& j) {
    return str(j, "kind") == "event" && str(j, "event") == "TimeToRest";
  });
  ASSERT_NE(rest, r.trace.end()) << r.run.output;
  ASSERT_TRUE(rest->contains("properties")) << rest->dump();
  const auto& properties = (*rest)["properties"];
  EXPECT_EQ(properties.value("furniture", ""), "sofa") << rest->dump();
  EXPECT_EQ(properties.value("occupied", false), true) << rest->dump();
  ASSERT_TRUE(properties.contains("time_ms") && properties["time_ms"].is_number_integer())
      << rest->dump();
  EXPECT_GT(properties["time_ms"].get<std::int64_t>(), 18 * 3'600'000);
  expect_no_mangled_keys(r.trace);
  std::remove(r.trace_path.c_str());
}

// A SpeechEvent's own `text` is a property of the event record, not a mangled "_text".
TEST(TraceSchema, ASpeechEventKeepsItsTextAsAProperty) {
  const auto r = run_icars("apps/icars/testdata/hear_speech.xml", "18:13");
  ASSERT_EQ(r.run.exit_code, 0) << r.run.output;
  const auto speech = std::find_if(r.trace.begin(), r.trace.end(), [](const json& j) {
    return str(j, "kind") == "event" && str(j, "event") == "SpeechEvent";
  });
  ASSERT_NE(speech, r.trace.end())
      << "no SpeechEvent by 18:13 (the user says \"turn on the TV\" at 18:12)";
  EXPECT_TRUE(str(*speech, "text").starts_with("Listen: SpeechEvent text=turn on the TV"))
      << speech->dump();
  ASSERT_TRUE(speech->contains("properties")) << speech->dump();
  const auto& properties = (*speech)["properties"];
  EXPECT_EQ(properties.value("text", ""), "turn on the TV") << speech->dump();
  EXPECT_EQ(properties.value("device", ""), "robot1_mic") << speech->dump();
  EXPECT_TRUE(properties.contains("time_ms") && properties["time_ms"].is_number_integer())
      << speech->dump();
  expect_no_mangled_keys(r.trace);

  const auto check = check_trace(r.trace_path);
  EXPECT_EQ(check.exit_code, 0) << check.output;
  std::remove(r.trace_path.c_str());
}

// docs/trace.md shows a valid example of every kind the schema knows.
TEST(TraceSchema, TheDocsExamplesCoverEveryKindAndAreValid) {
  const auto doc = read_file(kSource + "/docs/trace.md");
  const auto schema = json::parse(read_file(kSource + "/docs/trace.schema.json"));
  const auto examples_path = icars_test::temp_path("trace_schema", "doc_examples.jsonl");
  std::set<std::string> shown;
  {
    std::ofstream out(examples_path);
    const std::regex block("```json\n([^`]*)```");
    for (auto it = std::sregex_iterator(doc.begin(), doc.end(), block);
         it != std::sregex_iterator(); ++it) {
      std::istringstream lines((*it)[1].str());
      for (std::string line; std::getline(lines, line);) {
        if (line.empty()) continue;
        shown.insert(json::parse(line).value("kind", ""));
        out << line << '\n';
      }
    }
  }
  std::set<std::string> known;
  for (const auto& kind : schema["properties"]["kind"]["enum"])
    known.insert(kind.get<std::string>());
  EXPECT_EQ(shown, known)
      << "docs/trace.md should show one example per kind of docs/trace.schema.json";
  const auto check = check_trace(examples_path);
  EXPECT_EQ(check.exit_code, 0) << check.output;
  std::remove(examples_path.c_str());
}

// The schema is strict: the event record as icars wrote it before properties were nested
// (a SpeechEvent's text as "_text", properties beside the record's keys) is rejected, naming
// the line and the key.
TEST(TraceSchema, TheCheckerRejectsWhatTheSchemaDoesNotDescribe) {
  const auto path = icars_test::temp_path("trace_schema", "bad.jsonl");
  {
    std::ofstream out(path);
    out << R"({"t":1,"time":"d0 00:00:00.001","kind":"policy","source":"coordinator","text":"policy p started","policy":"p"})"
        << '\n'
        << R"({"t":2,"time":"d0 00:00:00.002","kind":"event","source":"Listen","text":"Listen: SpeechEvent text=hi","event":"SpeechEvent","task":"Listen","task_event":false,"_text":"hi","device":"mic"})"
        << '\n'
        << R"({"t":3,"time":"d0 00:00:00.003","kind":"state","source":"coordinator","text":"entered S","state":"S","event":"entered"})"
        << '\n';
  }
  const auto check = check_trace(path);
  EXPECT_EQ(check.exit_code, 1) << check.output;
  EXPECT_NE(check.output.find(path + ":2: "), std::string::npos) << check.output;
  EXPECT_NE(check.output.find("'properties' is a required property"), std::string::npos)
      << check.output;
  EXPECT_NE(check.output.find(path + ":3: 'entered' is not one of ['enter', 'exit']"),
            std::string::npos)
      << check.output;
  EXPECT_EQ(check.output.find(path + ":1:"), std::string::npos) << check.output;
  std::remove(path.c_str());
}
