// Temporal stability of a displayed sequence against its reference sequence, one frame pair at a
// time (docs/metrics.md, "Temporal stability", gives the formulas and the literature they follow).
//
// Both measures work on unrounded BT.601 luma Y' = 0.299 R' + 0.587 G' + 0.114 B' of the 8-bit
// sRGB values (the channel the benchmark's SSIM uses), in 8-bit levels:
//   temporal_error: mean over all pixels of |(T_k - T_{k-1}) - (R_k - R_{k-1})|, the error of the
//     frame-to-frame change (0 when the test changes exactly as the reference does, whatever its
//     per-frame error);
//   static_flicker: mean over the pixels whose reference does not change (|R_k - R_{k-1}| <=
//     static_threshold) of |T_k - T_{k-1}|, change that should not be there at all.
#pragma once

#include "core/buffers/image.h"

#include <cstdint>

namespace dhr {

struct TemporalScores {
  double temporal_error = 0;  // mean |dT - dR| over all pixels, luma levels
  double static_flicker = 0;  // mean |dT| over static pixels; 0 when there are none
  int64_t pixels = 0;         // pixels in the frame
  int64_t static_pixels = 0;  // pixels counted as static
};

// One frame step: the reference and the test at k-1 and at k. All four images must have the
// same, non-empty size (dhr::Error otherwise); static_threshold is in luma levels, >= 0.
TemporalScores temporal_scores(const ImageRGB8& reference_prev, const ImageRGB8& reference, const ImageRGB8& test_prev,
                               const ImageRGB8& test, double static_threshold = 0.0);

// Per-run accumulation over frame steps: temporal_error is the mean of the per-step values
// (every step has the same pixel count); static_flicker is weighted by each step's static pixels
// (the mean over all static pixel-steps of the run), 0 when none was static.
class TemporalRun {
 public:
  void add(const TemporalScores& step);
  int64_t steps() const { return steps_; }
  double temporal_error() const { return steps_ ? error_sum_ / double(steps_) : 0.0; }
  double static_flicker() const { return static_pixels_ ? flicker_sum_ / double(static_pixels_) : 0.0; }
  int64_t static_pixels() const { return static_pixels_; }

 private:
  int64_t steps_ = 0;
  double error_sum_ = 0;
  double flicker_sum_ = 0;  // sum of |dT| over static pixels
  int64_t static_pixels_ = 0;
};

}  // namespace dhr
