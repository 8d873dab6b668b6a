#include "plots.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "scaling.h"

namespace icars::bench {
namespace {

namespace fs = std::filesystem;

// One colour per system in every plot.
std::string colour_of(const std::string& system, std::size_t index) {
  static const std::map<std::string, std::string> known = {
      {"raw-tcp", "#7f7f7f"},
      {"planet", "#1f77b4"},
      {"grpc", "#d62728"},
      {"ice", "#2ca02c"},
      {"capnp", "#9467bd"},
      // A TLS variant in a light shade of its plaintext system's colour.
      {"planet-tls", "#aec7e8"},
      {"grpc-tls", "#ff9896"},
      {"ice-tls", "#98df8a"}};
  static const std::vector<std::string> others = {"#ff7f0e", "#8c564b", "#e377c2", "#17becf"};
  const auto c = known.find(system);
  return c != known.end() ? c->second : others[index % others.size()];
}

// A gnuplot string literal: single-quoted, a quote doubled.
std::string gnuplot_string(const std::string& text) {
  std::string quoted = "'";
  for (const char c : text) quoted += c == '\'' ? std::string("''") : std::string(1, c);
  return quoted + "'";
}

// A shell word: single-quoted, a quote as '\''.
std::string shell_word(const std::string& text) {
  std::string quoted = "'";
  for (const char c : text) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return quoted + "'";
}

bool run_gnuplot(const fs::path& script, const std::string& text) {
  std::ofstream(script) << text;
  const std::string command = "gnuplot " + shell_word(script.string()) + " 2>&1";
  return std::system(command.c_str()) == 0;
}

std::string header(const fs::path& png, int width, int height) {
  return fmt::format("set terminal pngcairo size {},{} font 'sans,10'\nset output {}\n", width,
                     height, gnuplot_string(png.string()));
}

// The points of a series that a system has no median for, as " (not measured at 1000 and
// 5000)", or "" when it has all of them.
std::string missing_points(const Report& report, const std::string& system,
                           const std::vector<std::pair<int, std::string>>& points) {
  std::vector<std::string> absent;
  for (const auto& [n, key] : points) {
    if (std::isnan(report.median_of(system, key))) absent.push_back(std::to_string(n));
  }
  if (absent.empty()) return "";
  std::string text = absent.front();
  for (std::size_t i = 1; i < absent.size(); ++i) {
    text += (i + 1 == absent.size() ? " and " : ", ") + absent[i];
  }
  return " (not measured at " + text + ")";
}

// One line per system through the points of a series: data blocks `x y...` per system, in
// the order of report.systems, and the `plot` clauses that draw column `column` of them.
struct Series {
  std::string data;
  std::vector<std::string> clauses;
};

Series series_of(const Report& report, const fs::path& dat,
                 const std::vector<std::pair<int, std::vector<std::string>>>& points,
                 const std::vector<std::pair<int, std::string>>& missing_keys, int column) {
  Series series;
  int block = 0;
  for (std::size_t i = 0; i < report.systems.size(); ++i) {
    const std::string& system = report.systems[i];
    std::string lines;
    for (const auto& [x, keys] : points) {
      std::string line = std::to_string(x);
      bool complete = true;
      for (const auto& key : keys) {
        const double v = report.median_of(system, key);
        complete = complete && std::isfinite(v) && v > 0;
        line += fmt::format(" {:.6g}", v);
      }
      if (complete) lines += line + "\n";
    }
    if (lines.empty()) continue;
    series.data += fmt::format("# {}\n{}\n\n", system, lines);
    series.clauses.push_back(
        fmt::format("{} index {} using 1:{} with linespoints lw 2 pt 7 ps 1.2 lc rgb '{}' title {}",
                    gnuplot_string(dat.string()), block++, column, colour_of(system, i),
                    gnuplot_string(system + missing_points(report, system, missing_keys))));
  }
  return series;
}

std::string join(const std::vector<std::string>& parts, const std::string& separator) {
  std::string text;
  for (std::size_t i = 0; i < parts.size(); ++i) text += (i ? separator : "") + parts[i];
  return text;
}

}  // namespace

bool plot_advantage(const Report& report, const fs::path& png) {
  const std::string base = report.baseline();
  const std::string base_name = base == "planet" ? "PLANET" : base;
  std::vector<std::string> others;
  for (const auto& s : report.systems) {
    if (s != base) others.push_back(s);
  }
  // A metric's bars are those of the systems that have a value for it, side by side around its
  // x (the TLS variants, say, run only a few workloads); every bar is as wide as the fullest
  // metric's.
  const auto drawn = [&](const Metric& m) {
    std::vector<std::pair<std::size_t, double>> bars_of;  // index into `others`, advantage
    for (std::size_t j = 0; j < others.size(); ++j) {
      const double a = report.advantage(others[j], m);
      if (std::isfinite(a) && a > 0) bars_of.emplace_back(j, a);
    }
    return bars_of;
  };
  std::size_t k = 1;
  for (const auto& m : metrics()) k = std::max(k, drawn(m).size());
  const double bar = 0.8 / static_cast<double>(k);

  // x positions: a unit per metric, half a unit between workloads.
  std::vector<std::string> xtics, group_tics, separators;
  std::vector<std::string> bars(others.size());
  std::string targets;
  double x = 0;
  double low = 1, high = 1;
  std::string group;
  double group_start = 0;
  const auto close_group = [&] {
    if (group.empty()) return;
    group_tics.push_back(fmt::format("{} {:.2f}", gnuplot_string(group), (group_start + x) / 2));
    separators.push_back(
        fmt::format("set arrow from {:.2f}, graph 0 to {:.2f}, graph 1 nohead "
                    "dt 3 lc rgb '#bbbbbb' back",
                    x + 0.25, x + 0.25));
    x += 0.5;
  };
  for (const auto& m : metrics()) {
    if (!report.has(m.key)) continue;
    if (m.group != group) {
      close_group();
      group = m.group;
      group_start = x;
    }
    const double centre = x + 0.5;
    xtics.push_back(fmt::format("{} {:.2f}", gnuplot_string(m.label), centre));
    const auto row = drawn(m);
    for (std::size_t i = 0; i < row.size(); ++i) {
      const auto [j, a] = row[i];
      const double offset = static_cast<double>(i) - (static_cast<double>(row.size()) - 1) / 2;
      bars[j] += fmt::format("{:.3f} {:.6g}\n", centre + offset * bar, a);
      low = std::min(low, a);
      high = std::max(high, a);
    }
    if (const auto t = report.target_advantage(m)) {
      targets += fmt::format("{:.3f} {:.6g} \"target {}\"\n", centre, *t, m.target->text);
      low = std::min(low, *t);
      high = std::max(high, *t);
    }
    x += 1;
  }
  close_group();
  if (xtics.empty()) return true;  // nothing measured

  const fs::path dat = fs::path(png).replace_extension(".dat");
  {
    std::ofstream out(dat);
    for (std::size_t j = 0; j < others.size(); ++j) {
      out << "# " << others[j] << ": x advantage\n"
          << (bars[j].empty() ? "NaN NaN\n" : bars[j]) << "\n\n";
    }
    if (!targets.empty()) out << "# targets: x advantage label\n" << targets;
  }
  const std::string data = gnuplot_string(dat.string());
  const int width = std::clamp(300 + 75 * static_cast<int>(xtics.size()), 1200, 2600);
  std::string gp = header(png, width, 850);
  gp +=
      fmt::format("set title {} font ',12' offset 0,1\n",
                  gnuplot_string(fmt::format("icars-compare: each system's advantage over {0} "
                                             "(medians of {1} repetitions; up is better, {0} = 1)",
                                             base_name, report.repetitions)));
  gp += fmt::format(
      "set ylabel {}\nset label {} at screen 0.5, screen 0.94 center font ',9'\n",
      gnuplot_string(fmt::format("advantage over {} (log scale; up is better)", base_name)),
      gnuplot_string(fmt::format("advantage = the system's value / {0}'s where higher is "
                                 "better (calls/s, MiB/s, deliveries/s, calls), {0}'s / the "
                                 "system's where lower is better (us, ms, KiB)",
                                 base_name)));
  gp += "set logscale y 10\nset grid ytics mytics lc rgb '#dddddd'\nset mytics 10\n";
  gp += fmt::format("set yrange [{:.6g}:{:.6g}]\n", low / 1.6, high * 1.6);
  gp += fmt::format("set xrange [-0.25:{:.2f}]\n", x - 0.25);
  gp += "set xtics rotate by -35 left noenhanced nomirror font ',9' (" + join(xtics, ", ") + ")\n";
  gp += "set link x2\nset x2tics noenhanced nomirror font ',10' (" + join(group_tics, ", ") + ")\n";
  gp += "set tics scale 0\n";
  for (const auto& s : separators) gp += s + "\n";
  gp +=
      "set key below horizontal noenhanced samplen 2 width 2\n"
      "set tmargin 6\nset bmargin 14\nset rmargin 16\n"
      "set style fill solid 0.85 border rgb '#333333'\n";
  std::vector<std::string> clauses = {
      fmt::format("1 with lines lw 2 dt 2 lc rgb '{}' title {}", colour_of(base, 0),
                  gnuplot_string(fmt::format("{} = 1 (parity)", base_name)))};
  for (std::size_t j = 0; j < others.size(); ++j) {
    clauses.push_back(fmt::format(
        "{} index {} using 1:2:($1-{:.4f}):($1+{:.4f}):(1):2 with boxxyerror lc rgb '{}' "
        "title {}",
        data, j, bar / 2, bar / 2, colour_of(others[j], j + 1), gnuplot_string(others[j])));
  }
  if (!targets.empty()) {
    clauses.push_back(fmt::format(
        "{} index {} using ($1-0.45):2:(0.9):(0) with vectors nohead lw 3 lc rgb 'black' "
        "title {}",
        data, others.size(), gnuplot_string("PLANET's target: met when at or below 1")));
    clauses.push_back(
        fmt::format("{} index {} using 1:2:3 with labels offset 0,0.7 font ',8' noenhanced notitle",
                    data, others.size()));
  }
  gp += "plot " + join(clauses, ", \\\n     ") + "\n";
  return run_gnuplot(fs::path(png).replace_extension(".gp"), gp);
}

bool plot_connections(const Report& report, const fs::path& png) {
  std::vector<std::pair<int, std::vector<std::string>>> points;
  std::vector<std::pair<int, std::string>> missing_keys;
  for (const int n : kConnectionPoints) {
    points.push_back({n, {connections_calls_key(n), connections_p99_key(n)}});
    missing_keys.emplace_back(n, connections_calls_key(n));
  }
  const fs::path dat = fs::path(png).replace_extension(".dat");
  const Series calls = series_of(report, dat, points, missing_keys, 2);
  if (calls.clauses.empty()) return true;  // the series was not run
  const Series p99 = series_of(report, dat, points, missing_keys, 3);
  std::ofstream(dat) << "# connections calls/s p99_us\n" << calls.data;

  std::string gp = header(png, 1500, 620);
  gp += fmt::format(
      "set multiplot layout 1,2 title {} font ',12'\n",
      gnuplot_string(fmt::format("icars-compare: small synchronous calls over N connections to one "
                                 "server, min(N, 2 x cores) client threads calling them in turn "
                                 "(medians of {} repetitions)",
                                 report.repetitions)));
  gp +=
      "set logscale x 10\nset xrange [0.7:1500]\nset xtics ('1' 1, '10' 10, '100' 100, "
      "'1,000' 1000)\nset grid lc rgb '#dddddd'\nset key top left noenhanced box opaque\n"
      "set xlabel 'client connections (log scale)'\nset format y '%.0s%c'\n";
  gp +=
      "set title 'throughput: calls/s (higher is better)'\nset ylabel 'calls/s'\n"
      "set yrange [0:*]\n";
  gp += "plot " + join(calls.clauses, ", \\\n     ") + "\n";
  gp +=
      "set title 'p99 latency of a call (lower is better)'\nset ylabel 'p99 (us, log scale)'\n"
      "set logscale y 10\nset yrange [*:*]\nset format y '%g'\nset key top left\n";
  gp += "plot " + join(p99.clauses, ", \\\n     ") + "\n";
  gp += "unset multiplot\n";
  return run_gnuplot(fs::path(png).replace_extension(".gp"), gp);
}

bool plot_fan_out(const Report& report, const fs::path& png) {
  std::vector<std::pair<int, std::vector<std::string>>> points;
  std::vector<std::pair<int, std::string>> missing_keys;
  for (const int n : kSubscriberPoints) {
    points.push_back({n, {fan_out_key(n)}});
    missing_keys.emplace_back(n, fan_out_key(n));
  }
  const fs::path dat = fs::path(png).replace_extension(".dat");
  const Series deliveries = series_of(report, dat, points, missing_keys, 2);
  if (deliveries.clauses.empty()) return true;  // the series was not run
  std::ofstream(dat) << "# subscribers deliveries/s\n" << deliveries.data;

  std::string gp = header(png, 1000, 650);
  gp += fmt::format(
      "set title {} font ',12'\n",
      gnuplot_string(fmt::format("icars-compare: event fan-out, 64-byte events to N subscriber "
                                 "connections (medians of {} repetitions)",
                                 report.repetitions)));
  gp +=
      "set logscale xy 10\nset xrange [7:7000]\nset xtics ('10' 10, '100' 100, '1,000' 1000, "
      "'5,000' 5000)\nset grid xtics ytics mytics lc rgb '#dddddd'\n"
      "set key bottom left noenhanced box opaque\nset format y '%.0s%c'\n"
      "set xlabel 'subscribers (log scale)'\n"
      "set ylabel 'deliveries/s until every subscriber has every event (log scale)'\n";
  gp += "plot " + join(deliveries.clauses, ", \\\n     ") + "\n";
  return run_gnuplot(fs::path(png).replace_extension(".gp"), gp);
}

}  // namespace icars::bench
