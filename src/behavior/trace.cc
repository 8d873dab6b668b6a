#include "icars/behavior/trace.h"

#include <fmt/format.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <stdexcept>

namespace icars::behavior {

std::string TraceRecord::field(std::string_view name) const {
  for (const auto& [n, v] : fields) {
    if (n != name) continue;
    if (const auto* s = std::get_if<std::string>(&v)) return *s;
    if (const auto* b = std::get_if<bool>(&v)) return *b ? "true" : "false";
    return fmt::format("{}", std::get<double>(v));
  }
  return "";
}

namespace {

template <class T>
std::optional<T> typed_field(const std::vector<std::pair<std::string, TraceValue>>& fields, std::string_view name) {
  for (const auto& [n, v] : fields) {
    if (n != name) continue;
    if (const auto* value = std::get_if<T>(&v)) return *value;
    return std::nullopt;
  }
  return std::nullopt;
}

}  // namespace

std::optional<double> TraceRecord::number(std::string_view name) const { return typed_field<double>(fields, name); }

std::optional<bool> TraceRecord::flag(std::string_view name) const { return typed_field<bool>(fields, name); }

std::string TraceRecord::to_json() const {
  nlohmann::ordered_json j;
  j["t"] = time.count();
  j["time"] = format_time(time);
  j["kind"] = kind;
  j["source"] = source;
  j["text"] = text;
  for (const auto& [name, value] : fields) {
    // A field never replaces the record's own keys: it is written as "_<name>" instead.
    const bool reserved = name == "t" || name == "time" || name == "kind" || name == "source" || name == "text";
    const auto key = reserved ? "_" + name : name;
    std::visit([&](const auto& v) { j[key] = v; }, value);
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
