#include "icars/dashboard/trace_file.h"

#include <fmt/format.h>

#include <fstream>
#include <nlohmann/json.hpp>

namespace icars::dashboard {

namespace {

// The record's time, or why the line is not a record.
std::int64_t time_of(const std::string& line, const std::filesystem::path& file, std::uint64_t number) {
  const auto j = nlohmann::json::parse(line, nullptr, false);
  if (j.is_discarded() || !j.is_object()) {
    throw std::runtime_error(fmt::format("{}:{}: not a JSON object (a trace has one record per line)", file.string(), number));
  }
  const auto t = j.find("t");
  if (t == j.end() || !t->is_number_integer()) {
    throw std::runtime_error(fmt::format("{}:{}: a record without its time \"t\" (docs/trace.md)", file.string(), number));
  }
  return t->get<std::int64_t>();
}

}  // namespace

TraceFile::TraceFile(std::filesystem::path file) : file_(std::move(file)) {
  std::ifstream in(file_, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("{}:0: cannot read the trace", file_.string()));
  std::string line;
  std::uint64_t offset = 0;
  std::uint64_t number = 0;
  std::string last;
  while (std::getline(in, line)) {
    ++number;
    const auto at = offset;
    offset += line.size() + 1;
    if (line.empty()) continue;
    // Every line is checked to be an object; only the first and last are parsed for their time
    // (a week's trace indexes in the time it takes to read it).
    if (line.front() != '{' || line.back() != '}') {
      throw std::runtime_error(fmt::format("{}:{}: not a JSON object (a trace has one record per line)",
                                           file_.string(), number));
    }
    if (offsets_.empty()) first_ms_ = time_of(line, file_, number);
    offsets_.push_back(at);
    last = std::move(line);
  }
  if (offsets_.empty()) throw std::runtime_error(fmt::format("{}:0: the trace has no records", file_.string()));
  last_ms_ = time_of(last, file_, number);
}

std::vector<std::string> TraceFile::read(std::uint64_t from, std::size_t count) const {
  std::vector<std::string> out;
  if (from >= offsets_.size()) return out;
  std::lock_guard lock(mutex_);
  std::ifstream in(file_, std::ios::binary);
  in.seekg(static_cast<std::streamoff>(offsets_[from]));
  std::string line;
  while (out.size() < count && from + out.size() < offsets_.size() && std::getline(in, line)) {
    if (!line.empty()) out.push_back(std::move(line));
  }
  return out;
}

RecordSource TraceFile::source() const {
  return RecordSource{[this] { return size(); }, [this](std::uint64_t from, std::size_t count) { return read(from, count); }};
}

}  // namespace icars::dashboard
