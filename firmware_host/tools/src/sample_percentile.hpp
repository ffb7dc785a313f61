#pragma once
// The benchmarks' percentile of a set of timings: the sample at rank p * n (clamped to
// the last), no interpolation, so the figure printed is one that was measured.
#include <algorithm>
#include <cstddef>
#include <vector>

namespace markcell::host {

inline double sample_percentile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(std::min<double>(static_cast<double>(v.size()) - 1, p * static_cast<double>(v.size())));
  return v[i];
}

}  // namespace markcell::host
