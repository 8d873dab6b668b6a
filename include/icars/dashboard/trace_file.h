// A recorded trace (`icars run --trace FILE`, docs/trace.md) opened for replay: its records are
// found by index without holding them in memory (one offset per record), so a week-long trace
// replays in a dashboard as quickly as an evening's.
#pragma once

#include <cstdint>
#include <filesystem>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include "icars/dashboard/dashboard.h"

namespace icars::dashboard {

class TraceFile {
 public:
  // Reads the file once to index its lines. Throws std::runtime_error "<file>:<line>: <why>" for
  // a file that cannot be read or a line that is not a JSON object with a time `t`, and for a
  // file without records.
  explicit TraceFile(std::filesystem::path file);

  std::uint64_t size() const { return offsets_.size(); }
  std::int64_t first_ms() const { return first_ms_; }
  std::int64_t last_ms() const { return last_ms_; }
  // Records [from, from + count) as JSON lines (fewer at the end). Thread-safe.
  std::vector<std::string> read(std::uint64_t from, std::size_t count) const;
  // For Dashboard::replay(); the TraceFile must outlive the dashboard.
  RecordSource source() const;

 private:
  std::filesystem::path file_;
  std::vector<std::uint64_t> offsets_;  // where each record's line starts
  std::int64_t first_ms_ = 0;
  std::int64_t last_ms_ = 0;
  mutable std::mutex mutex_;
};

}  // namespace icars::dashboard
