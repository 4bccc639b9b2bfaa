// Temporal stability measures; definitions in core/metrics/temporal.h and docs/metrics.md.
#include "core/metrics/temporal.h"

#include "core/base/error.h"
#include "core/base/vec8.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace dhr {

namespace {

inline double luma_f(const Rgb8& p) { return 0.299 * p.r + 0.587 * p.g + 0.114 * p.b; }

// Each pixel's terms of the two sums: |dT - dR|, and |dT| where the reference is static (0
// elsewhere, which leaves a sum of non-negative terms unchanged); returns the static count.
// Built for AVX2 and the baseline (core/base/vec8.h) so that the compiler can vectorize it; apart
// from the sums, which stay sequential in temporal_scores.
DHR_VEC8_TARGETS int64_t step_terms(const Rgb8* rp, const Rgb8* r, const Rgb8* tp, const Rgb8* t, size_t n,
                                    double threshold, double* err, double* flicker) {
  int64_t still = 0;
  for (size_t i = 0; i < n; ++i) {
    const double dr = luma_f(r[i]) - luma_f(rp[i]);
    const double dt = luma_f(t[i]) - luma_f(tp[i]);
    err[i] = std::abs(dt - dr);
    const bool is_static = std::abs(dr) <= threshold;
    flicker[i] = is_static ? std::abs(dt) : 0.0;
    still += is_static ? 1 : 0;
  }
  return still;
}

}  // namespace

TemporalScores temporal_scores(const ImageRGB8& reference_prev, const ImageRGB8& reference, const ImageRGB8& test_prev,
                               const ImageRGB8& test, double static_threshold) {
  const int w = reference.width(), h = reference.height();
  for (const ImageRGB8* im : {&reference_prev, &test_prev, &test})
    if (im->width() != w || im->height() != h)
      fail("temporal scores: frames differ in size: reference {}x{}, got {}x{}", w, h, im->width(), im->height());
  if (reference.empty()) fail("temporal scores: cannot compare empty frames");
  if (!(static_threshold >= 0) || !std::isfinite(static_threshold))
    fail("temporal scores: static_threshold {} must be a finite value >= 0 (luma levels)", static_threshold);
  double err = 0, flicker = 0;
  int64_t still = 0;
  constexpr size_t kChunk = 512;
  double err_terms[kChunk], flicker_terms[kChunk];
  for (size_t at = 0; at < reference.size(); at += kChunk) {
    const size_t n = std::min(kChunk, reference.size() - at);
    still += step_terms(reference_prev.data() + at, reference.data() + at, test_prev.data() + at, test.data() + at, n,
                        static_threshold, err_terms, flicker_terms);
    for (size_t i = 0; i < n; ++i) {  // sequential: a fixed summation order
      err += err_terms[i];
      flicker += flicker_terms[i];
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
