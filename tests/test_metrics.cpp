// SSIM / PSNR as the benchmark scores frames: checked against OpenCV's quality module and
// against closed-form cases.
#include "core/error.h"
#include "core/metrics.h"
#include "core/rng.h"

#include <gtest/gtest.h>
#include <opencv2/quality/qualityssim.hpp>
#include <tbb/global_control.h>

#include <cmath>

namespace dhr {
namespace {

ImageRGB8 test_image(int w, int h, uint64_t seed) {
  ImageRGB8 img(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float n = rng_uniform({seed, uint32_t(y * w + x), 0, 0, 9});
      const float base = 128 + 100 * std::sin(x * 0.15f) * std::cos(y * 0.11f);
      img(x, y) = {uint8_t(std::clamp(base + 40 * (n - 0.5f), 0.0f, 255.0f)), uint8_t((x * 3 + y) & 255),
                   uint8_t(std::clamp(255 - base, 0.0f, 255.0f))};
    }
  return img;
}

TEST(Metrics, IdenticalImages) {
  ImageRGB8 a = test_image(40, 30, 1);
  QualityScores q = compare_images(a, a);
  EXPECT_DOUBLE_EQ(q.ssim, 1.0);
  EXPECT_TRUE(std::isinf(q.psnr_db));
  EXPECT_EQ(q.mean_abs_error, 0.0);
}

TEST(Metrics, PsnrClosedForm) {
  ImageRGB8 a(16, 16, {100, 100, 100}), b(16, 16, {101, 101, 101});
  EXPECT_NEAR(psnr_db(a, b), 10 * std::log10(255.0 * 255.0), 1e-9);  // MSE = 1
}

TEST(Metrics, SsimMatchesOpenCvQualityModule) {
  const ImageRGB8 a = test_image(97, 61, 2), b = test_image(97, 61, 3);
  const ImageU8 la = luma(a), lb = luma(b);
  cv::Mat ma(la.height(), la.width(), CV_8UC1, const_cast<uint8_t*>(la.data()));
  cv::Mat mb(lb.height(), lb.width(), CV_8UC1, const_cast<uint8_t*>(lb.data()));
  const double cv_ssim = cv::quality::QualitySSIM::compute(ma, mb, cv::noArray())[0];
  const double ours = ssim_u8(la, lb);
  EXPECT_LT(ours, 0.99);  // the images do differ
  EXPECT_NEAR(ours, cv_ssim, 1e-4);
  EXPECT_NEAR(compare_images(a, b).ssim, ours, 1e-12);
}

TEST(Metrics, SsimRgbMeanAveragesChannels) {
  const ImageRGB8 a = test_image(33, 20, 4), b = test_image(33, 20, 5);
  double sum = 0;
  for (int c = 0; c < 3; ++c) {
    ImageU8 pa(33, 20), pb(33, 20);
    for (size_t i = 0; i < pa.size(); ++i) {
      pa[i] = c == 0 ? a[i].r : c == 1 ? a[i].g : a[i].b;
      pb[i] = c == 0 ? b[i].r : c == 1 ? b[i].g : b[i].b;
    }
    sum += ssim_u8(pa, pb);
  }
  EXPECT_NEAR(compare_images(a, b, SsimChannel::RgbMean).ssim, sum / 3, 1e-12);
}

TEST(Metrics, ConstantImagesAndTinyImages) {
  // Zero variance on both sides: SSIM is defined through the constants, no NaN.
  ImageRGB8 a(5, 3, {10, 10, 10}), b(5, 3, {200, 200, 200});
  const QualityScores q = compare_images(a, b);
  EXPECT_TRUE(std::isfinite(q.ssim));
  EXPECT_LT(q.ssim, 0.1);
  ImageRGB8 one(1, 1, {7, 7, 7});
  EXPECT_DOUBLE_EQ(compare_images(one, one).ssim, 1.0);
}

TEST(Metrics, SizeMismatchAndEmptyAreErrors) {
  EXPECT_THROW(compare_images(ImageRGB8(4, 4), ImageRGB8(4, 5)), Error);
  EXPECT_THROW(compare_images(ImageRGB8(), ImageRGB8()), Error);
}

TEST(Metrics, IndependentOfThreadCount) {
  const ImageRGB8 a = test_image(120, 80, 6), b = test_image(120, 80, 7);
  double one, two;
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
    one = compare_images(a, b).ssim;
  }
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
    two = compare_images(a, b).ssim;
  }
  EXPECT_EQ(one, two);
}

TEST(Metrics, ErrorMapHasColourBarAndFixedScale) {
  ImageF e(10, 48, 0.0f);
  e(3, 3) = 100.0f;
  ImageRGB8 m = error_map(e, 10.0f);
  EXPECT_EQ(m.height(), 48 + 4);
  EXPECT_EQ(m(3, 3), m(9, 50));   // saturated value = right end of the bar
  EXPECT_EQ(m(0, 0), m(0, 50));   // zero = left end of the bar
}

}  // namespace
}  // namespace dhr

namespace dhr {
namespace {
TEST(Metrics, IdenticalFlatAndDarkImagesScoreExactlyOne) {
  // Rounding in the local moments of flat regions once gave 0.99997 for identical images.
  ImageRGB8 a(64, 36);
  for (int y = 0; y < 36; ++y)
    for (int x = 0; x < 64; ++x) a(x, y) = x < 32 ? Rgb8{13, 13, 13} : Rgb8{uint8_t(200 + (y & 1)), 90, 7};
  EXPECT_EQ(compare_images(a, a).ssim, 1.0);
  EXPECT_EQ(compare_images(a, a, SsimChannel::RgbMean).ssim, 1.0);
}
}  // namespace
}  // namespace dhr
