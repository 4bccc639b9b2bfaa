// SSIM / PSNR as the benchmark scores frames: checked against OpenCV's quality module (the
// mirrored convention), scikit-image (the valid-interior reference convention) and
// closed-form cases.
#include "core/base/error.h"
#include "core/base/rng.h"
#include "core/metrics/metrics.h"

#include <gtest/gtest.h>
#include <opencv2/quality/qualityssim.hpp>
#include <tbb/global_control.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

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
  EXPECT_EQ(m(3, 3), m(9, 50));  // saturated value = right end of the bar
  EXPECT_EQ(m(0, 0), m(0, 50));  // zero = left end of the bar
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

// The reference convention against scikit-image itself: tests/ssim_reference.py runs
// skimage.metrics.structural_similarity (gaussian_weights=True, sigma=1.5,
// use_sample_covariance=False, data_range=255) on the same planes; they must agree to 1e-4. A
// missing scikit-image fails the test (scripts/setup.sh installs it).
namespace dhr {
namespace {

void write_pair(const std::string& path, int w, int h, int c, const uint8_t* a, const uint8_t* b) {
  std::ofstream f(path, std::ios::binary);
  const int32_t header[3] = {w, h, c};  // little-endian on every machine the project builds on
  f.write(reinterpret_cast<const char*>(header), sizeof header);
  f.write(reinterpret_cast<const char*>(a), std::streamsize(size_t(w) * h * c));
  f.write(reinterpret_cast<const char*>(b), std::streamsize(size_t(w) * h * c));
  ASSERT_TRUE(f.good()) << path;
}

// Runs the reference script on the pair files; one value per file, in order.
std::vector<double> skimage_ssim(const std::vector<std::string>& files) {
  std::string cmd = "/usr/bin/python3 " + std::string(DHR_SOURCE_DIR) + "/tests/ssim_reference.py";
  for (const auto& f : files) cmd += " " + f;
  cmd += " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return {};
  std::string out;
  char buf[256];
  while (fgets(buf, sizeof buf, p)) out += buf;
  const int rc = pclose(p);
  EXPECT_EQ(rc, 0) << "reference script failed: " << out;
  std::vector<double> values;
  std::istringstream in(out);
  for (double v; in >> v;) values.push_back(v);
  EXPECT_EQ(values.size(), files.size()) << out;
  return values;
}

ImageRGB8 shifted(const ImageRGB8& a, int dx) {
  ImageRGB8 out(a.width(), a.height());
  for (int y = 0; y < a.height(); ++y)
    for (int x = 0; x < a.width(); ++x) out(x, y) = a(std::clamp(x + dx, 0, a.width() - 1), y);
  return out;
}

ImageRGB8 noisy(const ImageRGB8& a, float amplitude, uint64_t seed) {
  ImageRGB8 out = a;
  for (size_t i = 0; i < out.size(); ++i) {
    auto add = [&](uint8_t v, uint32_t c) {
      const float n = rng_uniform({seed, uint32_t(i), c, 0, 11}) - 0.5f;
      return uint8_t(std::clamp(float(v) + 2 * amplitude * n, 0.0f, 255.0f));
    };
    out[i] = {add(out[i].r, 0), add(out[i].g, 1), add(out[i].b, 2)};
  }
  return out;
}

TEST(Metrics, ValidSsimMatchesScikitImage) {
  struct Pair {
    ImageRGB8 a, b;
  };
  std::vector<Pair> pairs;
  pairs.push_back({test_image(97, 61, 2), test_image(97, 61, 3)});                // independent
  pairs.push_back({test_image(128, 72, 4), shifted(test_image(128, 72, 4), 2)});  // a 2-pixel shift
  pairs.push_back({test_image(64, 48, 5), noisy(test_image(64, 48, 5), 12, 1)});  // added noise
  pairs.push_back({test_image(11, 11, 6), test_image(11, 11, 7)});                // one window exactly
  pairs.push_back({test_image(200, 13, 8), noisy(test_image(200, 13, 8), 40, 2)});
  const std::string dir = ::testing::TempDir();
  std::vector<std::string> files;
  std::vector<double> ours;
  for (size_t k = 0; k < pairs.size(); ++k) {
    const Pair& p = pairs[k];
    const ImageU8 la = luma(p.a), lb = luma(p.b);
    files.push_back(dir + "/ssim_pair_" + std::to_string(k) + "_luma.bin");
    write_pair(files.back(), la.width(), la.height(), 1, la.data(), lb.data());
    ours.push_back(compare_images(p.a, p.b, SsimChannel::Luma, nullptr, SsimBorder::Valid).ssim);
    EXPECT_EQ(ours.back(), ssim_u8(la, lb, nullptr, SsimBorder::Valid));
    files.push_back(dir + "/ssim_pair_" + std::to_string(k) + "_rgb.bin");
    write_pair(files.back(), p.a.width(), p.a.height(), 3, &p.a.data()->r, &p.b.data()->r);
    ours.push_back(compare_images(p.a, p.b, SsimChannel::RgbMean, nullptr, SsimBorder::Valid).ssim);
  }
  const std::vector<double> ref = skimage_ssim(files);
  ASSERT_EQ(ref.size(), ours.size());
  double worst = 0;
  for (size_t i = 0; i < ref.size(); ++i) {
    EXPECT_NEAR(ours[i], ref[i], 1e-4) << files[i];
    EXPECT_LT(ours[i], 0.999) << files[i];  // every pair differs
    worst = std::max(worst, std::abs(ours[i] - ref[i]));
  }
  std::printf("largest |dhrbench - scikit-image| over %zu SSIM values: %.3g\n", ref.size(), worst);
  // The two conventions do differ on these pairs (otherwise the comparison would prove nothing
  // about the choice of pixels averaged).
  EXPECT_GT(std::abs(compare_images(pairs[1].a, pairs[1].b).ssim - ours[2]), 1e-3);
}

TEST(Metrics, ValidSsimMapIsTheMirroredMapAndIdenticalScoresOne) {
  // The map does not depend on the convention (only the averaged pixels do).
  const ImageRGB8 a = test_image(40, 30, 9), b = test_image(40, 30, 10);
  ImageF m1, m2;
  const double valid = compare_images(a, b, SsimChannel::Luma, &m1, SsimBorder::Valid).ssim;
  compare_images(a, b, SsimChannel::Luma, &m2, SsimBorder::Mirrored);
  EXPECT_EQ(m1, m2);
  double sum = 0;
  for (int y = 5; y < 25; ++y)
    for (int x = 5; x < 35; ++x) sum += m1(x, y);
  EXPECT_NEAR(valid, sum / (30.0 * 20.0), 1e-6);
  EXPECT_EQ(valid, compare_images(a, b, SsimChannel::Luma, nullptr, SsimBorder::Valid).ssim);
  EXPECT_EQ(compare_images(a, a, SsimChannel::Luma, nullptr, SsimBorder::Valid).ssim, 1.0);
  EXPECT_EQ(compare_images(a, a, SsimChannel::RgbMean, nullptr, SsimBorder::Valid).ssim, 1.0);
}

// The two-pass SSIM as it was computed before the fused version of core/metrics/metrics.cpp (one
// horizontal pass over the whole image into five interleaved planes, then one vertical pass):
// the definition of the bits the fused version must reproduce.
double two_pass_ssim(const ImageU8& ia, const ImageU8& ib, ImageF* map, SsimBorder border) {
  constexpr int kRadius = 5;
  constexpr double kC1 = (0.01 * 255) * (0.01 * 255);
  constexpr double kC2 = (0.03 * 255) * (0.03 * 255);
  const int w = ia.width(), h = ia.height();
  std::vector<float> fa(ia.pixels().begin(), ia.pixels().end()), fb(ib.pixels().begin(), ib.pixels().end());
  const float* a = fa.data();
  const float* b = fb.data();
  std::array<float, 2 * kRadius + 1> g{};
  double gsum = 0;
  for (int i = -kRadius; i <= kRadius; ++i) gsum += std::exp(-(i * i) / (2.0 * 1.5 * 1.5));
  for (int i = -kRadius; i <= kRadius; ++i)
    g[size_t(i + kRadius)] = float(std::exp(-(i * i) / (2.0 * 1.5 * 1.5)) / gsum);
  auto reflect101 = [](int i, int n) {
    if (n == 1) return 0;
    while (i < 0 || i >= n) {
      if (i < 0) i = -i;
      if (i >= n) i = 2 * n - 2 - i;
    }
    return i;
  };
  const bool valid = border == SsimBorder::Valid;
  const int x0 = valid && !map ? kRadius : 0, x1 = valid && !map ? w - kRadius : w;
  const int y0 = valid && !map ? kRadius : 0, y1 = valid && !map ? h - kRadius : h;
  std::vector<float> hz(size_t(w) * h * 5);
  for (int y = 0; y < h; ++y) {
    const float* ra = a + size_t(y) * w;
    const float* rb = b + size_t(y) * w;
    float* out = &hz[size_t(y) * w * 5];
    for (int x = x0; x < x1; ++x) {
      float s[5] = {0, 0, 0, 0, 0};
      for (int k = -kRadius; k <= kRadius; ++k) {
        const int xx = reflect101(x + k, w);
        const float wa = ra[xx], wb = rb[xx], gk = g[size_t(k + kRadius)];
        s[0] += gk * wa;
        s[1] += gk * wb;
        s[2] += gk * wa * wa;
        s[3] += gk * wb * wb;
        s[4] += gk * wa * wb;
      }
      for (int c = 0; c < 5; ++c) out[x * 5 + c] = s[c];
    }
  }
  std::vector<double> row_sums(size_t(h), 0.0);
  if (map) map->resize(w, h);
  for (int y = y0; y < y1; ++y) {
    double row = 0;
    for (int x = x0; x < x1; ++x) {
      double s[5] = {0, 0, 0, 0, 0};
      for (int k = -kRadius; k <= kRadius; ++k) {
        const float* p = &hz[(size_t(reflect101(y + k, h)) * w + x) * 5];
        const double gk = g[size_t(k + kRadius)];
        for (int c = 0; c < 5; ++c) s[c] += gk * p[c];
      }
      const double mu_a = s[0], mu_b = s[1];
      const double var_a = std::max(0.0, s[2] - mu_a * mu_a);
      const double var_b = std::max(0.0, s[3] - mu_b * mu_b);
      const double bound = std::sqrt(var_a * var_b);
      const double cov = std::clamp(s[4] - mu_a * mu_b, -bound, bound);
      const double v =
          ((2 * mu_a * mu_b + kC1) * (2 * cov + kC2)) / ((mu_a * mu_a + mu_b * mu_b + kC1) * (var_a + var_b + kC2));
      if (map) (*map)(x, y) = float(v);
      if (!valid || (x >= kRadius && x < w - kRadius)) row += v;
    }
    row_sums[size_t(y)] = row;
  }
  double total = 0;
  if (!valid) {
    for (double r : row_sums) total += r;
    return total / (double(w) * h);
  }
  for (int y = kRadius; y < h - kRadius; ++y) total += row_sums[size_t(y)];
  return total / (double(w - 2 * kRadius) * double(h - 2 * kRadius));
}

TEST(Metrics, SsimIsBitIdenticalToTheTwoPassDefinition) {
  // Sizes: narrower and shorter than a window, odd, around the fused pass's 32-row bands and
  // 256-column blocks, and a full frame.
  const int sizes[][2] = {{1, 1}, {3, 7}, {9, 4}, {11, 11}, {12, 33}, {37, 29}, {257, 65}, {300, 97}, {1280, 720}};
  uint64_t seed = 1;
  for (const auto& sz : sizes) {
    const int w = sz[0], h = sz[1];
    const ImageRGB8 a = test_image(w, h, seed++), b = test_image(w, h, seed++);
    const ImageU8 la = luma(a), lb = luma(b);
    for (SsimBorder border : {SsimBorder::Mirrored, SsimBorder::Valid}) {
      if (border == SsimBorder::Valid && (w < 11 || h < 11)) continue;
      for (bool with_map : {false, true}) {
        ImageF map, ref_map;
        const double got = ssim_u8(la, lb, with_map ? &map : nullptr, border);
        const double want = two_pass_ssim(la, lb, with_map ? &ref_map : nullptr, border);
        EXPECT_EQ(std::memcmp(&got, &want, sizeof got), 0)
            << w << "x" << h << " map " << with_map << ": " << got << " vs " << want;
        if (with_map) {
          ASSERT_EQ(map.size(), ref_map.size());
          EXPECT_EQ(std::memcmp(map.data(), ref_map.data(), map.size() * sizeof(float)), 0) << w << "x" << h;
        }
      }
    }
  }
}

// luma() rounds with a truncation of x + 0.5 where it called std::lround: the same integer for
// every (r, g, b), all 2^24 of them.
TEST(Metrics, LumaRoundsAsLround) {
  ImageRGB8 img(256, 256);
  for (int r = 0; r < 256; ++r) {
    for (int g = 0; g < 256; ++g)
      for (int b = 0; b < 256; ++b) img(b, g) = {uint8_t(r), uint8_t(g), uint8_t(b)};
    const ImageU8 l = luma(img);
    int bad = 0;
    for (int g = 0; g < 256; ++g)
      for (int b = 0; b < 256; ++b) bad += l(b, g) != uint8_t(std::lround(0.299 * r + 0.587 * g + 0.114 * b));
    ASSERT_EQ(bad, 0) << "r = " << r;
  }
}

TEST(Metrics, ValidSsimRefusesImagesSmallerThanOneWindow) {
  const std::string msg = [] {
    try {
      compare_images(ImageRGB8(10, 40), ImageRGB8(10, 40), SsimChannel::Luma, nullptr, SsimBorder::Valid);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  }();
  EXPECT_NE(msg.find("11x11"), std::string::npos) << msg;
  EXPECT_NE(msg.find("10x40"), std::string::npos) << msg;
  EXPECT_THROW(ssim_u8(ImageU8(40, 3), ImageU8(40, 3), nullptr, SsimBorder::Valid), Error);
  EXPECT_NO_THROW(ssim_u8(ImageU8(40, 3), ImageU8(40, 3), nullptr, SsimBorder::Mirrored));
}

}  // namespace
}  // namespace dhr
