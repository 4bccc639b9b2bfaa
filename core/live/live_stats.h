// Live mode's summaries of per-frame times and scores (core/live/live_server.cpp,
// core/live/live_client.cpp). Internal: included by those files only.
#pragma once

#include "core/results/results.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <utility>
#include <vector>

namespace dhr::live_detail {

// Median and p95 as the simulator's stage statistics compute them (StageStats), plus max, mean, n.
inline nlohmann::json percentiles(std::vector<double> v) {
  if (v.empty()) return nullptr;
  const StageStats s{std::move(v)};
  const double max = *std::max_element(s.samples_ms.begin(), s.samples_ms.end());
  const double n = double(s.samples_ms.size());
  return {{"median", s.median()}, {"p95", s.p95()}, {"max", max}, {"mean", s.total() / n}, {"n", s.samples_ms.size()}};
}

}  // namespace dhr::live_detail
