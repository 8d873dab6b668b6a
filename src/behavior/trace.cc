#include "icars/behavior/trace.h"

#include <fmt/format.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <stdexcept>

#include "icars/planet/event.h"

namespace icars::behavior {

namespace {

template <class T>
std::optional<TraceValue> integer_of(const planet::Value& v) {
  if (!v.is<T>()) return std::nullopt;
  return static_cast<std::int64_t>(v.as<T>());
}

template <class T>
std::optional<T> typed(const TraceFields& fields, std::string_view name) {
  for (const auto& [n, v] : fields) {
    if (n != name) continue;
    if (const auto* value = std::get_if<T>(&v)) return *value;
    return std::nullopt;
  }
  return std::nullopt;
}

bool is_record_key(std::string_view name) {
  return name == "t" || name == "time" || name == "kind" || name == "source" || name == "text" ||
         name == "properties";
}

}  // namespace

std::optional<TraceValue> trace_value(const planet::Value& value) {
  if (value.is<bool>()) return value.as<bool>();
  if (value.is<std::string>()) return value.as<std::string>();
  if (value.is<double>()) return value.as<double>();
  if (value.is<float>()) return static_cast<double>(value.as<float>());
  for (const auto& n : {integer_of<std::uint8_t>(value), integer_of<std::int16_t>(value),
                        integer_of<std::int32_t>(value), integer_of<std::int64_t>(value)}) {
    if (n) return n;
  }
  return std::nullopt;
}

TraceRecord& TraceRecord::with_properties(const planet::Properties& event) {
  properties.emplace();
  for (const auto& [name, value] : event.items()) {
    if (auto v = trace_value(value)) properties->emplace_back(name, std::move(*v));
  }
  return *this;
}

std::string TraceRecord::field(std::string_view name) const {
  for (const auto& [n, v] : fields) {
    if (n != name) continue;
    if (const auto* s = std::get_if<std::string>(&v)) return *s;
    if (const auto* b = std::get_if<bool>(&v)) return *b ? "true" : "false";
    if (const auto* i = std::get_if<std::int64_t>(&v)) return std::to_string(*i);
    return fmt::format("{}", std::get<double>(v));
  }
  return "";
}

std::optional<double> TraceRecord::number(std::string_view name) const {
  if (const auto i = typed<std::int64_t>(fields, name)) return static_cast<double>(*i);
  return typed<double>(fields, name);
}

std::optional<bool> TraceRecord::flag(std::string_view name) const { return typed<bool>(fields, name); }

std::optional<TraceValue> TraceRecord::property(std::string_view name) const {
  if (!properties) return std::nullopt;
  for (const auto& [n, v] : *properties) {
    if (n == name) return v;
  }
  return std::nullopt;
}

std::string TraceRecord::to_json() const {
  nlohmann::ordered_json j;
  j["t"] = time.count();
  j["time"] = format_time(time);
  j["kind"] = kind;
  j["source"] = source;
  j["text"] = text;
  for (const auto& [name, value] : fields) {
    // A field named like a record key breaks with()'s contract: written as "_<name>", it
    // replaces nothing, and docs/trace.schema.json rejects the record (its test names it).
    const auto key = is_record_key(name) ? "_" + name : name;
    std::visit([&](const auto& v) { j[key] = v; }, value);
  }
  if (properties) {
    auto& object = j["properties"] = nlohmann::ordered_json::object();
    for (const auto& property : *properties) {
      const std::string& name = property.first;  // clang 14 (the fuzz build) cannot capture a structured binding in a lambda
      std::visit([&](const auto& v) { object[name] = v; }, property.second);
    }
  }
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

void Trace::add_sink(Sink sink) {
  std::lock_guard lock(mutex_);
  sinks_.push_back(std::move(sink));
}

void Trace::record(TraceRecord record) {
  std::lock_guard lock(mutex_);
  for (const auto& sink : sinks_) sink(record);
}

Trace::Sink timeline_printer(std::FILE* out, std::vector<std::string> quiet) {
  return [out, quiet = std::move(quiet)](const TraceRecord& r) {
    if (std::find(quiet.begin(), quiet.end(), r.kind) != quiet.end()) return;
    const auto line = fmt::format("[{}] {:<10} {}\n", format_time(r.time), r.kind, r.text);
    std::fputs(line.c_str(), out);
    std::fflush(out);
  };
}

Trace::Sink json_lines_writer(const std::string& path) {
  std::shared_ptr<std::FILE> file(std::fopen(path.c_str(), "w"), [](std::FILE* f) {
    if (f) std::fclose(f);
  });
  if (!file) throw std::runtime_error("cannot write the trace file " + path);
  return [file](const TraceRecord& r) {
    const auto line = r.to_json() + "\n";
    std::fputs(line.c_str(), file.get());
    std::fflush(file.get());
  };
}

Trace::Sink TraceLog::sink() {
  return [state = state_](const TraceRecord& r) {
    {
      std::lock_guard lock(state->mutex);
      state->records.push_back(r);
    }
    state->changed.notify_all();
  };
}

std::vector<TraceRecord> TraceLog::records() const {
  std::lock_guard lock(state_->mutex);
  return state_->records;
}

std::vector<TraceRecord> TraceLog::of_kind(std::string_view kind) const {
  std::lock_guard lock(state_->mutex);
  std::vector<TraceRecord> out;
  for (const auto& r : state_->records) {
    if (r.kind == kind) out.push_back(r);
  }
  return out;
}

bool TraceLog::wait_for(const std::function<bool(const TraceRecord&)>& pred,
                        std::chrono::milliseconds timeout) {
  std::unique_lock lock(state_->mutex);
  std::size_t checked = 0;
  return state_->changed.wait_for(lock, timeout, [&] {
    for (; checked < state_->records.size(); ++checked) {
      if (pred(state_->records[checked])) return true;
    }
    return false;
  });
}

}  // namespace icars::behavior
