// LDR-FLIP: the image difference evaluator of Andersson et al., "FLIP: A Difference Evaluator for
// Alternating Images" (HPG 2020), written from the paper. docs/metrics.md gives every step, its
// constants, the choices the paper leaves open, and what was validated.
//
// Inputs are 8-bit sRGB images; the result is a per-pixel error in [0, 1] (0 = the images look
// the same when flipped between, 1 = the largest difference) and its mean over all pixels. The
// map is deterministic: it does not depend on the number of threads.
#pragma once

#include "core/buffers/image.h"

#include <cstddef>
#include <vector>

namespace dhr {

// The paper's viewing setup: a 0.7 m wide 3840-pixel monitor seen from 0.7 m, 67 pixels per degree.
constexpr double kFlipDefaultPpd = 67.0;

struct FlipViewing {
  double distance_m = 0.7;       // eye to screen
  double display_width_m = 0.7;  // physical width of the screen
  int display_width_px = 3840;   // horizontal resolution of the screen
};
// Pixels per degree of visual angle: distance * (width_px / width_m) * pi / 180 (the paper's
// formula; 67.02 for the default setup). Throws dhr::Error for non-positive or non-finite values.
double pixels_per_degree(const FlipViewing& viewing);

struct FlipResult {
  ImageF map;       // per-pixel FLIP error in [0, 1], same size as the inputs
  double mean = 0;  // mean of map over all pixels (summed in double, in a fixed order)
};

// FLIP of `test` against `reference` at `ppd` pixels per degree. Throws dhr::Error when sizes
// differ, an image is empty, or ppd is not in (0, 1000].
FlipResult flip(const ImageRGB8& reference, const ImageRGB8& test, double ppd = kFlipDefaultPpd);

// The half of FLIP that depends on one image alone: per pixel, the Hunt-adjusted CIELAB of its
// CSF-filtered colour and the magnitudes of its edge and point detectors (docs/metrics.md). A
// reference scored against many images (the runs of a sweep share their local reference and
// ground truth) computes it once: flip(flip_features(r, ppd), t) is flip(r, t, ppd), bit for bit.
struct FlipFeatures {
  int width = 0, height = 0;
  double ppd = 0;
  PixelVector<float> lab;          // L, a, b per pixel, row-major
  PixelVector<float> edge, point;  // one per pixel, row-major
  size_t bytes() const { return (lab.size() + edge.size() + point.size()) * sizeof(float); }
};

// Throws dhr::Error for an empty image or ppd not in (0, 1000].
FlipFeatures flip_features(const ImageRGB8& image, double ppd = kFlipDefaultPpd);

// FLIP of `test` against the reference whose features these are, at their ppd. Throws dhr::Error
// when the sizes differ or the features are not whole.
FlipResult flip(const FlipFeatures& reference, const ImageRGB8& test);

// The error map on FLIP's own colour map (matplotlib's "magma", as the authors show their maps):
// error e in [0, 1] -> entry round(255 e); values outside [0, 1] (or NaN) saturate.
ImageRGB8 flip_colour_map(const ImageF& flip_map);

// CIELAB's f(t) (cube root above (6/29)^3, linear below), one value and a row in place: the
// row kernel must give lab_f_value's bits on every input (tests/core/metrics/test_flip.cpp checks it).
namespace flip_detail {
float lab_f_value(float t);
void lab_f_values(float* v, size_t n);
// The filter taps (a product and a sum each) that flip(features, test) computes per pixel of the
// test image at `ppd`, counted from the kernels it builds: the horizontal pass's seven planes
// and the vertical pass's eight (tests/core/metrics/bench_metrics.cpp times them alone, as a floor). Throws
// dhr::Error for ppd not in (0, 1000].
int test_half_taps(double ppd);
}  // namespace flip_detail

}  // namespace dhr
