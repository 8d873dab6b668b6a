#include "report.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <fstream>

#include "percentile.h"
#include "scaling.h"

namespace icars::bench {
namespace {

using json = nlohmann::json;

// 1000 as "1,000".
std::string with_commas(int n) {
  const std::string digits = std::to_string(n);
  std::string text;
  for (std::size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) text += ',';
    text += digits[i];
  }
  return text;
}

// 1 as "1 connection", 1000 as "1,000 connections".
std::string count_of(int n, const std::string& thing) {
  return with_commas(n) + " " + thing + (n == 1 ? "" : "s");
}

std::vector<Metric> make_metrics() {
  const Target small_p50{Target::Kind::times_raw_tcp, 1.3, "<= 1.3x raw"};
  const Target upload{Target::Kind::times_raw_tcp, 0.7, ">= 70% of raw"};
  std::vector<Metric> all = {
      {"small_p50_us", "small call p50", "us", false, "small call", small_p50},
      {"small_p99_us", "small call p99", "us", false, "small call", {}},
      {"pipeline1_calls_s", "pipelined calls, 1 client", "calls/s", true, "pipelined", {}},
      {"pipeline8_calls_s", "pipelined calls, 8 clients", "calls/s", true, "pipelined", {}},
      {"upload_1mib_mib_s", "1 MiB upload", "MiB/s", true, "upload", upload},
      {"upload_64mib_mib_s", "64 MiB upload", "MiB/s", true, "upload", upload},
      {"upload_8mib_mib_s", "8 MiB upload", "MiB/s", true, "upload", upload},
      {"hol_echo_ms", "large echo (HOL)", "ms", false, "head-of-line",
       Target{Target::Kind::times_raw_tcp, 1.5, "<= 1.5x raw"}},
      {"hol_echo_cold_ms", "large echo, the first (cold memory)", "ms", false, "head-of-line", {}},
      {"hol_small_p50_us", "small call p50 during echo", "us", false, "head-of-line", {}},
      {"hol_small_p99_us", "small call p99 during echo", "us", false, "head-of-line", {}},
      {"hol_small_max_ms", "small call max during echo", "ms", false, "head-of-line",
       Target{Target::Kind::absolute, 5.0, "< 5 ms"}},
      {"hol_small_calls", "small calls during echo", "calls", true, "head-of-line", {}},
      {"fanout_deliveries_s", "event fan-out", "deliveries/s", true, "fan-out", {}},
      {"reconnect_ms", "reconnection", "ms", false, "reconnection", {}},
  };
  for (const int n : kConnectionPoints) {
    all.push_back({connections_calls_key(n),
                   "calls, " + count_of(n, "connection"),
                   "calls/s",
                   true,
                   "connections: calls/s",
                   {}});
  }
  for (const int n : kConnectionPoints) {
    all.push_back({connections_p99_key(n),
                   "call p99, " + count_of(n, "connection"),
                   "us",
                   false,
                   "connections: p99",
                   {}});
  }
  all.push_back(
      {kIdleConnectionKey, "memory per idle connection", "KiB", false, "idle memory", {}});
  for (const int n : kSubscriberPoints) {
    all.push_back({fan_out_key(n),
                   "fan-out, " + count_of(n, "subscriber"),
                   "deliveries/s",
                   true,
                   "fan-out scaling",
                   {}});
  }
  return all;
}

std::string format_value(double v) {
  if (std::isnan(v)) return "-";
  if (std::isinf(v)) return "inf";
  if (v >= 1e6) return fmt::format("{:.2f}M", v / 1e6);
  if (v >= 1e4) return fmt::format("{:.0f}k", v / 1e3);
  if (v >= 100) return fmt::format("{:.0f}", v);
  if (v >= 10) return fmt::format("{:.1f}", v);
  return fmt::format("{:.2f}", v);
}

// NaN (not measured, or a ratio of nothing) as JSON null.
json number_or_null(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

}  // namespace

const std::vector<Metric>& metrics() {
  static const std::vector<Metric> all = make_metrics();
  return all;
}

void Report::record_missing(const std::string& system, const std::string& key,
                            const std::string& why) {
  MissingPoint& point = missing[system][key];
  point.reason = why;  // on one line: some systems' messages span several
  std::replace(point.reason.begin(), point.reason.end(), '\n', ' ');
  ++point.repetitions;
}

const MissingPoint* Report::missing_point(const std::string& system, const std::string& key) const {
  const auto points = missing.find(system);
  if (points == missing.end()) return nullptr;
  const auto point = points->second.find(key);
  return point == points->second.end() ? nullptr : &point->second;
}

double Report::median_of(const std::string& system, const std::string& key) const {
  const auto s = samples.find(system);
  if (s == samples.end()) return std::nan("");
  const auto m = s->second.find(key);
  return m == s->second.end() ? std::nan("") : median(m->second);
}

bool Report::has(const std::string& key) const {
  return std::any_of(systems.begin(), systems.end(),
                     [&](const auto& s) { return !std::isnan(median_of(s, key)); });
}

std::string Report::baseline() const {
  if (systems.empty() || std::find(systems.begin(), systems.end(), "planet") != systems.end()) {
    return "planet";
  }
  return systems.front();
}

double Report::advantage(const std::string& system, const Metric& metric) const {
  const double mine = median_of(system, metric.key);
  const double base = median_of(baseline(), metric.key);
  return metric.higher_better ? mine / base : base / mine;
}

std::optional<double> Report::target_advantage(const Metric& metric) const {
  if (!metric.target || baseline() != "planet") return std::nullopt;
  const double planet = median_of("planet", metric.key);
  const double threshold = metric.target->kind == Target::Kind::absolute
                               ? metric.target->value
                               : metric.target->value * median_of("raw-tcp", metric.key);
  const double at = metric.higher_better ? threshold / planet : planet / threshold;
  if (!std::isfinite(at) || at <= 0) return std::nullopt;
  return at;
}

void Report::print(std::ostream& out) const {
  out << fmt::format(
      "\nMedians of {} repetitions (client and server in separate processes on "
      "loopback). Ratios: x/raw = system / raw TCP, x/planet = system / PLANET.\n\n",
      repetitions);
  std::size_t width = 8;
  for (const auto& m : metrics()) width = std::max(width, m.label.size());
  // A column is as wide as its heading, at least (a long name, such as "planet-tls", widens it).
  const auto column = [](const std::string& heading, std::size_t at_least) {
    return std::max(at_least, heading.size());
  };
  std::string head = fmt::format("{:{}} {:>13}", "workload", width, "unit");
  for (const auto& s : systems) head += fmt::format(" {:>{}}", s, column(s, 9));
  for (const auto& s : systems) {
    if (s != "raw-tcp") head += fmt::format(" {:>{}}", s + "/raw", column(s + "/raw", 11));
  }
  for (const auto& s : systems) {
    if (s != "raw-tcp" && s != "planet") {
      head += fmt::format(" {:>{}}", s + "/planet", column(s + "/planet", 12));
    }
  }
  out << head << "\n" << std::string(head.size(), '-') << "\n";
  for (const auto& m : metrics()) {
    if (!has(m.key)) continue;
    std::string row = fmt::format("{:{}} {:>13}", m.label, width, m.unit);
    for (const auto& s : systems) {
      row += fmt::format(" {:>{}}", format_value(median_of(s, m.key)), column(s, 9));
    }
    const double raw = median_of("raw-tcp", m.key);
    const double planet = median_of("planet", m.key);
    for (const auto& s : systems) {
      if (s != "raw-tcp") {
        row +=
            fmt::format(" {:>{}}", format_value(median_of(s, m.key) / raw), column(s + "/raw", 11));
      }
    }
    for (const auto& s : systems) {
      if (s != "raw-tcp" && s != "planet") {
        row += fmt::format(" {:>{}}", format_value(median_of(s, m.key) / planet),
                           column(s + "/planet", 12));
      }
    }
    out << row << "\n";
  }
  out << "\n(higher is better for calls/s, MiB/s, deliveries/s and calls; lower for the rest)\n";
  if (missing.empty()) return;
  out << "\nNot measured (\"-\" above, or fewer repetitions in the median):\n";
  for (const auto& s : systems) {
    for (const auto& m : metrics()) {
      if (const MissingPoint* point = missing_point(s, m.key)) {
        out << fmt::format("  {:8} {}: {} (in {} of {} repetitions)\n", s, m.label, point->reason,
                           point->repetitions, repetitions);
      }
    }
  }
}

json Report::to_json() const {
  json rows = json::array();
  for (const auto& m : metrics()) {
    for (const auto& s : systems) {
      const auto sys = samples.find(s);
      if (sys == samples.end() || !sys->second.contains(m.key)) continue;
      const auto& values = sys->second.at(m.key);
      rows.push_back(
          {{"workload", m.key},
           {"label", m.label},
           {"unit", m.unit},
           {"higher_is_better", m.higher_better},
           {"system", s},
           {"median", median(values)},
           {"min", *std::min_element(values.begin(), values.end())},
           {"max", *std::max_element(values.begin(), values.end())},
           {"runs", values},
           {"ratio_to_raw_tcp", number_or_null(median_of(s, m.key) / median_of("raw-tcp", m.key))},
           {"ratio_to_planet", number_or_null(median_of(s, m.key) / median_of("planet", m.key))},
           {"advantage", number_or_null(advantage(s, m))}});
    }
  }
  json not_measured = json::array();
  for (const auto& s : systems) {
    for (const auto& m : metrics()) {
      if (const MissingPoint* point = missing_point(s, m.key)) {
        not_measured.push_back({{"system", s},
                                {"workload", m.key},
                                {"label", m.label},
                                {"reason", point->reason},
                                {"repetitions", point->repetitions}});
      }
    }
  }
  // The other numbers the clients reported (the server's RSS before any connection, the client
  // threads of a connections point, ...): their medians.
  json details = json::object();
  for (const auto& [system, values] : samples) {
    for (const auto& [key, runs] : values) {
      const bool listed = std::any_of(metrics().begin(), metrics().end(),
                                      [&](const Metric& m) { return m.key == key; });
      if (!listed) details[system][key] = median(runs);
    }
  }
  return {{"repetitions", repetitions},       {"systems", systems},
          {"advantage_baseline", baseline()}, {"rows", rows},
          {"missing", not_measured},          {"details", details}};
}

Report Report::from_json(const json& results) {
  Report report;
  report.systems = results.at("systems").get<std::vector<std::string>>();
  report.repetitions = results.at("repetitions").get<int>();
  for (const auto& row : results.at("rows")) {
    report.samples[row.at("system").get<std::string>()][row.at("workload").get<std::string>()] =
        row.at("runs").get<std::vector<double>>();
  }
  for (const auto& point : results.value("missing", json::array())) {
    report.missing[point.at("system").get<std::string>()][point.at("workload").get<std::string>()] =
        {point.at("reason").get<std::string>(), point.at("repetitions").get<int>()};
  }
  return report;
}

void Report::write_csv(const std::filesystem::path& file) const {
  std::ofstream out(file);
  out << "workload,unit,system,median,min,max,ratio_to_raw_tcp,ratio_to_planet,advantage,missing\n";
  const auto quoted = [](std::string text) {
    std::string q = "\"";
    for (const char c : text) q += c == '"' ? std::string("\"\"") : std::string(1, c);
    return q + "\"";
  };
  for (const auto& m : metrics()) {
    for (const auto& s : systems) {
      std::string why;
      if (const MissingPoint* point = missing_point(s, m.key)) {
        why =
            fmt::format("{} of {} repetitions: {}", point->repetitions, repetitions, point->reason);
      }
      const auto sys = samples.find(s);
      if (sys == samples.end() || !sys->second.contains(m.key)) {
        if (!why.empty()) out << fmt::format("{},{},{},,,,,,,{}\n", m.key, m.unit, s, quoted(why));
        continue;
      }
      const auto& v = sys->second.at(m.key);
      out << fmt::format("{},{},{},{},{},{},{},{},{},{}\n", m.key, m.unit, s, median(v),
                         *std::min_element(v.begin(), v.end()),
                         *std::max_element(v.begin(), v.end()),
                         median_of(s, m.key) / median_of("raw-tcp", m.key),
                         median_of(s, m.key) / median_of("planet", m.key), advantage(s, m),
                         why.empty() ? std::string() : quoted(why));
    }
  }
}

}  // namespace icars::bench
