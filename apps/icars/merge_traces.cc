#include "merge_traces.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>

namespace icars::app {

int merge_traces(const std::vector<std::string>& files, const std::string& output) {
  struct Record {
    std::int64_t t;
    std::optional<std::int64_t> wall;
    std::size_t file;
    std::size_t line;
    std::string text;
  };
  std::vector<Record> records;
  for (std::size_t f = 0; f < files.size(); ++f) {
    std::ifstream in(files[f]);
    if (!in) {
      std::fprintf(stderr, "icars merge-traces: %s cannot be read\n", files[f].c_str());
      return 2;
    }
    const auto server = std::filesystem::path(files[f]).stem().string();
    std::string line;
    std::size_t number = 0;
    while (std::getline(in, line)) {
      ++number;
      if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
      auto record = nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false);
      if (!record.is_object() || !record.contains("t") || !record["t"].is_number_integer()) {
        std::fprintf(stderr, "icars merge-traces: %s:%zu: not a trace record (a JSON object with an integer \"t\")\n",
                     files[f].c_str(), number);
        return 2;
      }
      const bool named = record.contains("server");
      if (!named) record["server"] = server;
      std::optional<std::int64_t> wall;
      if (record.contains("wall_us") && record["wall_us"].is_number_integer()) wall = record["wall_us"].get<std::int64_t>();
      records.push_back({record["t"].get<std::int64_t>(), wall, f, number, named ? line : record.dump()});
    }
  }
  // The machine's time when every record has it (icars serve writes it: the servers' house
  // clocks differ by up to a poll); the house's time otherwise.
  const bool by_wall = std::all_of(records.begin(), records.end(), [](const Record& r) { return r.wall.has_value(); });
  std::stable_sort(records.begin(), records.end(), [by_wall](const Record& a, const Record& b) {
    const auto ka = by_wall ? *a.wall : a.t;
    const auto kb = by_wall ? *b.wall : b.t;
    if (ka != kb) return ka < kb;
    if (a.file != b.file) return a.file < b.file;
    return a.line < b.line;
  });
  std::ofstream file;
  if (!output.empty() && output != "-") {
    file.open(output);
    if (!file) {
      std::fprintf(stderr, "icars merge-traces: %s cannot be written\n", output.c_str());
      return 2;
    }
  }
  std::ostream& out = file.is_open() ? static_cast<std::ostream&>(file) : std::cout;
  for (const auto& r : records) out << r.text << '\n';
  out.flush();
  return out ? 0 : 1;
}

}  // namespace icars::app
