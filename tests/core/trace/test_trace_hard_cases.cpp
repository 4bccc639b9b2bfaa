// Numerically hard cases for the server's tracing (the rules are in core/trace/trace.h): surfaces far
// from the origin, large tilted surfaces, grazing lights, degenerate and non-finite triangles,
// lights touching or inside geometry, zero-radius lights, a camera inside geometry, an empty
// view and invalid rays. Every case asserts no NaN, no crash and the documented answer.
#include "core/base/error.h"
#include "core/pass/composite.h"
#include "core/pass/passes.h"
#include "core/scene/shapes.h"
#include "core/trace/rt_scene.h"
#include "core/trace/trace.h"

#include "tests/support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <tuple>
#include <utility>

namespace dhr {
namespace {

constexpr int kW = 48, kH = 32;

using test::make_object;

Scene base_scene() {
  Scene s;
  s.name = "hard_case";
  Material m;
  m.name = "grey";
  m.albedo = glm::vec3(0.5f);
  s.materials.push_back(m);
  s.ambient = glm::vec3(0.2f);
  return s;
}

Light point_light(glm::vec3 p, float radius = 0.0f) { return test::sphere_light(p, radius, 20.0f); }
using test::distant_light;

Camera cam(glm::vec3 pos, glm::vec3 target) {
  return Camera::look_at(pos, target, {0, 1, 0}, 60.0f, kW, kH, 0.05f, 1000.0f);
}

bool bit(const PassBuffer& pb, int light, size_t pixel) {
  const size_t bpp = size_t((pb.desc.channels + 7) / 8);
  return (pb.bytes[pixel * bpp + size_t(light >> 3)] >> (light & 7)) & 1u;
}

size_t covered(const GBuffer& g) {
  size_t n = 0;
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x) n += g.covered(x, y);
  return n;
}

void expect_finite_image(const GBuffer& g, const Scene& s, const TraceResult& r) {
  const ImageRGB8 img = composite(g, s, r.find("visibility"), r.find("ao"));
  EXPECT_EQ(img.width(), g.width());
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x)
      if (g.covered(x, y)) {
        ASSERT_TRUE(std::isfinite(g.depth(x, y)));
        ASSERT_TRUE(std::isfinite(g.position(x, y).x));
      }
}

// A lit plane far from the origin stays fully lit: no shadow acne, no AO self-occlusion.
class FarFromOrigin : public ::testing::TestWithParam<float> {};

TEST_P(FarFromOrigin, LitPlaneStaysFullyLit) {
  const float o = GetParam();
  const glm::vec3 offset(o, o, -o);  // every coordinate large, the normal axis included
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(40.0f, 40.0f), offset));
  s.lights.push_back(point_light(offset + glm::vec3(1, 5, -1)));
  s.lights.push_back(point_light(offset + glm::vec3(-2, 4, 1), 0.5f));
  s.lights.push_back(distant_light({0.3f, 1.0f, 0.2f}, 2.0f));
  s.ao = AoSettings{1.0f, 16};
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam(offset + glm::vec3(0, 3, 4), offset), 0.0);
  const size_t cov = covered(g);
  ASSERT_GT(cov, size_t(kW * kH / 2));
  for (bool soft : {false, true}) {
    TraceSettings ts;
    ts.soft_shadows = soft;
    const TraceResult r = trace_passes(rt, g, ts);
    ASSERT_TRUE(r.find("visibility") && r.find("ao"));
    EXPECT_EQ(r.stats.invalid_rays, 0u);
    size_t lit = 0, ao_full = 0;
    for (size_t i = 0; i < g.depth.size(); ++i) {
      if (g.object_id[i] == kBackgroundId) continue;
      for (int l = 0; l < 3; ++l) lit += bit(*r.find("visibility"), l, i);
      ao_full += r.find("ao")->bytes[i] == 16;
    }
    EXPECT_EQ(lit, 3 * cov) << "offset " << o << (soft ? " soft" : " hard");
    EXPECT_EQ(ao_full, cov) << "offset " << o;
    expect_finite_image(g, s, r);
  }
}

INSTANTIATE_TEST_SUITE_P(Offsets, FarFromOrigin, ::testing::Values(0.0f, 1e5f, 1e6f));

// A lone plane rotated (30, 0, 20) degrees (a scene's rotate_deg: x, then y, then z), 1 m to
// 100 km across, centred on the world origin or far from it, with nothing to occlude it: no
// pixel may be shadowed (hard or soft) or occluded (AO). Embree's intersection error grows with
// the triangle (its edges and normal are rounded to float), not with the hit point, so an
// origin offset scaled by the hit point's coordinates alone would shadow big planes near the
// world origin. Two views: the whole plane, and a close-up of its centre.
class LargeTiltedPlane : public ::testing::TestWithParam<std::tuple<float, float>> {};

TEST_P(LargeTiltedPlane, UnoccludedPlaneIsNeverShadowed) {
  const auto [size, far] = GetParam();
  const glm::vec3 r = glm::radians(glm::vec3(30.0f, 0.0f, 20.0f));
  const glm::quat q = glm::angleAxis(r.z, glm::vec3(0, 0, 1)) * glm::angleAxis(r.y, glm::vec3(0, 1, 0)) *
                      glm::angleAxis(r.x, glm::vec3(1, 0, 0));
  const glm::vec3 centre = glm::vec3(2.0f, 1.0f, -3.0f) * far;
  const glm::vec3 n = q * glm::vec3(0, 1, 0), t = q * glm::vec3(1, 0, 0);
  Mesh plane = make_plane(size, size);
  for (auto& p : plane.positions) p = q * p;
  for (auto& v : plane.normals) v = q * v;
  Scene s = base_scene();
  s.objects.push_back(make_object(1, plane, centre));
  // Every light well above the plane's horizon from every point of it.
  s.lights.push_back(point_light(centre + n * size));
  s.lights.push_back(point_light(centre + (n + 0.3f * t) * size, 0.1f * size));
  s.lights.push_back(distant_light(n + 0.2f * t, 2.0f));
  s.ao = AoSettings{0.1f * size, 16};
  RtScene rt(s);
  const float close = std::min(size, 2.0f);  // the close-up: a few metres around the centre
  for (const float d : {size, close}) {
    const Camera c =
        Camera::look_at(centre + (0.7f * n + 0.5f * t) * d, centre, {0, 1, 0}, 60.0f, kW, kH, 1e-3f * d, 10.0f * d);
    const GBuffer g = rt.primary_gbuffer(c, 0.0);
    const size_t cov = covered(g);
    ASSERT_GT(cov, size_t(kW * kH / 4)) << "size " << size << " view " << d;
    TraceSettings hard, soft;
    hard.soft_shadows = false;
    soft.samples_per_light = 4;
    const TraceResult rh = trace_passes(rt, g, hard), rs = trace_passes(rt, g, soft);
    ASSERT_TRUE(rh.find("visibility") && rs.find("visibility") && rh.find("ao"));
    ASSERT_EQ(rs.find("visibility")->desc.kind, PassKind::SoftVisibility);
    EXPECT_EQ(rh.stats.invalid_rays + rs.stats.invalid_rays, 0u);
    const size_t npx = g.depth.size();
    size_t hard_dark = 0, soft_dark = 0, ao_dark = 0;
    for (size_t i = 0; i < npx; ++i) {
      if (g.object_id[i] == kBackgroundId) continue;
      bool h = false, so = false;
      for (int l = 0; l < 3; ++l) {
        h = h || !bit(*rh.find("visibility"), l, i);
        so = so || rs.find("visibility")->bytes[size_t(l) * npx + i] != 4;
      }
      hard_dark += h;
      soft_dark += so;
      ao_dark += rh.find("ao")->bytes[i] != 16;
    }
    EXPECT_EQ(hard_dark, 0u) << "size " << size << " m, centre " << far << ", view " << d << " m: " << cov << " px";
    EXPECT_EQ(soft_dark, 0u) << "size " << size << " m, centre " << far << ", view " << d << " m: " << cov << " px";
    EXPECT_EQ(ao_dark, 0u) << "size " << size << " m, centre " << far << ", view " << d << " m: " << cov << " px";
  }
}

INSTANTIATE_TEST_SUITE_P(SizesAndPlaces, LargeTiltedPlane,
                         ::testing::Combine(::testing::Values(1.0f, 100.0f, 300.0f, 1e3f, 1e4f, 1e5f),
                                            ::testing::Values(0.0f, 1e5f)));

// A horizontal quad mesh over x in [x0, x1], z in [z0, z1] at height y, facing +y, cut into
// `segments` quads along x (1: two long triangles).
Mesh strip_mesh(float x0, float x1, float z0, float z1, float y, int segments) {
  Mesh m;
  for (int i = 0; i <= segments; ++i) {
    const float x = i == segments ? x1 : x0 + (x1 - x0) * float(i) / float(segments);
    m.positions.push_back({x, y, z1});
    m.positions.push_back({x, y, z0});
  }
  for (int i = 0; i < segments; ++i) {
    const unsigned a = unsigned(2 * i);
    m.triangles.push_back({a, a + 2, a + 3});
    m.triangles.push_back({a, a + 3, a + 1});
  }
  return m;
}

// A 40 m x 3 cm strip (like classroom's wall strips) beside and under a 4 cm high ledge: the
// ledge (a quad at y = 4 cm over z in [-0.5, 0]) occludes part of the strip's AO hemisphere and
// shadows the part of it with z < 1.2 cm from the light. Its two long triangles must give what
// the same strip cut into 3 cm squares gives (Embree's error is tiny for both: the strip is
// axis-aligned). An offset grown with emax^3 / |Ng| (52 mm here) would start the rays above
// the ledge: AO near 1 and no shadow.
TEST(TraceHardCases, LongStripUnderLedge) {
  struct Answer {
    double ao = 0.0;
    size_t shadowed = 0, pixels = 0;
  };
  auto trace = [](int segments) {
    Scene s = base_scene();
    s.objects.push_back(make_object(1, strip_mesh(-20.0f, 20.0f, 0.0f, 0.03f, 0.0f, segments), glm::vec3(0.0f)));
    s.objects.push_back(make_object(2, strip_mesh(-20.0f, 20.0f, -0.5f, 0.0f, 0.04f, 1), glm::vec3(0.0f)));
    s.lights.push_back(point_light({0.0f, 1.0f, -0.3f}));
    s.ao = AoSettings{0.2f, 64};
    RtScene rt(s);
    const GBuffer g = rt.primary_gbuffer(
        Camera::look_at({0.0f, 0.3f, 0.5f}, {0.0f, 0.0f, 0.015f}, {0, 1, 0}, 8.0f, kW, kH, 0.01f, 10.0f), 0.0);
    const TraceResult r = trace_passes(rt, g, TraceSettings{});
    EXPECT_TRUE(r.find("visibility") && r.find("ao"));
    EXPECT_EQ(r.stats.invalid_rays, 0u);
    Answer a;
    for (size_t i = 0; i < g.depth.size(); ++i) {
      if (g.object_id[i] != 1) continue;
      ++a.pixels;
      a.ao += r.find("ao")->bytes[i] / 64.0;
      a.shadowed += !bit(*r.find("visibility"), 0, i);
    }
    a.ao /= double(std::max<size_t>(a.pixels, 1));
    return a;
  };
  const Answer slivers = trace(1), squares = trace(1333);
  std::printf("strip: AO %.3f, %zu of %zu px shadowed (1333 squares: AO %.3f, %zu of %zu)\n", slivers.ao,
              slivers.shadowed, slivers.pixels, squares.ao, squares.shadowed, squares.pixels);
  ASSERT_GT(squares.pixels, 150u);
  EXPECT_NEAR(double(slivers.pixels), double(squares.pixels), 0.02 * double(squares.pixels));
  // The ledge hides a good part of the hemisphere and shadows about 40 % of the strip.
  EXPECT_LT(squares.ao, 0.9);
  EXPECT_GT(squares.shadowed, squares.pixels / 5);
  EXPECT_NEAR(slivers.ao, squares.ao, 0.02) << "two long triangles vs 1333 squares";
  EXPECT_NEAR(double(slivers.shadowed), double(squares.shadowed), 0.02 * double(squares.pixels) + 2.0);
}

// A scene of a 20 m plane (id 1) and an occluder box (id 2) of `box` metres centred `height`
// above it, a point light at `light`, scaled by `scale` and moved by `offset`: the plane's
// shadowed pixels (hard shadows) and its covered ones.
std::pair<size_t, size_t> box_shadow(glm::vec3 offset, float scale, glm::vec3 box, float height, glm::vec3 light) {
  Scene s = base_scene();
  auto place = [&](Mesh m, glm::vec3 at) {
    for (auto& p : m.positions) p = (p + at) * scale + offset;
    return m;
  };
  s.objects.push_back(make_object(1, place(make_plane(20.0f, 20.0f), glm::vec3(0.0f)), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, place(make_box(box), {0.25f, height, 0.0f}), glm::vec3(0.0f)));
  s.lights.push_back(point_light(light * scale + offset));
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(
      Camera::look_at(glm::vec3(0.0f, 4.0f, 6.0f) * scale + offset, glm::vec3(1.0f, 0.0f, 0.0f) * scale + offset,
                      {0, 1, 0}, 40.0f, 160, 120, 0.05f * scale, 1000.0f * scale),
      0.0);
  const TraceResult r = trace_passes(rt, g, TraceSettings{});
  EXPECT_EQ(r.stats.invalid_rays, 0u);
  size_t shadowed = 0, plane = 0;
  for (size_t i = 0; i < g.depth.size(); ++i) {
    if (g.object_id[i] != 1) continue;
    ++plane;
    shadowed += !bit(*r.find("visibility"), 0, i);
  }
  return {shadowed, plane};
}

// A 1 m box 0.25 m above a plane, far from the world origin along the plane's normal and
// along every axis: its shadow on the plane must match the origin-placed scene's. Every
// coordinate of the scene is a multiple of 1/16 m, so it is exactly representable up to
// 1000 km (float spacing 6.25 cm there; at 100 km 7.8 mm) and the G-buffers match the
// origin-placed one; what differs is the origin's rounding: it must start at least one float
// spacing above the plane, and starts at most a few (origin_offset_m, core/trace/trace.h), which moves
// the shadow's outline by a fraction of that. Tolerance: 2 % of the shadow plus 2 pixels up to
// 100 km; 15 % at 1000 km, where the origins start two float spacings (12.5 cm) up, half the
// box's 25 cm gap, and the shadow measured 11-13 % smaller (one spacing is the least any float
// origin can rise). The old 256-ULP offset (2 m at 100 km) lost every shadowed pixel at
// 100 km and 30 % of them at 10 km.
TEST(TraceHardCases, BoxShadowFarFromOrigin) {
  const glm::vec3 box(1.0f), up(0, 1, 0), all(1, 1, -1), light(-4.0f, 3.0f, 0.0f);
  const auto [reference, plane] = box_shadow(glm::vec3(0.0f), 1.0f, box, 0.75f, light);
  ASSERT_GT(reference, 500u);
  ASSERT_GT(plane, size_t(160 * 120 / 3));
  for (const glm::vec3 dir : {up, all})
    for (const float d : {1e3f, 1e4f, 1e5f, 1e6f}) {
      const auto [shadowed, covered_px] = box_shadow(dir * d, 1.0f, box, 0.75f, light);
      const double tol = d < 1e6f ? 0.02 * double(reference) + 2.0 : 0.15 * double(reference);
      EXPECT_NEAR(double(covered_px), double(plane), 0.01 * double(plane)) << d;
      std::printf("box shadow at %g m along (%g, %g, %g): %zu px (origin-placed: %zu)\n", double(d), double(dir.x),
                  double(dir.y), double(dir.z), shadowed, reference);
      EXPECT_NEAR(double(shadowed), double(reference), tol)
          << "offset " << d << " along (" << dir.x << ", " << dir.y << ", " << dir.z << ")";
    }
}

// A thin slab (1 m x 5 cm x 1 m, 5 cm above the plane) scaled down to 1e-4 (and 2^-13, where
// every float of the scene scales exactly): its shadow matches the unit-scale scene's. A fixed
// offset of n / 65536 (15 um) near the world origin would start the rays above the 1e-4 slab.
TEST(TraceHardCases, TinySceneCastsItsShadow) {
  const glm::vec3 slab(1.0f, 0.05f, 1.0f), light(-4.0f, 0.5f, 0.0f);
  const auto [reference, plane] = box_shadow(glm::vec3(0.0f), 1.0f, slab, 0.075f, light);
  ASSERT_GT(reference, 300u);
  for (const float scale : {1e-4f, 0x1p-13f, 1e-5f}) {
    const auto [shadowed, covered_px] = box_shadow(glm::vec3(0.0f), scale, slab, 0.075f, light);
    EXPECT_NEAR(double(covered_px), double(plane), 0.01 * double(plane)) << scale;
    std::printf("slab shadow at scale %g: %zu px (unit scale: %zu)\n", double(scale), shadowed, reference);
    EXPECT_NEAR(double(shadowed), double(reference), 0.02 * double(reference) + 2.0) << "scale " << scale;
  }
}

// Lights nearly in the plane: every pixel with n.l > 0 stays lit.
TEST(TraceHardCases, GrazingLightsStayLit) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(40.0f, 40.0f), glm::vec3(0.0f)));
  for (float elevation_deg : {0.05f, 0.5f, 2.0f}) {
    const float e = glm::radians(elevation_deg);
    s.lights.push_back(distant_light({std::cos(e), std::sin(e), 0.3f}));
  }
  s.lights.push_back(point_light({200.0f, 0.02f, 0.0f}));  // far away, barely above the plane
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 2, 6}, {0, 0, 0}), 0.0);
  TraceSettings ts;
  const TraceResult r = trace_passes(rt, g, ts);
  ASSERT_TRUE(r.find("visibility"));
  size_t expected = 0, lit = 0;
  for (size_t i = 0; i < g.depth.size(); ++i) {
    if (g.object_id[i] == kBackgroundId) continue;
    for (int l = 0; l < 4; ++l) {
      const Light& L = s.lights[size_t(l)];
      const glm::vec3 dir = L.type == LightType::Distant ? L.direction : L.position - g.position[i];
      if (glm::dot(g.geo_normal[i], dir) > 0.0f) {
        ++expected;
        lit += bit(*r.find("visibility"), l, i);
      }
    }
  }
  EXPECT_GT(expected, 0u);
  EXPECT_EQ(lit, expected);
}

// Degenerate, non-finite and out-of-range triangles are skipped and counted; tracing works.
TEST(TraceHardCases, DegenerateAndNonFiniteTrianglesAreSkipped) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  Mesh bad;
  const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
  bad.positions = {{0, 1, 0},     {1, 1, 0},   {2, 1, 0},    // collinear: zero area
                   {0, 1, 1},     {nan, 1, 1}, {inf, 1, 2},  // non-finite
                   {1e20f, 1, 0}, {0, 1, 3},   {1, 1, 3}};   // huge
  bad.triangles = {{0, 1, 2}, {0, 0, 3}, {3, 4, 7}, {3, 5, 8}, {6, 7, 8}, {7, 8, 99}};
  s.objects.push_back(make_object(2, bad, glm::vec3(0.0f)));
  s.lights.push_back(point_light({0, 5, 0}));
  s.ao = AoSettings{0.5f, 8};
  RtScene rt(s);
  const RtBuildStats& bs = rt.build_stats();
  EXPECT_EQ(bs.triangles_total, 8u);
  EXPECT_EQ(bs.triangles_built, 2u);
  EXPECT_EQ(bs.skipped_degenerate, 2u);
  EXPECT_EQ(bs.skipped_nonfinite, 2u);
  EXPECT_EQ(bs.skipped_huge, 1u);
  EXPECT_EQ(bs.skipped_bad_index, 1u);
  EXPECT_EQ(bs.skipped(), 6u);
  const GBuffer g = rt.primary_gbuffer(cam({0, 4, 6}, {0, 0, 0}), 0.0);
  const TraceResult r = trace_passes(rt, g, TraceSettings{});
  ASSERT_TRUE(r.find("visibility"));
  size_t lit = 0;
  for (size_t i = 0; i < g.depth.size(); ++i)
    lit += g.object_id[i] != kBackgroundId && bit(*r.find("visibility"), 0, i);
  EXPECT_EQ(lit, covered(g));  // the skipped triangles cast no shadow
  expect_finite_image(g, s, r);
}

// A point light lying on the plane: n.l = 0 everywhere, no ray, no light, no NaN.
TEST(TraceHardCases, LightOnTheSurface) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.lights.push_back(point_light({0.5f, 0.0f, 0.5f}));
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 4, 6}, {0, 0, 0}), 0.0);
  const TraceResult r = trace_passes(rt, g, TraceSettings{});
  EXPECT_EQ(r.stats.shadow_rays, 0u);
  EXPECT_EQ(r.stats.invalid_rays, 0u);
  const ImageRGB8 img = composite(g, s, r.find("visibility"), nullptr);
  const Rgb8 ambient_only = tonemap_srgb8(glm::vec3(0.5f) * s.ambient);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x)
      if (g.covered(x, y)) {
        ASSERT_EQ(img(x, y), ambient_only) << x << "," << y;
      }
}

// A sphere light cutting through the plane: points inside its sphere are visible (no ray);
// outside it, the ray to the centre (hard mode) rises above the plane and is unoccluded; the
// soft rays partly dive below the horizon into the plane (occluded, as they should be).
TEST(TraceHardCases, LightIntersectingGeometry) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.lights.push_back(point_light({0.0f, 0.1f, 0.0f}, 1.0f));
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 3, 3}, {0, 0, 0}), 0.0);
  for (bool soft : {false, true}) {
    TraceSettings ts;
    ts.soft_shadows = soft;
    const TraceResult r = trace_passes(rt, g, ts);
    EXPECT_GT(r.stats.shadow_inside_light, 0u);
    EXPECT_EQ(r.stats.invalid_rays, 0u);
    size_t inside = 0;
    for (size_t i = 0; i < g.depth.size(); ++i) {
      if (g.object_id[i] == kBackgroundId) continue;
      const bool in = glm::length(g.position[i] - s.lights[0].position) <= 1.0f;
      inside += in;
      if (in || !soft) {
        EXPECT_TRUE(bit(*r.find("visibility"), 0, i)) << i;
      }
    }
    EXPECT_NEAR(double(inside), double(r.stats.shadow_inside_light), 2.0);  // float vs double at the rim
    expect_finite_image(g, s, r);
  }
}

// A light inside a closed box seen from outside: every outer face looks away from it.
TEST(TraceHardCases, LightInsideClosedBox) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_box({2, 2, 2}), glm::vec3(0.0f)));
  s.lights.push_back(point_light({0.2f, 0.1f, 0.0f}, 0.3f));
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({3, 3, 4}, {0, 0, 0}), 0.0);
  ASSERT_GT(covered(g), 0u);
  for (bool soft : {false, true}) {
    TraceSettings ts;
    ts.soft_shadows = soft;
    const TraceResult r = trace_passes(rt, g, ts);
    EXPECT_EQ(r.stats.shadow_rays, 0u);
    for (size_t i = 0; i < g.depth.size(); ++i) EXPECT_FALSE(bit(*r.find("visibility"), 0, i));
    expect_finite_image(g, s, r);
  }
}

// A zero-radius light (and a distant light of zero angular radius): soft == hard, bit for bit.
TEST(TraceHardCases, ZeroRadiusLightSoftEqualsHard) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, make_box({1, 1, 1}), glm::vec3(0.3f, 0.5f, 0.0f)));
  s.lights.push_back(point_light({1, 4, 1}, 0.0f));
  s.lights.push_back(distant_light({-0.4f, 1.0f, 0.3f}, 0.0f));
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 4, 6}, {0, 0, 0}), 0.0);
  TraceSettings hard, soft;
  hard.soft_shadows = false;
  soft.soft_shadows = true;
  soft.samples_per_light = 1;
  const TraceResult rh = trace_passes(rt, g, hard), rs = trace_passes(rt, g, soft);
  EXPECT_EQ(rs.plan.shadow, ShadowMode::Hard);  // point lights only: hard whatever the setting
  ASSERT_TRUE(rh.find("visibility") && rs.find("visibility"));
  EXPECT_EQ(rh.find("visibility")->bytes, rs.find("visibility")->bytes);
  EXPECT_EQ(rh.stats.shadow_rays, rs.stats.shadow_rays);
  size_t shadowed = 0;
  for (size_t i = 0; i < g.depth.size(); ++i) shadowed += g.object_id[i] == 1 && !bit(*rh.find("visibility"), 0, i);
  EXPECT_GT(shadowed, 0u);  // the box does cast a shadow
}

// A camera inside a closed box with the light outside: everything is shadowed; AO with a
// radius larger than the box is fully occluded.
TEST(TraceHardCases, CameraInsideGeometry) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_box({2, 2, 2}), glm::vec3(0.0f)));
  s.lights.push_back(point_light({5, 6, 4}, 0.5f));
  s.ao = AoSettings{10.0f, 8};
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0.1f, 0.2f, 0.3f}, {0, 0, -1}), 0.0);
  EXPECT_EQ(covered(g), size_t(kW * kH));
  const TraceResult r = trace_passes(rt, g, TraceSettings{});
  ASSERT_TRUE(r.find("visibility") && r.find("ao"));
  for (size_t i = 0; i < g.depth.size(); ++i) {
    EXPECT_FALSE(bit(*r.find("visibility"), 0, i)) << i;
    EXPECT_EQ(r.find("ao")->bytes[i], 0) << i;
  }
  EXPECT_EQ(r.stats.invalid_rays, 0u);
  expect_finite_image(g, s, r);
}

// Nothing in view: no ray is traced at all.
TEST(TraceHardCases, EmptyViewTracesNoRay) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.lights.push_back(point_light({0, 5, 0}, 0.5f));
  s.ao = AoSettings{1.0f, 8};
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 2, 0}, {0, 10, 0.1f}), 0.0);  // looking up
  EXPECT_EQ(covered(g), 0u);
  const TraceResult r = trace_passes(rt, g, TraceSettings{});
  EXPECT_EQ(r.stats.shadow_rays, 0u);
  EXPECT_EQ(r.stats.ao_rays, 0u);
  EXPECT_EQ(r.stats.covered_pixels, 0u);
  const ImageRGB8 img = composite(g, s, r.find("visibility"), r.find("ao"));
  for (const Rgb8& p : img.pixels()) EXPECT_EQ(p, tonemap_srgb8(s.background));
}

// Invalid rays (a G-buffer point at 1e19 or NaN with an id the scene does not know) are
// counted and never traced; their answer is "unoccluded".
TEST(TraceHardCases, InvalidRaysAreCountedNotTraced) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.lights.push_back(point_light({0, 5, 0}));
  s.lights.push_back(distant_light({0, 1, 0}, 1.0f));
  s.ao = AoSettings{1.0f, 8};
  RtScene rt(s);
  GBuffer g;
  g.camera = cam({0, 2, 2}, {0, 0, 0});
  g.resize(3, 1);
  g.object_id(0, 0) = 99;  // unknown: falls back to the G-buffer's position
  g.position(0, 0) = glm::vec3(1e19f, 0.0f, 0.0f);
  g.geo_normal(0, 0) = glm::vec3(0, 1, 0);
  g.object_id(1, 0) = 99;
  g.position(1, 0) = glm::vec3(std::numeric_limits<float>::quiet_NaN());
  g.geo_normal(1, 0) = glm::vec3(0, 1, 0);
  g.object_id(2, 0) = 1;  // an ordinary point on the plane
  g.prim_id(2, 0) = 0;
  g.bary(2, 0) = glm::vec2(0.3f, 0.3f);
  g.geo_normal(2, 0) = glm::vec3(0, 1, 0);
  TraceSettings ts;
  ts.samples_per_light = 4;
  const TraceResult r = trace_passes(rt, g, ts);
  EXPECT_EQ(r.stats.unresolved_pixels, 2u);
  // Pixel 0: 1 hard + 4 soft shadow rays and 8 AO rays invalid; pixel 1: the NaN point fails
  // before (no light decision possible) -> same rays, all invalid.
  EXPECT_EQ(r.stats.invalid_rays, 2u * (1 + 4 + 8));
  EXPECT_EQ(r.stats.shadow_rays, 1u + 4u);  // pixel 2 only
  EXPECT_EQ(r.stats.ao_rays, 8u);
  ASSERT_TRUE(r.find("visibility") && r.find("ao"));
  EXPECT_EQ(r.find("visibility")->desc.kind, PassKind::SoftVisibility);
  for (size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(r.find("visibility")->bytes[0 * 3 + i], 4) << i;  // unoccluded
    EXPECT_EQ(r.find("visibility")->bytes[1 * 3 + i], 4) << i;
    EXPECT_EQ(r.find("ao")->bytes[i], 8) << i;
  }
}

}  // namespace
}  // namespace dhr
