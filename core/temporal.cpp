// Temporal stability measures; definitions in core/temporal.h and docs/metrics.md.
#include "core/temporal.h"

#include "core/error.h"

#include <cmath>
#include <vector>

namespace dhr {

namespace {
inline double luma_f(const Rgb8& p) { return 0.299 * p.r + 0.587 * p.g + 0.114 * p.b; }
}  // namespace

TemporalScores temporal_scores(const ImageRGB8& reference_prev, const ImageRGB8& reference,
                               const ImageRGB8& test_prev, const ImageRGB8& test, double static_threshold) {
  const int w = reference.width(), h = reference.height();
  for (const ImageRGB8* im : {&reference_prev, &test_prev, &test})
    if (im->width() != w || im->height() != h)
      fail("temporal scores: frames differ in size: reference {}x{}, got {}x{}", w, h, im->width(), im->height());
  if (reference.empty()) fail("temporal scores: cannot compare empty frames");
  if (!(static_threshold >= 0) || !std::isfinite(static_threshold))
    fail("temporal scores: static_threshold {} must be a finite value >= 0 (luma levels)", static_threshold);
  double err = 0, flicker = 0;
  int64_t still = 0;
  for (size_t i = 0; i < reference.size(); ++i) {  // sequential: a fixed summation order
    const double dr = luma_f(reference[i]) - luma_f(reference_prev[i]);
    const double dt = luma_f(test[i]) - luma_f(test_prev[i]);
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

void TemporalRun::add(const TemporalScores& step) {
  ++steps_;
  error_sum_ += step.temporal_error;
  flicker_sum_ += step.static_flicker * double(step.static_pixels);
  static_pixels_ += step.static_pixels;
}

}  // namespace dhr
