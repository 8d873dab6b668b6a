// The trace's records as tools read them: the JSON-lines file (docs/trace.md) keeps an event's
// properties apart from the record's own keys and keeps integers as integers.
#include "icars/behavior/trace.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "icars/behavior/behavior.h"

namespace b = icars::behavior;
using nlohmann::json;

namespace {

// What the Coordinator records when a task's root propagates `event` (docs/trace.md, "event").
b::TraceRecord event_record(const b::Event& event) {
  b::TraceRecord r;
  r.time = icars::Time(65520845);
  r.kind = "event";
  r.source = "Listen";
  r.text = "Listen: " + b::describe_event(event);
  r.with("event", event.type())
      .with("task", std::string("Listen"))
      .with("task_event", false)
      .with_properties(event);
  return r;
}

b::Event speech() {
  b::Event e("SpeechEvent");
  e.set("text", std::string("turn on the TV"))
      .set("confidence", 0.95)
      .set("device", std::string("robot1_mic"))
      .set("time_ms", std::int64_t{65520845});
  return e;
}

}  // namespace

TEST(TraceJson, ASpeechEventsTextIsItsPropertyNotTheRecordsText) {
  const auto j = json::parse(event_record(speech()).to_json());
  EXPECT_EQ(
      j["text"],
      "Listen: SpeechEvent text=turn on the TV confidence=0.95 device=robot1_mic time_ms=65520845");
  ASSERT_TRUE(j.contains("properties")) << j.dump();
  EXPECT_EQ(j["properties"]["text"], "turn on the TV");
  EXPECT_EQ(j["properties"]["device"], "robot1_mic");
  EXPECT_EQ(j["event"], "SpeechEvent");
  EXPECT_EQ(j["task"], "Listen");
  for (const auto& [key, value] : j.items()) EXPECT_FALSE(key.starts_with("_")) << j.dump();
}

TEST(TraceJson, IntegerPropertiesOfEveryIdlWidthAreWrittenAsIntegers) {
  b::Event e("WaypointReached");
  e.set("waypoint", std::string("door"))
      .set("index", std::int32_t{3})
      .set("time_ms", std::int64_t{86'400'000LL * 30})
      .set("level", std::uint8_t{200})
      .set("step", std::int16_t{-7})
      .set("ratio", 0.5F)
      .set("moving", true)
      .set("audio", icars::planet::Binary{{std::byte{1}}});  // no trace value: left out
  const auto r = event_record(e);
  const auto j = json::parse(r.to_json());
  const auto& p = j["properties"];
  ASSERT_TRUE(p["index"].is_number_integer()) << j.dump();
  EXPECT_EQ(p["index"], 3);
  ASSERT_TRUE(p["time_ms"].is_number_integer()) << j.dump();
  EXPECT_EQ(p["time_ms"].get<std::int64_t>(), 86'400'000LL * 30);
  EXPECT_EQ(p["level"], 200);
  EXPECT_EQ(p["step"], -7);
  EXPECT_DOUBLE_EQ(p["ratio"].get<double>(), 0.5);
  EXPECT_EQ(p["moving"], true);
  EXPECT_EQ(p["waypoint"], "door");
  EXPECT_FALSE(p.contains("audio")) << j.dump();
  // In the order the event has them, as the text does.
  std::vector<std::string> names;
  const auto ordered = nlohmann::ordered_json::parse(r.to_json());
  for (const auto& [key, value] : ordered["properties"].items()) names.push_back(key);
  EXPECT_EQ(names, (std::vector<std::string>{"waypoint", "index", "time_ms", "level", "step",
                                             "ratio", "moving"}));
  EXPECT_EQ(r.text,
            "Listen: WaypointReached waypoint=door index=3 time_ms=2592000000 level=200 step=-7 "
            "ratio=0.5 moving=true");
  EXPECT_EQ(std::get<std::int64_t>(*r.property("index")), 3);
  EXPECT_FALSE(r.property("audio"));
}

TEST(TraceJson, AnEventWithoutPropertiesHasAnEmptyObjectAndOtherRecordsNone) {
  const auto j = json::parse(event_record(b::Event("TimeToRest")).to_json());
  ASSERT_TRUE(j.contains("properties"));
  EXPECT_TRUE(j["properties"].is_object());
  EXPECT_TRUE(j["properties"].empty());

  b::TraceRecord state;
  state.kind = "state";
  state.with("state", std::string("Normal")).with("event", std::string("enter"));
  EXPECT_FALSE(json::parse(state.to_json()).contains("properties"));
}

TEST(TraceJson, IntegerFieldsStayIntegersAndReadAsNumbers) {
  b::TraceRecord r;
  r.kind = "command";
  r.with("request", std::int64_t{15}).with("x", 1.5);
  const auto j = json::parse(r.to_json());
  EXPECT_TRUE(j["request"].is_number_integer()) << j.dump();
  EXPECT_EQ(r.to_json().find("15.0"), std::string::npos) << r.to_json();
  EXPECT_EQ(r.number("request"), 15.0);
  EXPECT_EQ(r.field("request"), "15");
  EXPECT_EQ(r.number("x"), 1.5);
}

TEST(TraceJson, TheJsonLinesWriterWritesOneRecordPerLine) {
  const auto path =
      (std::filesystem::temp_directory_path() / fmt::format("trace_test_{}.jsonl", ::getpid()))
          .string();
  {
    const auto sink = b::json_lines_writer(path);
    b::TraceRecord policy;
    policy.kind = "policy";
    policy.text = "policy listen started";
    policy.with("policy", std::string("listen"));
    sink(policy);
    sink(event_record(speech()));
  }
  std::ifstream in(path);
  std::vector<json> lines;
  for (std::string line; std::getline(in, line);) lines.push_back(json::parse(line));
  std::filesystem::remove(path);
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[0]["kind"], "policy");
  EXPECT_EQ(lines[1]["properties"]["text"], "turn on the TV");
  EXPECT_EQ(lines[1]["properties"]["time_ms"], 65520845);
  EXPECT_EQ(lines[1]["t"], 65520845);
  EXPECT_EQ(lines[1]["time"], "d0 18:12:00.845");
}

TEST(TraceJson, AnUnwritablePathIsAnErrorNamingIt) {
  try {
    b::json_lines_writer("/nonexistent/dir/trace.jsonl");
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/dir/trace.jsonl"), std::string::npos)
        << e.what();
  }
}
