// The statistics every icars-compare figure is reported with: nearest-rank percentiles.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <utility>
#include <vector>

namespace icars::bench {

// The nearest-rank p-quantile (0 < p <= 1) of a sample; NaN for an empty one.
inline double percentile(std::vector<double> values, double p) {
  if (values.empty()) return std::nan("");
  std::sort(values.begin(), values.end());
  const auto rank = static_cast<std::size_t>(std::ceil(p * static_cast<double>(values.size())));
  return values[std::min(values.size() - 1, rank == 0 ? 0 : rank - 1)];
}

inline double median(std::vector<double> values) { return percentile(std::move(values), 0.5); }

}  // namespace icars::bench
