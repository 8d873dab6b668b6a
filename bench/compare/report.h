// The results of an icars-compare run: every metric's samples per system, the points a system
// could not reach and why, printed as a table and written as JSON and CSV (plots.h draws them).
// The metric table here is the one list of what icars-compare reports.
#pragma once

#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

namespace icars::bench {

// A target of docs/performance.md ("Not reached, and why") for PLANET's value of a metric.
struct Target {
  enum class Kind { times_raw_tcp, absolute };
  Kind kind;
  double value;      // a factor of raw TCP's median, or the value itself in the metric's unit
  std::string text;  // short, for a plot: "<= 1.3x raw" (of raw TCP's median)
};

// One metric of the table: its unit, whether larger is better, and the workload it belongs to
// (the groups of the advantage plot).
struct Metric {
  std::string key;
  std::string label;
  std::string unit;
  bool higher_better;
  std::string group;
  std::optional<Target> target;
};

// Every metric icars-compare reports, in the order of the table.
const std::vector<Metric>& metrics();

// samples[system][metric key] = one value per repetition.
using Samples = std::map<std::string, std::map<std::string, std::vector<double>>>;

// Why a point was not measured in a repetition, and in how many repetitions that happened.
struct MissingPoint {
  std::string reason;  // the last repetition's
  int repetitions = 0;
};
using Missing = std::map<std::string, std::map<std::string, MissingPoint>>;

struct Report {
  std::vector<std::string> systems;
  int repetitions = 0;
  Samples samples;
  Missing missing;

  void record_missing(const std::string& system, const std::string& key, const std::string& why);
  const MissingPoint* missing_point(const std::string& system, const std::string& key) const;

  // The median of a metric for a system; NaN when it was not measured.
  double median_of(const std::string& system, const std::string& key) const;
  bool has(const std::string& key) const;  // measured for at least one system
  // The system the advantage plot and "x/planet" compare with: PLANET, or the first system
  // when PLANET is not in the run.
  std::string baseline() const;
  // A system's advantage over the baseline in a metric, where up is always better: its median
  // over the baseline's where higher is better, the baseline's over its own where lower is.
  double advantage(const std::string& system, const Metric& metric) const;
  // Where a system exactly at PLANET's target for `metric` would stand on the advantage scale;
  // nullopt when the metric has no target or the figures it needs were not measured.
  std::optional<double> target_advantage(const Metric& metric) const;

  void print(std::ostream& out) const;
  nlohmann::json to_json() const;
  static Report from_json(const nlohmann::json& results);  // what to_json wrote
  void write_csv(const std::filesystem::path& file) const;
};

}  // namespace icars::bench
