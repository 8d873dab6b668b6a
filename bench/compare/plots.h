// The plots of an icars-compare run, drawn by gnuplot (pngcairo): each writes <name>.png with
// the data and script it was drawn from (<name>.dat, <name>.gp) beside it, and returns false
// when gnuplot failed or is missing (what gnuplot said is on stderr).
#pragma once

#include <filesystem>

#include "report.h"

namespace icars::bench {

// compare.png: every system's advantage over the baseline (PLANET) in every measured metric,
// up always better, on a log scale from the parity line at 1, grouped by workload, with
// PLANET's targets of docs/performance.md marked where a metric has one.
bool plot_advantage(const Report& report, const std::filesystem::path& png);

// scaling_connections.png: calls/s and p99 latency against the number of client connections
// (log x), one line per system. Nothing is drawn when the series was not run.
bool plot_connections(const Report& report, const std::filesystem::path& png);

// scaling_fanout.png: deliveries/s against the number of subscribers, log-log, one line per
// system. Nothing is drawn when the series was not run.
bool plot_fan_out(const Report& report, const std::filesystem::path& png);

}  // namespace icars::bench
