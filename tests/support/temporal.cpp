#include "tests/support.h"

#include <cmath>

namespace dhr::test {

TemporalScores temporal_scores_one_loop(const ImageRGB8& reference_prev, const ImageRGB8& reference,
                                        const ImageRGB8& test_prev, const ImageRGB8& test, double static_threshold) {
  auto y = [](const Rgb8& p) { return 0.299 * p.r + 0.587 * p.g + 0.114 * p.b; };
  double err = 0, flicker = 0;
  int64_t still = 0;
  for (size_t i = 0; i < reference.size(); ++i) {
    const double dr = y(reference[i]) - y(reference_prev[i]), dt = y(test[i]) - y(test_prev[i]);
    err += std::abs(dt - dr);
    if (std::abs(dr) <= static_threshold) {
      flicker += std::abs(dt);
      ++still;
    }
  }
  TemporalScores s;
  s.pixels = int64_t(reference.size());
  s.temporal_error = err / double(reference.size());
  s.static_pixels = still;
  s.static_flicker = still ? flicker / double(still) : 0.0;
  return s;
}

}  // namespace dhr::test
