// Temporal stability measures; definitions in core/temporal.h and docs/metrics.md.
#include "core/temporal.h"

#include "core/error.h"
#include "core/vec8.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace dhr {

namespace {

inline double luma_f(const Rgb8& p) { return 0.299 * p.r + 0.587 * p.g + 0.114 * p.b; }
inline Vec4d luma4(const Rgb8* p) {
  const Vec4d r = {double(p[0].r), double(p[1].r), double(p[2].r), double(p[3].r)};
  const Vec4d g = {double(p[0].g), double(p[1].g), double(p[2].g), double(p[3].g)};
  const Vec4d b = {double(p[0].b), double(p[1].b), double(p[2].b), double(p[3].b)};
  return 0.299 * r + 0.587 * g + 0.114 * b;
}
// std::abs lane by lane, but for -0, which stays -0 (std::abs gives +0): adding either to a sum
// leaves it unchanged, and no -0 arises here (a difference of equal values is +0).
inline Vec4d abs4(Vec4d v) { return v < 0.0 ? -v : v; }

// Each pixel's terms of the two sums: |dT - dR|, and |dT| where the reference is static (0
// elsewhere, which leaves a sum of non-negative terms unchanged); returns the static count.
// Four pixels at a time in double, the same operations per pixel as luma_f's expression.
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
