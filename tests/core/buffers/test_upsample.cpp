// Reduced-resolution passes (core/buffers/upsample.h): the sampled G-buffer, and the client's upsampling
// on analytic G-buffers: exact on one surface, no bleeding across a silhouette where bilinear
// bleeds, refusals, and the same bytes at any thread count.
#include "core/buffers/upsample.h"

#include "core/base/error.h"
#include "tests/support.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>

namespace dhr {
namespace {

using test::error_of;

// A camera at the origin looking down -z at two planes facing it: z = -near_m where x < split
// (object 1), z = -far_m elsewhere (object 2); every pixel moved by (1.5, -0.5) since the
// previous frame.
GBuffer two_planes(int w, int h, float split_x, float near_m = 2.0f, float far_m = 5.0f) {
  GBuffer g;
  g.camera = Camera::look_at({0, 0, 0}, {0, 0, -1}, {0, 1, 0}, 60.0f, w, h, 0.05f, 100.0f);
  g.resize(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const Ray r = g.camera.primary_ray(float(x) + 0.5f, float(y) + 0.5f);
      const bool near = float(x) + 0.5f < split_x;
      const float d = near ? near_m : far_m;
      const float t = d / -r.direction.z;
      g.position(x, y) = r.origin + t * r.direction;
      g.depth(x, y) = d;
      g.normal(x, y) = g.geo_normal(x, y) = {0, 0, 1};
      g.object_id(x, y) = near ? 1 : 2;
      g.motion(x, y) = {1.5f, -0.5f};
    }
  return g;
}

PassBuffer ao_of(const GBuffer& g, int scale, uint8_t (*value)(const GBuffer&, int, int)) {
  PassBuffer b;
  b.desc = {PassKind::Ao, reduced_size(g.width(), scale), reduced_size(g.height(), scale), 1, 255};
  b.bytes.resize(b.desc.byte_size());
  for (int y = 0; y < b.desc.height; ++y)
    for (int x = 0; x < b.desc.width; ++x)
      b.bytes[size_t(y * b.desc.width + x)] = value(g, sample_of(x, scale, g.width()), sample_of(y, scale, g.height()));
  return b;
}

uint8_t by_object(const GBuffer& g, int x, int y) { return g.object_id(x, y) == 1 ? 40 : 210; }

TEST(Upsample, SizesAndScales) {
  EXPECT_EQ(reduced_size(320, 2), 160);
  EXPECT_EQ(reduced_size(321, 2), 161);
  EXPECT_EQ(reduced_size(180, 4), 45);
  EXPECT_EQ(sample_of(0, 2, 320), 1);
  EXPECT_EQ(sample_of(160, 2, 321), 320) << "the last sample is clamped into the image";
  EXPECT_EQ(pass_scale(320, 180, 320, 180), 1);
  EXPECT_EQ(pass_scale(320, 180, 160, 90), 2);
  EXPECT_EQ(pass_scale(320, 180, 80, 45), 4);
  EXPECT_EQ(pass_scale(321, 181, 161, 91), 2);
  EXPECT_EQ(pass_scale(320, 180, 100, 90), 0);
  EXPECT_EQ(pass_scale(320, 180, 160, 45), 0);
}

TEST(Upsample, DownsampledGBufferSamplesItsPixelsAndScalesMotion) {
  const GBuffer g = two_planes(37, 21, 15.0f);
  for (int scale : {2, 3, 4}) {
    const GBuffer low = downsample_gbuffer(g, scale);
    ASSERT_EQ(low.width(), reduced_size(37, scale));
    ASSERT_EQ(low.height(), reduced_size(21, scale));
    EXPECT_EQ(low.camera.width, low.width());
    EXPECT_EQ(low.camera.height, low.height());
    for (int y = 0; y < low.height(); ++y)
      for (int x = 0; x < low.width(); ++x) {
        const int sx = sample_of(x, scale, 37), sy = sample_of(y, scale, 21);
        EXPECT_EQ(low.object_id(x, y), g.object_id(sx, sy));
        EXPECT_EQ(low.depth(x, y), g.depth(sx, sy));
        EXPECT_EQ(low.position(x, y), g.position(sx, sy));
        // Inside the image the sample sits where low-res coordinates put its centre: the motion
        // is the full-res motion over the scale.
        if (sx == x * scale + scale / 2 && sy == y * scale + scale / 2) {
          EXPECT_FLOAT_EQ(low.motion(x, y).x, 1.5f / float(scale));
          EXPECT_FLOAT_EQ(low.motion(x, y).y, -0.5f / float(scale));
        }
      }
  }
  EXPECT_EQ(downsample_gbuffer(g, 1).position.pixels(), g.position.pixels());
  EXPECT_NE(error_of([&] { (void)downsample_gbuffer(g, 0); }), "");
  EXPECT_NE(error_of([&] { (void)downsample_gbuffer(g, kMaxPassScale + 1); }), "");
}

TEST(Upsample, JointBilateralKeepsEachSurfaceItsOwnWhereBilinearBleeds) {
  for (int scale : {2, 4}) {
    const GBuffer g = two_planes(96, 54, 45.0f);  // the silhouette between two samples at both scales
    const PassBuffer low = ao_of(g, scale, by_object);
    const PassBuffer jb = upsample_pass(low, g, scale, UpsampleFilter::JointBilateral);
    const PassBuffer bl = upsample_pass(low, g, scale, UpsampleFilter::Bilinear);
    ASSERT_EQ(jb.desc.width, 96);
    ASSERT_EQ(jb.desc.height, 54);
    ASSERT_EQ(jb.bytes.size(), size_t(96 * 54));
    int bled_jb = 0, bled_bl = 0;
    for (int y = 0; y < 54; ++y)
      for (int x = 0; x < 96; ++x) {
        const uint8_t own = by_object(g, x, y);
        bled_jb += jb.bytes[size_t(y * 96 + x)] != own;
        bled_bl += bl.bytes[size_t(y * 96 + x)] != own;
      }
    EXPECT_EQ(bled_jb, 0) << "scale " << scale;
    EXPECT_GE(bled_bl, 54) << "scale " << scale << ": bilinear mixes the two surfaces along the silhouette";
  }
}

TEST(Upsample, OnOneSurfaceSeenStraightOnJointBilateralIsBilinear) {
  const GBuffer g = two_planes(80, 48, -1.0f);  // one plane
  const PassBuffer low = ao_of(g, 2, [](const GBuffer&, int x, int y) { return uint8_t(x + 2 * y); });
  const PassBuffer jb = upsample_pass(low, g, 2, UpsampleFilter::JointBilateral);
  const PassBuffer bl = upsample_pass(low, g, 2, UpsampleFilter::Bilinear);
  EXPECT_EQ(jb.bytes, bl.bytes);
  // A linear ramp is reproduced within rounding between samples.
  const PassBuffer nearest = upsample_pass(low, g, 2, UpsampleFilter::Nearest);
  int off = 0;
  for (int y = 2; y < 46; ++y)
    for (int x = 2; x < 78; ++x) off += std::abs(int(bl.bytes[size_t(y * 80 + x)]) - (x + 2 * y)) > 1;
  EXPECT_EQ(off, 0);
  EXPECT_NE(nearest.bytes, bl.bytes);
}

TEST(Upsample, ConstantStaysConstantAndScaleOneIsACopy) {
  const GBuffer g = two_planes(50, 30, 20.0f);
  for (UpsampleFilter f : {UpsampleFilter::JointBilateral, UpsampleFilter::Bilinear, UpsampleFilter::Nearest}) {
    const PassBuffer low = ao_of(g, 3, [](const GBuffer&, int, int) { return uint8_t(77); });
    const PassBuffer up = upsample_pass(low, g, 3, f);
    for (uint8_t v : up.bytes) ASSERT_EQ(v, 77) << upsample_filter_name(f);
    const PassBuffer same = ao_of(g, 1, by_object);
    EXPECT_EQ(upsample_pass(same, g, 1, f).bytes, same.bytes);
  }
}

TEST(Upsample, SoftVisibilityPlanesAreUpsampledOneByOne) {
  const GBuffer g = two_planes(64, 40, 31.0f);
  PassBuffer low;
  low.desc = {PassKind::SoftVisibility, 32, 20, 3, 8};
  low.bytes.resize(low.desc.byte_size());
  for (size_t c = 0; c < 3; ++c)
    for (size_t i = 0; i < 32 * 20; ++i) low.bytes[c * 640 + i] = uint8_t(c * 3 + 1);
  const PassBuffer up = upsample_pass(low, g, 2, UpsampleFilter::JointBilateral);
  ASSERT_EQ(up.desc.channels, 3);
  for (size_t c = 0; c < 3; ++c)
    for (size_t i = 0; i < 64 * 40; ++i) ASSERT_EQ(up.bytes[c * 2560 + i], uint8_t(c * 3 + 1));
}

TEST(Upsample, RefusesWhatItCannotUpsample) {
  const GBuffer g = two_planes(64, 40, 31.0f);
  PassBuffer wrong = ao_of(g, 2, by_object);
  EXPECT_NE(error_of([&] { (void)upsample_pass(wrong, g, 4, UpsampleFilter::JointBilateral); }).find("16x10 expected"),
            std::string::npos);
  wrong.bytes.pop_back();
  EXPECT_NE(error_of([&] { (void)upsample_pass(wrong, g, 2, UpsampleFilter::JointBilateral); }), "");
  PassBuffer mask;
  mask.desc = {PassKind::Visibility, 32, 20, 2, 1};
  mask.bytes.resize(mask.desc.byte_size());
  EXPECT_NE(error_of([&] { (void)upsample_pass(mask, g, 2, UpsampleFilter::Bilinear); }).find("visibility"),
            std::string::npos);
  EXPECT_NE(error_of([&] { (void)upsample_filter_of("bicubic"); }).find("joint_bilateral"), std::string::npos);
  EXPECT_EQ(upsample_filter_of(upsample_filter_name(UpsampleFilter::Bilinear)), UpsampleFilter::Bilinear);
}

TEST(Upsample, SameBytesAtAnyThreadCount) {
  const GBuffer g = two_planes(200, 120, 77.0f);
  const PassBuffer low = ao_of(
      g, 4, [](const GBuffer& gb, int x, int y) { return uint8_t((x * 7 + y * 13 + gb.object_id(x, y) * 50) % 256); });
  PassBuffer one, two;
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
    one = upsample_pass(low, g, 4, UpsampleFilter::JointBilateral);
  }
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
    two = upsample_pass(low, g, 4, UpsampleFilter::JointBilateral);
  }
  EXPECT_EQ(one.bytes, two.bytes);
}

}  // namespace
}  // namespace dhr
