#pragma once
// Order statistics for benchmark reports. Benchmarks report medians and
// percentiles rather than means: the machines are shared, and one slow
// round (another process's build) must not move the figure.

#include <algorithm>
#include <cmath>
#include <vector>

namespace penumbra::bench {

/// The p-th percentile (p in (0, 100]) by nearest rank; 0 for no values.
inline double Percentile(std::vector<double> values, double p) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const size_t rank = size_t(std::ceil(p / 100.0 * double(values.size())));
  return values[std::clamp<size_t>(rank, 1, values.size()) - 1];
}

/// The median: the mean of the two middle values for an even count.
inline double Median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

}  // namespace penumbra::bench
