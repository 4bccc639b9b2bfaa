// Images, camera and the counter-based random numbers.
#include "core/base/error.h"
#include "core/base/rng.h"
#include "core/buffers/camera.h"
#include "core/buffers/image.h"
#include "core/buffers/image_io.h"
#include "core/buffers/pass_buffer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <set>

namespace dhr {
namespace {

TEST(Image, SizeChecksBeforeAllocating) {
  EXPECT_THROW(ImageF(-1, 4), Error);
  EXPECT_THROW(ImageF(kMaxImageSide + 1, 1), Error);
  EXPECT_THROW(ImageU8(kMaxImageSide, kMaxImageSide), Error);  // area above kMaxImagePixels
  EXPECT_NO_THROW(ImageU8(kMaxImageSide, 4));
}

TEST(Image, IndexingAndViews) {
  ImageU8 img(5, 3, 7);
  img(4, 2) = 9;
  EXPECT_EQ(img[14], 9);
  auto v = img.view().sub(1, 1, 3, 2);
  v(2, 1) = 4;
  EXPECT_EQ(img(3, 2), 4);
  EXPECT_EQ(v.row(0).size(), 3u);
}

TEST(BitImage, SetGetCount) {
  BitImage b(130, 3);
  EXPECT_EQ(b.words_per_row(), 3);
  b.set(0, 0, true);
  b.set(64, 1, true);
  b.set(129, 2, true);
  EXPECT_TRUE(b.get(129, 2));
  EXPECT_FALSE(b.get(128, 2));
  EXPECT_EQ(b.count_set(), 3u);
  b.set(64, 1, false);
  EXPECT_EQ(b.count_set(), 2u);
}

TEST(ImageIo, PngAndExrRoundTrip) {
  const auto dir = std::filesystem::temp_directory_path() / "dhr_test_image_io";
  ImageRGB8 rgb(7, 5);
  for (int y = 0; y < 5; ++y)
    for (int x = 0; x < 7; ++x) rgb(x, y) = {uint8_t(x * 30), uint8_t(y * 50), uint8_t(x + y)};
  write_png((dir / "a.png").string(), rgb);
  EXPECT_EQ(read_rgb8((dir / "a.png").string()), rgb);
  ImageF f(3, 2, 0.25f);
  write_exr((dir / "f.exr").string(), f);
  EXPECT_TRUE(std::filesystem::exists(dir / "f.exr"));
  EXPECT_THROW(read_rgb8((dir / "missing.png").string()), Error);
  EXPECT_THROW(write_png((dir / "e.png").string(), ImageU8()), Error);
  std::filesystem::remove_all(dir);
}

TEST(Camera, ProjectInvertsPrimaryRay) {
  Camera c = Camera::look_at({1, 2, 3}, {0, 0, -5}, {0, 1, 0}, 50.0f, 320, 200, 0.1f, 100.0f);
  for (float px : {0.5f, 100.25f, 319.5f})
    for (float py : {0.5f, 77.0f, 199.5f}) {
      Ray r = c.primary_ray(px, py);
      glm::vec3 p = r.origin + 7.0f * r.direction;
      glm::vec3 q = c.project(p);
      EXPECT_NEAR(q.x, px, 1e-3);
      EXPECT_NEAR(q.y, py, 1e-3);
      EXPECT_NEAR(q.z, c.view_depth(p), 1e-4);
    }
}

TEST(Camera, MatricesAgreeWithProject) {
  Camera c = Camera::look_at({0, 1, 0}, {3, 1, -4}, {0, 1, 0}, 70.0f, 640, 360, 0.05f, 50.0f);
  glm::vec3 p{2.0f, 1.7f, -6.0f};
  glm::vec4 clip = c.view_projection() * glm::vec4(p, 1.0f);
  glm::vec2 ndc = glm::vec2(clip) / clip.w;
  glm::vec3 q = c.project(p);
  EXPECT_NEAR((ndc.x + 1) * 0.5f * 640, q.x, 1e-2);
  EXPECT_NEAR((1 - ndc.y) * 0.5f * 360, q.y, 1e-2);
  EXPECT_NEAR(clip.w, q.z, 1e-4);  // clip w = linear view depth
}

TEST(Camera, BadInputRejected) {
  EXPECT_THROW(Camera::look_at({0, 0, 0}, {0, 0, 0}, {0, 1, 0}, 60, 8, 8, 0.1f, 10), Error);
  EXPECT_THROW(Camera::look_at({0, 0, 0}, {0, 0, -1}, {0, 1, 0}, 180, 8, 8, 0.1f, 10), Error);
  EXPECT_THROW(Camera::look_at({0, 0, 0}, {0, 0, -1}, {0, 1, 0}, 60, 8, 8, 1.0f, 0.5f), Error);
  EXPECT_THROW(Camera::look_at({NAN, 0, 0}, {0, 0, -1}, {0, 1, 0}, 60, 8, 8, 0.1f, 10), Error);
  // Looking straight up still gives an orthonormal frame.
  Camera c = Camera::look_at({0, 0, 0}, {0, 5, 0}, {0, 1, 0}, 60, 8, 8, 0.1f, 10);
  EXPECT_NEAR(glm::dot(c.forward, c.up), 0.0f, 1e-6);
  EXPECT_NEAR(glm::length(c.up), 1.0f, 1e-6);
}

TEST(Rng, DeterministicAndKeySensitive) {
  RngKey k{42, 1000, 7, 3, kStreamAo};
  EXPECT_EQ(rng_bits(k), rng_bits(k));
  std::set<uint64_t> seen;
  seen.insert(rng_bits(k));
  RngKey a = k;
  a.seed = 43;
  seen.insert(rng_bits(a));
  RngKey b = k;
  b.pixel = 1001;
  seen.insert(rng_bits(b));
  RngKey c = k;
  c.frame = 8;
  seen.insert(rng_bits(c));
  RngKey d = k;
  d.sample = 4;
  seen.insert(rng_bits(d));
  RngKey e = k;
  e.stream = kStreamLightBase;
  seen.insert(rng_bits(e));
  seen.insert(rng_bits(k, 1));
  EXPECT_EQ(seen.size(), 7u);
}

TEST(Rng, UniformMomentsAndRange) {
  // Mean 1/2 and variance 1/12 within 5 standard errors over 200k keys.
  const int n = 200000;
  double sum = 0, sum2 = 0;
  float lo = 1, hi = 0;
  for (int i = 0; i < n; ++i) {
    float u = rng_uniform({1, uint32_t(i), 0, 0, kStreamAo});
    lo = std::min(lo, u);
    hi = std::max(hi, u);
    sum += u;
    sum2 += double(u) * u;
  }
  const double mean = sum / n, var = sum2 / n - mean * mean;
  EXPECT_GE(lo, 0.0f);
  EXPECT_LT(hi, 1.0f);
  EXPECT_NEAR(mean, 0.5, 5 * std::sqrt(1.0 / 12 / n));
  EXPECT_NEAR(var, 1.0 / 12, 0.002);
}

TEST(Rng, NeighbouringPixelsUncorrelated) {
  // Correlation between u(pixel) and u(pixel + 1) stays near zero.
  const int n = 100000;
  double sxy = 0, sx = 0, sy = 0, sxx = 0, syy = 0;
  for (int i = 0; i < n; ++i) {
    double x = rng_uniform({5, uint32_t(i), 2, 0, 1});
    double y = rng_uniform({5, uint32_t(i + 1), 2, 0, 1});
    sxy += x * y;
    sx += x;
    sy += y;
    sxx += x * x;
    syy += y * y;
  }
  const double cov = sxy / n - sx / n * sy / n;
  const double corr = cov / std::sqrt((sxx / n - sx * sx / n / n) * (syy / n - sy * sy / n / n));
  EXPECT_LT(std::abs(corr), 0.02);
}

TEST(PassDesc, SizesAndValidation) {
  EXPECT_EQ((PassDesc{PassKind::Visibility, 10, 10, 9, 1}.byte_size()), 200u);
  EXPECT_EQ((PassDesc{PassKind::SoftVisibility, 10, 10, 3, 255}.byte_size()), 300u);
  EXPECT_EQ((PassDesc{PassKind::Colour, 10, 10, 3, 255}.byte_size()), 300u);
  EXPECT_TRUE((PassDesc{PassKind::Visibility, 10, 10, 64, 1}.validate().empty()));
  EXPECT_FALSE((PassDesc{PassKind::Visibility, 10, 10, 65, 1}.validate().empty()));
  EXPECT_FALSE((PassDesc{PassKind::Ao, -1, 10, 1, 8}.validate().empty()));
  EXPECT_FALSE((PassDesc{PassKind::Ao, 10, 10, 1, 0}.validate().empty()));
}

}  // namespace
}  // namespace dhr
