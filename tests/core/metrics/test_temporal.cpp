// Temporal stability (core/metrics/temporal.h): a sequence that flickers scores worse than one that
// does not, at equal per-frame SSIM; closed-form cases; bad input.
#include "core/base/error.h"
#include "core/base/rng.h"
#include "core/metrics/metrics.h"
#include "core/metrics/temporal.h"
#include "tests/support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <vector>

namespace dhr {
namespace {

// A reference frame symmetric under a left-right mirror, so that mirroring a test frame
// around it leaves every per-frame score unchanged.
ImageRGB8 symmetric_reference(int w, int h) {
  ImageRGB8 img(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const int d = std::min(x, w - 1 - x);
      const uint8_t v = uint8_t(120 + 60 * std::sin(d * 0.3f) * std::cos(y * 0.2f));
      img(x, y) = {v, uint8_t(255 - v), uint8_t(80 + (d * 7 + y * 3) % 90)};
    }
  return img;
}

ImageRGB8 mirrored(const ImageRGB8& a) {
  ImageRGB8 out(a.width(), a.height());
  for (int y = 0; y < a.height(); ++y)
    for (int x = 0; x < a.width(); ++x) out(x, y) = a(a.width() - 1 - x, y);
  return out;
}

// The reference plus +-d noise (a fixed random sign per pixel and channel).
ImageRGB8 with_pattern(const ImageRGB8& ref, int d, uint64_t seed) {
  ImageRGB8 out = ref;
  for (size_t i = 0; i < out.size(); ++i) {
    auto add = [&](uint8_t v, uint32_t c) {
      const int s = rng_uniform({seed, uint32_t(i), c, 0, 31}) < 0.5f ? -d : d;
      return uint8_t(std::clamp(int(v) + s, 0, 255));
    };
    out[i] = {add(ref[i].r, 0), add(ref[i].g, 1), add(ref[i].b, 2)};
  }
  return out;
}

TEST(Temporal, FlickerScoresWorseAtEqualPerFrameSsim) {
  // A static reference shown for 8 frames. "steady" shows the same noisy frame every time;
  // "flicker" alternates between it and its mirror image. Since the reference is mirror
  // symmetric, every displayed frame has the same SSIM (and PSNR) against the reference in both
  // sequences, yet only the flickering one changes from frame to frame.
  const int w = 96, h = 64;
  const ImageRGB8 ref = symmetric_reference(w, h);
  ASSERT_EQ(mirrored(ref), ref);
  const ImageRGB8 noisy = with_pattern(ref, 12, 1), noisy_mirrored = mirrored(noisy);
  std::vector<ImageRGB8> steady, flicker;
  for (int k = 0; k < 8; ++k) {
    steady.push_back(noisy);
    flicker.push_back(k % 2 ? noisy_mirrored : noisy);
  }
  TemporalRun steady_run, flicker_run;
  for (int k = 0; k < 8; ++k) {
    for (SsimBorder border : {SsimBorder::Valid, SsimBorder::Mirrored}) {
      const QualityScores s = compare_images(ref, steady[size_t(k)], SsimChannel::Luma, nullptr, border);
      const QualityScores f = compare_images(ref, flicker[size_t(k)], SsimChannel::Luma, nullptr, border);
      EXPECT_LT(s.ssim, 0.95);  // the frames are visibly noisy
      // Equal up to float rounding: the local moments are summed in another order in the mirror.
      EXPECT_NEAR(s.ssim, f.ssim, 1e-5) << "frame " << k;
      EXPECT_NEAR(s.psnr_db, f.psnr_db, 1e-9) << "frame " << k;
    }
    if (k == 0) continue;
    const TemporalScores ts = temporal_scores(ref, ref, steady[size_t(k - 1)], steady[size_t(k)]);
    const TemporalScores tf = temporal_scores(ref, ref, flicker[size_t(k - 1)], flicker[size_t(k)]);
    EXPECT_EQ(ts.temporal_error, 0.0);
    EXPECT_EQ(ts.static_flicker, 0.0);
    EXPECT_GT(tf.temporal_error, 3.0);                // about half of the pixels change by several levels
    EXPECT_EQ(tf.static_pixels, int64_t(w) * h);      // the whole reference is static
    EXPECT_EQ(tf.static_flicker, tf.temporal_error);  // the same when nothing moves
    steady_run.add(ts);
    flicker_run.add(tf);
  }
  EXPECT_EQ(flicker_run.steps(), 7);
  EXPECT_EQ(steady_run.temporal_error(), 0.0);
  EXPECT_GT(flicker_run.temporal_error(), 3.0);
  EXPECT_GT(flicker_run.static_flicker(), 3.0);
}

TEST(Temporal, ChangeThatFollowsTheReferenceIsNoTemporalError) {
  // The reference brightens by 10 levels; a test that is off by a constant 5 but brightens the
  // same way has no temporal error; one that stays put has |dT - dR| = 10 everywhere.
  const ImageRGB8 r0(20, 10, {100, 100, 100}), r1(20, 10, {110, 110, 110});
  const ImageRGB8 t0(20, 10, {105, 105, 105}), t1(20, 10, {115, 115, 115});
  const TemporalScores follows = temporal_scores(r0, r1, t0, t1);
  EXPECT_NEAR(follows.temporal_error, 0.0, 1e-9);
  EXPECT_EQ(follows.static_pixels, 0);
  EXPECT_EQ(follows.static_flicker, 0.0);
  const TemporalScores lags = temporal_scores(r0, r1, t0, t0);
  EXPECT_NEAR(lags.temporal_error, 10.0, 1e-9);
  // The threshold makes a 10-level change count as static.
  EXPECT_EQ(temporal_scores(r0, r1, t0, t1, 10.0).static_pixels, 200);
}

TEST(Temporal, StaticFlickerOnlyCountsPixelsWhoseReferenceStaysPut) {
  // Left half of the reference changes, right half does not; the test flickers by 4 levels of
  // luma (grey) on the right half only.
  ImageRGB8 r0(10, 4, {50, 50, 50}), r1 = r0, t0 = r0, t1 = r0;
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 5; ++x) r1(x, y) = t1(x, y) = {90, 90, 90};
  for (int y = 0; y < 4; ++y)
    for (int x = 5; x < 10; ++x) t1(x, y) = {54, 54, 54};
  const TemporalScores s = temporal_scores(r0, r1, t0, t1);
  EXPECT_EQ(s.static_pixels, 20);
  EXPECT_NEAR(s.static_flicker, 4.0, 1e-9);
  EXPECT_NEAR(s.temporal_error, 2.0, 1e-9);  // 4 levels on half of the pixels
  TemporalRun run;
  run.add(s);
  run.add(temporal_scores(r0, r0, t0, t0));  // a step with 40 static pixels and no flicker
  EXPECT_NEAR(run.static_flicker(), 4.0 * 20 / 60, 1e-12);
  EXPECT_NEAR(run.temporal_error(), 1.0, 1e-12);
  EXPECT_EQ(run.static_pixels(), 60);
}

TEST(Temporal, BadInputIsAnError) {
  const ImageRGB8 a(8, 8), b(8, 9);
  EXPECT_THROW(temporal_scores(a, a, a, b), Error);
  EXPECT_THROW(temporal_scores(a, b, a, a), Error);
  EXPECT_THROW(temporal_scores(ImageRGB8(), ImageRGB8(), ImageRGB8(), ImageRGB8()), Error);
  EXPECT_THROW(temporal_scores(a, a, a, a, -1.0), Error);
  EXPECT_THROW(temporal_scores(a, a, a, a, std::nan("")), Error);
  EXPECT_EQ(TemporalRun().temporal_error(), 0.0);
}

TEST(Temporal, SameBitsAsOneSequentialLoop) {
  // Sizes around the vectors of 4 and the chunks of 512 pixels; images that share regions
  // (static pixels) and differ by noise elsewhere.
  const int sizes[][2] = {{1, 1}, {3, 1}, {5, 3}, {513, 1}, {37, 29}, {1280, 720}};
  uint64_t seed = 7;
  for (const auto& sz : sizes) {
    const int w = sz[0], h = sz[1];
    auto image = [&](uint64_t s, int keep_from) {
      ImageRGB8 im(w, h);
      for (int i = 0; i < w * h; ++i) {
        const bool shared = i >= keep_from;
        const uint64_t k = shared ? 1 : s;
        im[size_t(i)] = {uint8_t(rng_uniform({k, uint32_t(i), 0, 0, 9}) * 256),
                         uint8_t(rng_uniform({k, uint32_t(i), 1, 0, 9}) * 256),
                         uint8_t(rng_uniform({k, uint32_t(i), 2, 0, 9}) * 256)};
      }
      return im;
    };
    const int half = w * h / 2;
    const ImageRGB8 rp = image(seed++, half), r = image(seed++, half), tp = image(seed++, w * h / 3),
                    t = image(seed++, w * h);
    for (double threshold : {0.0, 0.5, 20.0}) {
      const TemporalScores got = temporal_scores(rp, r, tp, t, threshold);
      const TemporalScores want = test::temporal_scores_one_loop(rp, r, tp, t, threshold);
      EXPECT_EQ(std::bit_cast<uint64_t>(got.temporal_error), std::bit_cast<uint64_t>(want.temporal_error))
          << w << "x" << h << " threshold " << threshold;
      EXPECT_EQ(std::bit_cast<uint64_t>(got.static_flicker), std::bit_cast<uint64_t>(want.static_flicker))
          << w << "x" << h << " threshold " << threshold;
      EXPECT_EQ(got.static_pixels, want.static_pixels) << w << "x" << h;
      if (w * h > 1 && threshold == 0.0) {
        EXPECT_GT(got.static_pixels, 0) << "the test has static pixels";
      }
    }
  }
}

}  // namespace
}  // namespace dhr
