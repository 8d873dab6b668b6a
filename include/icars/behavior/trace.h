// The trace of a running application: what happened, when (simulated time), and who did it —
// state transitions, tasks and behaviors starting and ending, service calls, events, device
// effects, robot and user positions. Sinks turn it into a readable timeline, a JSON-lines file
// for tools and tests (docs/trace.md, checked against docs/trace.schema.json), or an in-memory
// log.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "icars/clock/time.h"

namespace icars::planet {
class Value;
class Properties;
}  // namespace icars::planet

namespace icars::behavior {

// A detail of a record: integers stay integers (a request id, an event's `time_ms`).
using TraceValue = std::variant<std::string, double, bool, std::int64_t>;
using TraceFields = std::vector<std::pair<std::string, TraceValue>>;

// A PLANET value as a condition sees it (condition.h): bool; byte, short, int and long as an
// integer; float and double as a double; string. Other types (binary, sequences, valued
// types) have no trace value: nullopt.
std::optional<TraceValue> trace_value(const planet::Value& value);

struct TraceRecord {
  Time time{0};
  std::string kind;    // "transition", "task", "behavior", "call", "event", "effect", "robot", ...
  std::string source;  // who: a state, a behavior's path ("RestMode/VoiceControl/GoToUser"), a device
  std::string text;    // one readable line
  TraceFields fields;  // details for machines, named by the code that records them
  // The properties of the event an "event" record is about, apart from `fields`, so that an
  // event's own names (a SpeechEvent's `text`, a property named `task`) clash with nothing.
  std::optional<TraceFields> properties;

  // `name` is none of the record's own keys: t, time, kind, source, text, properties.
  TraceRecord& with(std::string name, TraceValue value) {
    fields.emplace_back(std::move(name), std::move(value));
    return *this;
  }
  // Sets `properties` to every property that has a trace value (trace_value), in order.
  TraceRecord& with_properties(const planet::Properties& event);

  // The field's value as text ("" when absent).
  std::string field(std::string_view name) const;
  // The field's value when it is a number (a double or an integer) / a flag (nullopt when
  // absent or of another kind).
  std::optional<double> number(std::string_view name) const;
  std::optional<bool> flag(std::string_view name) const;
  // The event property's value (nullopt when absent or the record has no properties).
  std::optional<TraceValue> property(std::string_view name) const;
  // {"t":..., "time":"d0 18:10:00", "kind":..., "source":..., "text":..., <fields>,
  //  "properties":{...} when the record has properties}; docs/trace.md.
  std::string to_json() const;
};

// Fans records out to sinks. Thread-safe; a sink is called under the trace's lock, so records
// reach every sink in one order and a sink need not lock.
class Trace {
 public:
  using Sink = std::function<void(const TraceRecord&)>;
  void add_sink(Sink sink);
  void record(TraceRecord record);

 private:
  std::mutex mutex_;
  std::vector<Sink> sinks_;
};

// Prints "[d0 18:10:03] transition  Observation -> RestMode on TimeToRest" lines. Records of
// the kinds in `quiet` (e.g. "robot" positions) are not printed.
Trace::Sink timeline_printer(std::FILE* out, std::vector<std::string> quiet = {"robot", "user"});

// Appends one JSON object per line to `path` (truncated first); throws std::runtime_error
// naming the path when it cannot be opened.
Trace::Sink json_lines_writer(const std::string& path);

// Keeps every record, for tests and summaries.
class TraceLog {
 public:
  Trace::Sink sink();
  std::vector<TraceRecord> records() const;
  std::vector<TraceRecord> of_kind(std::string_view kind) const;
  // Waits until some record satisfies `pred` (checking records already kept too).
  bool wait_for(const std::function<bool(const TraceRecord&)>& pred, std::chrono::milliseconds timeout);

 private:
  struct State {
    mutable std::mutex mutex;
    std::condition_variable changed;
    std::vector<TraceRecord> records;
  };
  std::shared_ptr<State> state_ = std::make_shared<State>();
};

}  // namespace icars::behavior
