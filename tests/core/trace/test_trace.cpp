// The server's passes against analytic answers: AO (paper Eq. 1-3) on an open plane, at the
// foot of a wall and far from everything; hard and soft shadows (section 3.1) of simple
// occluders; ray counts and pass plans; determinism across thread counts; the composite.
#include "core/base/avx512.h"
#include "core/base/cpu_isa.h"
#include "core/base/error.h"
#include "core/base/rng.h"
#include "core/pass/composite.h"
#include "core/pass/passes.h"
#include "core/pass/reference.h"
#include "core/scene/shapes.h"
#include "core/trace/rt_scene.h"
#include "core/trace/trace.h"
#include "core/trace/trace_kernels.h"
#include "core/trace/trace_rays.h"

#include "tests/support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

#include <unistd.h>

namespace dhr {
namespace {

constexpr int kW = 48, kH = 32;

using test::make_object;
using test::ScopedEnv;

// A single quad (two triangles) with the given corners, counter-clockwise.
Mesh make_quad(glm::vec3 a, glm::vec3 b, glm::vec3 c, glm::vec3 d) {
  Mesh m;
  m.positions = {a, b, c, d};
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  return m;
}

Scene base_scene() {
  Scene s;
  s.name = "trace_test";
  Material m;
  m.name = "grey";
  m.albedo = glm::vec3(0.5f, 0.6f, 0.7f);
  s.materials.push_back(m);
  s.ambient = glm::vec3(0.3f);
  return s;
}

Light sphere_light(glm::vec3 p, float radius = 0.0f, float intensity = 10.0f) {
  return test::sphere_light(p, radius, intensity);
}
using test::distant_light;

Camera cam(glm::vec3 pos, glm::vec3 target) {
  return Camera::look_at(pos, target, {0, 1, 0}, 60.0f, kW, kH, 0.05f, 1000.0f);
}

// A plane with a box and a sphere on it: AO partly occluded at their feet, penumbrae behind them.
Scene occluders_scene() {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, make_box({1, 1, 1}), glm::vec3(0.0f, 0.5f, 0.0f)));
  s.objects.push_back(make_object(3, make_sphere(0.4f, 16, 8), glm::vec3(1.0f, 0.4f, 0.5f)));
  return s;
}

bool bit(const PassBuffer& pb, int light, size_t pixel) {
  const size_t bpp = size_t((pb.desc.channels + 7) / 8);
  return (pb.bytes[pixel * bpp + size_t(light >> 3)] >> (light & 7)) & 1u;
}

// A G-buffer of `count` pixels that all show the same point of object `id` (so that each
// pixel draws independent random numbers for the same estimate).
GBuffer point_gbuffer(const Scene& s, uint32_t id, glm::vec3 point, glm::vec3 normal, int count) {
  const Object* obj = nullptr;
  for (const auto& o : s.objects)
    if (o.id == id) obj = &o;
  EXPECT_NE(obj, nullptr);
  GBuffer g;
  g.camera = cam(point + normal * 2.0f + glm::vec3(0.01f, 0, 0.01f), point);
  g.resize(count, 1);
  for (uint32_t t = 0; t < obj->mesh.triangles.size(); ++t) {
    const glm::uvec3 tri = obj->mesh.triangles[t];
    const glm::dvec3 a(obj->mesh.positions[tri.x]), b(obj->mesh.positions[tri.y]), c(obj->mesh.positions[tri.z]);
    const glm::dvec3 n = glm::cross(b - a, c - a), p(point);
    const double area2 = glm::dot(n, n);
    const double b1 = glm::dot(glm::cross(p - a, c - a), n) / area2;
    const double b2 = glm::dot(glm::cross(b - a, p - a), n) / area2;
    if (b1 < 0 || b2 < 0 || b1 + b2 > 1) continue;
    for (int x = 0; x < count; ++x) {
      g.object_id(x, 0) = id;
      g.prim_id(x, 0) = t;
      g.bary(x, 0) = glm::vec2(float(b1), float(b2));
      g.position(x, 0) = point;
      g.geo_normal(x, 0) = normal;
      g.normal(x, 0) = normal;
      g.albedo(x, 0) = glm::vec3(1.0f);
      g.depth(x, 0) = 2.0f;
    }
    return g;
  }
  ADD_FAILURE() << "point not on object " << id;
  return g;
}

double mean_ao(const AoCounts& c) {
  double sum = 0;
  for (uint16_t v : c.unoccluded) sum += double(v) / c.rays;
  return sum / double(c.unoccluded.size());
}

// ---- building blocks ----

TEST(TraceBlocks, PixelRngMatchesCoreRng) {
  for (uint32_t pixel : {0u, 1u, 921599u})
    for (uint32_t sample : {0u, 7u, 255u}) {
      const PixelRng rng(42, pixel, 3);
      float u0, u1;
      rng.uniform2(sample, kStreamAo, u0, u1);
      const RngKey k{42, pixel, 3, sample, kStreamAo};
      EXPECT_EQ(u0, rng_uniform(k, 0));
      EXPECT_EQ(u1, rng_uniform(k, 1));
    }
}

TEST(TraceBlocks, OrthonormalBasis) {
  const glm::vec3 normals[] = {{0, 0, 1},
                               {0, 0, -1},
                               {1, 0, 0},
                               {0, 1, 0},
                               glm::normalize(glm::vec3(1, -2, 3)),
                               glm::normalize(glm::vec3(1e-4f, -1e-4f, -1.0f))};
  for (const auto& n : normals) {
    glm::vec3 t, b;
    orthonormal_basis(n, t, b);
    EXPECT_NEAR(glm::length(t), 1.0f, 1e-5f);
    EXPECT_NEAR(glm::length(b), 1.0f, 1e-5f);
    EXPECT_NEAR(glm::dot(t, n), 0.0f, 1e-5f);
    EXPECT_NEAR(glm::dot(b, n), 0.0f, 1e-5f);
    EXPECT_NEAR(glm::dot(t, b), 0.0f, 1e-5f);
    EXPECT_GT(glm::dot(glm::cross(t, b), n), 0.99f);  // right-handed
  }
}

// origin_offset_m (core/trace/trace.h): every term scales with the triangle's coordinates (no floor
// near the world origin), an axis-aligned sliver gets a few ULPs of its coordinates and a
// tilted one its float normal's error, and the rounded origin lies on the normal's side.
TEST(TraceBlocks, OriginOffsetFollowsTheErrorBound) {
  auto offset = [](const glm::dvec3 v[3]) {
    const glm::dvec3 n = glm::normalize(glm::cross(v[1] - v[0], v[2] - v[0]));
    return origin_offset_m(v, n, 0.0, embree_plane_error(v));
  };
  // classroom's 40.56 m x 3 cm wall strip in the plane z = 5 (float vertices, as Embree holds).
  const glm::dvec3 wall[3] = {glm::dvec3(glm::vec3(-20.28f, 1.0f, 5.0f)), glm::dvec3(glm::vec3(20.28f, 1.0f, 5.0f)),
                              glm::dvec3(glm::vec3(20.28f, 1.03f, 5.0f))};
  EXPECT_EQ(embree_plane_error(wall).fixed_m, 0.0);  // the off-axis edge components are 0
  EXPECT_LT(offset(wall), 4.0 * 0x1p-24 * 5.0);      // (a) alone, and its safety factor
  EXPECT_GT(offset(wall), 0.0);
  // The same strip turned about y: its long edges have two non-zero components, the normal's
  // y component cancels (error ~2^-24 emax^2 against |Ng| = emax x 3 cm) and the offset grows to
  // some 10 um (tilted about x, the long edge keeps one non-zero component: no such error).
  glm::dvec3 tilted[3];
  for (int k = 0; k < 3; ++k)
    tilted[k] = glm::dvec3(glm::vec3(float(0.6 * wall[k].x + 0.8 * wall[k].z), float(wall[k].y),
                                     float(-0.8 * wall[k].x + 0.6 * wall[k].z)));
  EXPECT_GT(offset(tilted), 10.0 * offset(wall));
  EXPECT_LT(offset(tilted), 1e-3);  // an emax^3 / |Ng| bound gives 52 mm
  // Scaling by a power of two scales every term by it (tiny and huge scenes alike).
  for (const double scale : {0x1p-14, 0x1p+17}) {
    for (const glm::dvec3* t : {wall, static_cast<const glm::dvec3*>(tilted)}) {
      const glm::dvec3 v[3] = {t[0] * scale, t[1] * scale, t[2] * scale};
      EXPECT_NEAR(offset(v), offset(t) * scale, 1e-9 * offset(t) * scale) << scale;
    }
  }
  // Embree's test in float (Moeller-Trumbore: e1 = v0 - v1, e2 = v2 - v0, Ng = e2 x e1,
  // T = Ng . (v0 - o)) never finds the rounded origin on the triangle's front side: a ray into
  // n's hemisphere needs T of the sign of Ng . n to hit (T = 0 misses: t > tnear = 0).
  const glm::dvec3 points[] = {{0, 0, 0}, {1e-3, -2e-2, 0.5}, {3, -4, 5}, {1e5, -1e5, 1e5}, {-1e6, 2e6, 7}};
  const glm::dvec3 normals[] = {{0, 1, 0},
                                {0, -1, 0},
                                glm::normalize(glm::dvec3(1, 1, -1)),
                                {-1, 0, 0},
                                glm::normalize(glm::dvec3(0.3, 1, 0.01))};
  for (const auto& p : points)
    for (const auto& n : normals)
      for (const double size : {1e-4, 1.0, 1e3}) {
        const glm::dvec3 t = std::abs(n.y) < 0.9 ? glm::normalize(glm::cross(n, glm::dvec3(0, 1, 0)))
                                                 : glm::normalize(glm::cross(n, glm::dvec3(1, 0, 0)));
        const glm::dvec3 b = glm::cross(n, t);
        glm::dvec3 v[3] = {p - size * (t + b), p + size * (2.0 * t - b), p + size * 2.0 * b};
        for (auto& q : v) q = glm::dvec3(glm::vec3(q));  // float vertices
        const glm::dvec3 cr = glm::cross(v[1] - v[0], v[2] - v[0]);
        if (!(glm::length(cr) > 0.0)) continue;  // 0.1 mm at 1000 km: collapsed in float
        const glm::dvec3 nv = glm::normalize(cr);
        const double d = origin_offset_m(v, nv, 0.0, embree_plane_error(v));
        // Some ULPs of the coordinates and of the size (not a bound growing as emax^3 / |Ng|).
        EXPECT_LT(d, 64.0 * 0x1p-24 * (std::abs(p.x) + std::abs(p.y) + std::abs(p.z) + 3.0 * size));
        const glm::vec3 f[3] = {glm::vec3(v[0]), glm::vec3(v[1]), glm::vec3(v[2])};
        const glm::vec3 ng = glm::cross(f[2] - f[0], f[0] - f[1]);
        for (int i = 0; i < 64; ++i) {
          const double b1 = (i % 8) / 8.0, b2 = (i / 8) / 8.0 * (1.0 - b1);
          const glm::dvec3 pv = (1.0 - b1 - b2) * v[0] + b1 * v[1] + b2 * v[2];
          const glm::vec3 o = offset_ray_origin(pv, nv, d);
          const glm::vec3 c = f[0] - o;
          const float tv = ng.x * c.x + ng.y * c.y + ng.z * c.z;
          EXPECT_LE(double(tv) * glm::dot(glm::dvec3(ng), nv), 0.0) << p.x << " " << n.x << " " << size << " " << i;
        }
      }
  // With no known triangle, a few ULPs of the point's own coordinates.
  EXPECT_EQ(point_offset_m({0, 0, 0}, {0, 1, 0}), 0.0);
  EXPECT_EQ(point_offset_m({0, 1024, 0}, {0, 1, 0}), 8.0 * 0x1p-24 * 1024.0);
}

// ---- pass plans ----

TEST(PassPlan, FollowsTheScene) {
  Scene s = base_scene();
  PassPlan p = plan_passes(s, TraceSettings{});
  EXPECT_FALSE(p.visibility());
  EXPECT_FALSE(p.ao);
  EXPECT_NE(p.describe().find("no lights"), std::string::npos);
  EXPECT_NE(p.describe().find("no ao block"), std::string::npos);

  s.lights = {sphere_light({0, 1, 0}), distant_light({0, 1, 0})};  // point lights only
  p = plan_passes(s, TraceSettings{});
  EXPECT_EQ(p.shadow, ShadowMode::Hard);
  EXPECT_EQ(p.visibility_kind(), PassKind::Visibility);
  EXPECT_EQ(p.visibility_desc(4, 4).channels, 2);

  s.lights.push_back(sphere_light({0, 2, 0}, 0.5f));
  TraceSettings ts;
  p = plan_passes(s, ts);
  EXPECT_EQ(p.shadow, ShadowMode::SoftBit);
  EXPECT_EQ(p.light_soft, (std::vector<uint8_t>{0, 0, 1}));
  ts.samples_per_light = 16;
  p = plan_passes(s, ts);
  EXPECT_EQ(p.shadow, ShadowMode::SoftFraction);
  EXPECT_EQ(p.visibility_desc(4, 4).kind, PassKind::SoftVisibility);
  EXPECT_EQ(p.visibility_full_scale(), 16);
  ts.samples_per_light = 300;
  EXPECT_EQ(plan_passes(s, ts).visibility_full_scale(), 255);
  ts.soft_shadows = false;
  EXPECT_EQ(plan_passes(s, ts).shadow, ShadowMode::Hard);

  s.ao = AoSettings{0.5f, 16};
  p = plan_passes(s, TraceSettings{});
  EXPECT_TRUE(p.ao);
  EXPECT_EQ(p.ao_rays, 16);
  EXPECT_FLOAT_EQ(p.ao_radius_m, 0.5f);
  TraceSettings over;
  over.ao_rays = 4;
  over.ao_radius_m = 2.0f;
  p = plan_passes(s, over);
  EXPECT_EQ(p.ao_rays, 4);
  EXPECT_FLOAT_EQ(p.ao_radius_m, 2.0f);
  EXPECT_EQ(p.ao_desc(4, 4).full_scale, 4);

  over.ao_rays = 256;
  EXPECT_THROW(plan_passes(s, over), Error);
  TraceSettings bad;
  bad.samples_per_light = 0;
  EXPECT_THROW(plan_passes(s, bad), Error);
}

// ---- AO ----

TEST(TraceAo, OpenPlaneIsUnoccluded) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(50.0f, 50.0f), glm::vec3(0.0f)));
  s.ao = AoSettings{2.0f, 32};
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 3, 5}, {0, 0, 0}), 0.0);
  TraceStats st;
  const PassPlan plan = plan_passes(s, TraceSettings{});
  const PassBuffer ao = trace_ao(rt, g, plan, TraceSettings{}, st);
  EXPECT_EQ(ao.desc.full_scale, 32);
  size_t cov = 0;
  for (size_t i = 0; i < ao.bytes.size(); ++i) {
    EXPECT_EQ(ao.bytes[i], 32) << i;
    cov += g.object_id[i] != kBackgroundId;
  }
  EXPECT_GT(cov, 0u);
  EXPECT_EQ(st.ao_rays, cov * 32);  // background pixels trace nothing
}

// A point on a floor at the foot of a (very) large wall, radius (very) large: the wall hides
// exactly half of the cosine-weighted hemisphere, O = 1/2. 64 pixels x 64 rays = 4096
// Bernoulli samples: standard error sqrt(0.25 / 4096) = 0.0078; tolerance 4 standard errors.
TEST(TraceAo, FootOfWallIsHalfOccluded) {
  Scene s = base_scene();
  const float L = 1e4f;
  s.objects.push_back(make_object(1, make_quad({-L, 0, L}, {L, 0, L}, {L, 0, -L}, {-L, 0, -L}), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, make_quad({0, 0, L}, {0, 0, -L}, {0, L, -L}, {0, L, L}), glm::vec3(0.0f)));
  RtScene rt(s);
  const GBuffer g = point_gbuffer(s, 1, {0.01f, 0.0f, 0.3f}, {0, 1, 0}, 64);
  TraceSettings ts;
  ts.seed = 7;
  TraceStats st;
  const AoCounts c = trace_ao_counts(rt, g, 64, 1e5f, ts, st);
  const double se = std::sqrt(0.25 / (64.0 * 64.0));
  EXPECT_NEAR(mean_ao(c), 0.5, 4.0 * se);
  EXPECT_EQ(st.ao_rays, 64u * 64u);
  EXPECT_EQ(st.invalid_rays, 0u);
}

// Farther than r from every surface but its own: O = 1 exactly.
TEST(TraceAo, FarFromOtherSurfacesIsUnoccluded) {
  Scene s = base_scene();
  const float L = 100.0f;
  s.objects.push_back(make_object(1, make_quad({-L, 0, L}, {L, 0, L}, {L, 0, -L}, {-L, 0, -L}), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, make_quad({0, 0, L}, {0, 0, -L}, {0, L, -L}, {0, L, L}), glm::vec3(0.0f)));
  s.objects.push_back(make_object(3, make_box({1, 1, 1}), glm::vec3(3.0f, 2.6f, 0.0f)));  // 2.1 m above
  RtScene rt(s);
  const GBuffer g = point_gbuffer(s, 1, {3.0f, 0.0f, 0.3f}, {0, 1, 0}, 16);  // 3 m from the wall
  TraceStats st;
  const AoCounts c = trace_ao_counts(rt, g, 128, 2.0f, TraceSettings{}, st);
  EXPECT_EQ(mean_ao(c), 1.0);
  // And with a radius that reaches the wall and the box, some rays are occluded.
  const AoCounts c2 = trace_ao_counts(rt, g, 128, 3.5f, TraceSettings{}, st);
  EXPECT_LT(mean_ao(c2), 1.0);
}

TEST(TraceAo, DeterministicAcrossThreadCounts) {
  Scene s = occluders_scene();
  s.lights.push_back(sphere_light({2, 4, 1}, 0.5f));
  s.ao = AoSettings{1.0f, 8};
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 2, 4}, {0, 0.3f, 0}), 0.0);
  TraceSettings one, two;
  one.threads = 1;
  two.threads = 2;
  one.samples_per_light = two.samples_per_light = 4;
  const TraceResult r1 = trace_passes(rt, g, one), r2 = trace_passes(rt, g, two);
  ASSERT_TRUE(r1.find("ao") && r2.find("ao") && r1.find("visibility") && r2.find("visibility"));
  EXPECT_EQ(r1.find("ao")->bytes, r2.find("ao")->bytes);
  EXPECT_EQ(r1.find("visibility")->bytes, r2.find("visibility")->bytes);
  EXPECT_EQ(r1.stats.ao_rays, r2.stats.ao_rays);
  // Some AO occlusion actually happens (the test would be empty otherwise).
  size_t partial = 0;
  for (uint8_t v : r1.find("ao")->bytes) partial += v < 8;
  EXPECT_GT(partial, 0u);
  // A different frame gives different noise.
  TraceSettings other = one;
  other.frame = 1;
  EXPECT_NE(trace_passes(rt, g, other).find("ao")->bytes, r1.find("ao")->bytes);
}

// The AVX-512 AO kernel gives the baseline kernel's rays, counts and statistics bit for bit,
// on any thread count, for ray counts that fill packets with whole pixels (divisors and
// multiples of 16) and for those whose packets split pixels.
TEST(TraceAo, WideKernelsGiveTheSameBits) {
  Scene s = occluders_scene();
  s.ao = AoSettings{1.0f, 8};
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 2, 4}, {0, 0.3f, 0}), 0.0);
  if (!wide_kernels_available(rt))
    std::printf("note: no AVX2 or AVX-512 here; both settings run the baseline kernel\n");
  for (int rays : {1, 2, 4, 8, 16, 32, 48, 3, 5, 7, 13, 17, 100, 255})
    for (bool lattice : {false, true}) {  // the ground truth's lattice (TraceSettings::lattice) too
      SCOPED_TRACE(lattice ? "lattice" : "random");
      TraceSettings wide, base;
      wide.frame = base.frame = 7;
      wide.lattice = base.lattice = lattice;
      base.wide_kernels = false;
      wide.threads = 2;
      base.threads = 1;
      TraceStats sw, sb;
      const AoCounts cw = trace_ao_counts(rt, g, rays, 0.8f, wide, sw);
      const AoCounts cb = trace_ao_counts(rt, g, rays, 0.8f, base, sb);
      EXPECT_EQ(cw.unoccluded, cb.unoccluded) << rays << " rays";
      EXPECT_EQ(sw.ao_rays, sb.ao_rays);
      EXPECT_EQ(sw.covered_pixels, sb.covered_pixels);
      EXPECT_EQ(sw.invalid_rays, sb.invalid_rays);
      size_t partial = 0;
      for (uint16_t v : cw.unoccluded) partial += v < rays;
      EXPECT_GT(partial, 0u) << rays << " rays: no occlusion, the comparison would be empty";
      const std::vector<RTCRay> rw = collect_ao_rays(rt, g, rays, 0.8f, wide),
                                rb = collect_ao_rays(rt, g, rays, 0.8f, base);
      ASSERT_EQ(rw.size(), rb.size());
      EXPECT_EQ(std::memcmp(rw.data(), rb.data(), rw.size() * sizeof(RTCRay)), 0) << rays << " rays";
    }
}

// The ground truth's lattice (TraceSettings::lattice) against independent uniforms, at the
// same N samples per pixel: both against a reference of many independent samples (another
// seed), over the pixels whose reference is strictly between 0 and 1 (partly occluded AO, the
// penumbra). The lattice's estimate is unbiased (its mean error within four standard errors of
// zero) and its squared error smaller.
struct LatticeErrors {
  double mse_random = 0.0, mse_lattice = 0.0, mean_lattice = 0.0, se_lattice = 0.0;
  size_t pixels = 0;
};
LatticeErrors lattice_errors(const std::vector<uint16_t>& ref, int ref_n, const std::vector<uint16_t>& rnd,
                             const std::vector<uint16_t>& lat, int n) {
  LatticeErrors e;
  double sum = 0.0, sum2 = 0.0;
  for (size_t i = 0; i < ref.size(); ++i) {
    const double r = double(ref[i]) / ref_n;
    if (r <= 0.0 || r >= 1.0) continue;
    const double dr = double(rnd[i]) / n - r, dl = double(lat[i]) / n - r;
    e.mse_random += dr * dr;
    e.mse_lattice += dl * dl;
    sum += dl;
    sum2 += dl * dl;
    ++e.pixels;
  }
  const double m = double(e.pixels);
  e.mse_random /= m;
  e.mse_lattice /= m;
  e.mean_lattice = sum / m;
  e.se_lattice = std::sqrt(std::max(0.0, sum2 / m - e.mean_lattice * e.mean_lattice) / m);
  return e;
}

TEST(TraceAo, LatticeIsUnbiasedAndConvergesFaster) {
  Scene s = occluders_scene();
  s.lights.push_back(sphere_light({0.5f, 2.5f, -1.0f}, 0.6f));
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 2, 4}, {0, 0.3f, 0}), 0.0);
  constexpr int kN = 32, kRef = 2048;
  TraceSettings rnd, lat, ref;
  lat.lattice = true;
  ref.seed = 99;
  TraceStats st;
  {
    const AoCounts r = trace_ao_counts(rt, g, kRef, 1.0f, ref, st);
    const LatticeErrors e = lattice_errors(r.unoccluded, kRef, trace_ao_counts(rt, g, kN, 1.0f, rnd, st).unoccluded,
                                           trace_ao_counts(rt, g, kN, 1.0f, lat, st).unoccluded, kN);
    std::printf("AO, %zu pixels: MSE random %.3g, lattice %.3g (%.2fx); lattice mean error %.2g +- %.2g\n", e.pixels,
                e.mse_random, e.mse_lattice, e.mse_random / e.mse_lattice, e.mean_lattice, e.se_lattice);
    ASSERT_GT(e.pixels, 200u);
    EXPECT_LT(e.mse_lattice, 0.6 * e.mse_random);
    EXPECT_LT(std::abs(e.mean_lattice), 4.0 * e.se_lattice + 1e-3);
  }
  {
    rnd.samples_per_light = lat.samples_per_light = kN;
    ref.samples_per_light = 1024;  // the fraction path's most
    const PassPlan plan = plan_passes(s, rnd), ref_plan = plan_passes(s, ref);
    const VisibilityCounts r = trace_visibility_counts(rt, g, ref_plan, ref, st);
    const LatticeErrors e = lattice_errors(r.visible, 1024, trace_visibility_counts(rt, g, plan, rnd, st).visible,
                                           trace_visibility_counts(rt, g, plan, lat, st).visible, kN);
    std::printf("shadows, %zu pixels: MSE random %.3g, lattice %.3g (%.2fx); lattice mean error %.2g +- %.2g\n",
                e.pixels, e.mse_random, e.mse_lattice, e.mse_random / e.mse_lattice, e.mean_lattice, e.se_lattice);
    ASSERT_GT(e.pixels, 50u);
    EXPECT_LT(e.mse_lattice, 0.6 * e.mse_random);
    EXPECT_LT(std::abs(e.mean_lattice), 4.0 * e.se_lattice + 1e-3);
  }
}

// ---- shadows ----

// The visibility pass with `settings` on the wide kernels (2 threads) and on the baseline ones
// (1 thread): expects the same counts, statistics and rays in order; returns the wide counts,
// the baseline's statistics and the number of rays.
struct WideAsBase {
  VisibilityCounts counts;
  TraceStats stats;
  size_t rays = 0;
};
WideAsBase expect_wide_as_base(RtScene& rt, const Scene& s, const GBuffer& g, const TraceSettings& settings) {
  TraceSettings wide = settings, base = settings;
  base.wide_kernels = false;
  wide.threads = 2;
  base.threads = 1;
  const PassPlan plan = plan_passes(s, wide);
  TraceStats sw, sb;
  const VisibilityCounts cw = trace_visibility_counts(rt, g, plan, wide, sw);
  const VisibilityCounts cb = trace_visibility_counts(rt, g, plan, base, sb);
  EXPECT_EQ(cw.visible, cb.visible);
  EXPECT_EQ(sw.shadow_rays, sb.shadow_rays);
  EXPECT_EQ(sw.invalid_rays, sb.invalid_rays);
  EXPECT_EQ(sw.shadow_skipped_facing, sb.shadow_skipped_facing);
  EXPECT_EQ(sw.shadow_skipped_range, sb.shadow_skipped_range);
  const std::vector<RTCRay> rw = collect_visibility_rays(rt, g, plan, wide);
  const std::vector<RTCRay> rb = collect_visibility_rays(rt, g, plan, base);
  EXPECT_EQ(rw.size(), rb.size());
  if (rw.size() == rb.size()) {
    EXPECT_EQ(std::memcmp(rw.data(), rb.data(), rw.size() * sizeof(RTCRay)), 0);
  }
  return {cw, sb, rw.size()};
}

// The soft shadows' cone loops (S > 1 rays per light) on the vector kernel (AVX2's
// soft_pair_rays_x8) give the baseline kernel's counts, statistics and rays bit for bit: a
// sphere light partly hidden behind the box, a distant one and a sphere light below the plane
// (facing away), for S around the vector width (partial last packets) and large. (With
// AVX-512 the cone loops have no vector kernel: there it compares the AVX-512 surfaces and
// light classification with the baseline's.)
TEST(TraceShadows, WideKernelsGiveTheSameBitsWithManySamples) {
  Scene s = occluders_scene();
  s.lights.push_back(sphere_light({0.5f, 2.5f, -1.0f}, 0.6f));
  s.lights.push_back(distant_light({-0.4f, 1.0f, 0.3f}, 8.0f));
  s.lights.push_back(sphere_light({0.0f, -2.0f, 0.0f}, 0.5f));
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 2, 4}, {0, 0.3f, 0}), 0.0);
  if (!wide_kernels_available(rt))
    std::printf("note: no AVX2 or AVX-512 here; both settings run the baseline kernels\n");
  for (int samples : {2, 3, 5, 7, 8, 9, 16, 17, 64})
    for (bool lattice : {false, true}) {  // the ground truth's lattice (TraceSettings::lattice) too
      SCOPED_TRACE(std::to_string(samples) + (lattice ? " samples, lattice" : " samples, random"));
      TraceSettings settings;
      settings.frame = 5;
      settings.lattice = lattice;
      settings.samples_per_light = samples;
      const WideAsBase r = expect_wide_as_base(rt, s, g, settings);
      size_t partial = 0;
      for (uint16_t v : r.counts.visible) partial += v > 0 && v < samples;
      EXPECT_GT(partial, 0u) << "no penumbra, the comparison would be weak";
    }
}

// One ray per light and pixel (hard shadows, and soft ones with one sample), for every light
// count up to past the listing's vector ones (core/trace/trace_avx512.cpp's list_pairs_x16: a block
// whose traced pairs lie on 1 to 4 lights in registers, on more pair by pair, and past
// kListPairsMaxLights visibility_rows' own loop): the baseline kernels' counts, statistics and
// rays, in their order, bit for bit. The lights lie on both sides of the plane, some out of
// range, so that a block's pairs mix every code.
TEST(TraceShadows, WideKernelsGiveTheSameBitsForEveryLightCount) {
  Light candidates[] = {sphere_light({0.5f, 2.5f, -1.0f}, 0.6f), distant_light({-0.4f, 1.0f, 0.3f}, 8.0f),
                        sphere_light({0.0f, -2.0f, 0.0f}, 0.5f), sphere_light({-2.0f, 1.5f, 1.0f}, 0.3f),
                        sphere_light({2.5f, 0.6f, 0.5f}, 0.2f),  distant_light({0.3f, -1.0f, 0.2f}, 8.0f),
                        sphere_light({1.0f, 3.0f, 2.0f}, 0.4f)};
  candidates[0].range_m = 4.5f;  // some pairs out of range
  candidates[3].range_m = 2.5f;
  for (size_t nl : {1, 2, 3, 4, 5, 6, 7, 34}) {
    Scene s = occluders_scene();
    for (size_t l = 0; l < nl; ++l) {  // past 7, the same lights again, moved
      s.lights.push_back(candidates[l % std::size(candidates)]);
      s.lights.back().position += 0.05f * float(l / std::size(candidates)) * glm::vec3(1.0f, 0.5f, -0.3f);
    }
    RtScene rt(s);
    if (nl == 1 && !wide_kernels_available(rt))
      std::printf("note: no AVX2 or AVX-512 here; both settings run the baseline kernels\n");
    // 61 pixels a row: the last block of 16 is partial.
    const Camera c = Camera::look_at({0, 2, 4}, {0, 0.3f, 0}, {0, 1, 0}, 60.0f, 61, 37, 0.05f, 1000.0f);
    const GBuffer g = rt.primary_gbuffer(c, 0.0);
    for (bool soft : {false, true}) {
      SCOPED_TRACE(std::to_string(nl) + (soft ? " lights, soft" : " lights, hard"));
      TraceSettings settings;
      settings.frame = 3;
      settings.soft_shadows = soft;
      const WideAsBase r = expect_wide_as_base(rt, s, g, settings);
      size_t lit = 0, dark = 0;
      for (uint16_t v : r.counts.visible) lit += v > 0, dark += v == 0;
      EXPECT_GT(lit, 0u);
      EXPECT_GT(dark, 0u);
      EXPECT_GT(r.rays, 1000u);
      EXPECT_GT(r.stats.shadow_skipped_range, 0u);  // light 0's range
      if (nl >= 3) {
        EXPECT_GT(r.stats.shadow_skipped_facing, 0u);  // light 2 lies below the plane
      }
    }
  }
}

// A thread keeps the triangles it rebuilt (visibility_rows' table) from block to block of one
// pass, never into the next: two scenes that differ only in where the ground plane lies (slid
// within its own plane) give its triangles the same object and triangle ids; passes of the two
// in turn on one thread must each give the counts of the baseline kernels, which keep no table.
TEST(TraceShadows, PassesDoNotShareRebuiltTriangles) {
  Scene here = occluders_scene();
  here.lights.push_back(sphere_light({3, 4, 2}));
  Scene moved = here;
  ASSERT_EQ(moved.objects[0].id, 1u);
  for (glm::vec3& p : moved.objects[0].mesh.positions) p += glm::vec3(2.0f, 0.0f, 1.5f);
  RtScene rt_here(here), rt_moved(moved);
  const Camera c = cam({0.5f, 3, 4}, {0, 0.5f, 0});
  const auto pass = [&](RtScene& rt, const Scene& scene, bool wide) {
    TraceSettings s;
    s.threads = 1;
    s.soft_shadows = false;
    s.wide_kernels = wide;
    const GBuffer g = rt.primary_gbuffer(c, 0.0);
    TraceStats st;
    return trace_visibility_counts(rt, g, plan_passes(scene, s), s, st).visible;
  };
  const std::vector<uint16_t> want_here = pass(rt_here, here, false), want_moved = pass(rt_moved, moved, false);
  ASSERT_NE(want_here, want_moved);  // the floor's points differ, so some counts do
  for (int round = 0; round < 2; ++round) {
    EXPECT_EQ(pass(rt_here, here, true), want_here) << "round " << round;
    EXPECT_EQ(pass(rt_moved, moved, true), want_moved) << "round " << round;
  }
}

// Pixels whose surface faces away from every light trace no shadow ray.
TEST(TraceShadows, FacingAwayTracesNoRay) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.lights.push_back(distant_light({0.2f, -1.0f, 0.0f}));       // below the plane
  s.lights.push_back(sphere_light({0.0f, -2.0f, 0.0f}, 0.5f));  // below, soft
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 3, 5}, {0, 0, 0}), 0.0);
  TraceResult r = trace_passes(rt, g, TraceSettings{});
  ASSERT_GT(r.stats.covered_pixels, 0u);
  EXPECT_EQ(r.stats.shadow_rays, 0u);
  EXPECT_EQ(r.stats.shadow_skipped_facing, 2 * r.stats.covered_pixels);
  for (uint8_t b : r.find("visibility")->bytes) EXPECT_EQ(b, 0);
  // One light above: exactly one ray per covered pixel.
  s.lights.push_back(distant_light({0.0f, 1.0f, 0.2f}));
  RtScene rt2(s);
  r = trace_passes(rt2, g, TraceSettings{});
  EXPECT_EQ(r.stats.shadow_rays, r.stats.covered_pixels);
}

TEST(TraceShadows, BeyondRangeTracesNoRay) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(200.0f, 200.0f), glm::vec3(0.0f)));
  Light l = sphere_light({0, 1, 0});
  l.range_m = 3.0f;
  s.lights.push_back(l);
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 3, 5}, {0, 0, -10}), 0.0);
  const TraceResult r = trace_passes(rt, g, TraceSettings{});
  size_t in_range = 0;
  for (size_t i = 0; i < g.depth.size(); ++i) {
    if (g.object_id[i] == kBackgroundId) continue;
    const float d = glm::length(g.position[i] - l.position);
    if (std::abs(d - 3.0f) < 1e-3f) continue;
    in_range += d < 3.0f;
    EXPECT_EQ(bit(*r.find("visibility"), 0, i), d < 3.0f) << i;
  }
  EXPECT_GT(in_range, 0u);
  EXPECT_GT(r.stats.shadow_skipped_range, 0u);
  EXPECT_EQ(r.stats.shadow_rays + r.stats.shadow_skipped_range, r.stats.covered_pixels);
}

// Does the segment from p to q cross the axis-aligned box [lo, hi]? (slab test, double)
bool segment_hits_box(glm::dvec3 p, glm::dvec3 q, glm::dvec3 lo, glm::dvec3 hi) {
  double t0 = 0.0, t1 = 1.0;
  const glm::dvec3 d = q - p;
  for (int i = 0; i < 3; ++i) {
    if (d[i] == 0.0) {
      if (p[i] < lo[i] || p[i] > hi[i]) return false;
      continue;
    }
    double a = (lo[i] - p[i]) / d[i], b = (hi[i] - p[i]) / d[i];
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
  }
  return t0 <= t1;
}

// A unit box on the floor under a point light: a floor point is shadowed exactly when the
// segment to the light crosses the box (pixels within 2 cm of the shadow's edge are not judged).
TEST(TraceShadows, BoxCastsTheExpectedHardShadow) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, make_box({1, 1, 1}), glm::vec3(0.0f, 0.5f, 0.0f)));
  const glm::dvec3 light(2.0, 4.0, 0.5);
  s.lights.push_back(sphere_light(glm::vec3(light)));
  RtScene rt(s);
  const Camera c = Camera::look_at({0, 6, 3.0f}, {-1, 0, 0}, {0, 1, 0}, 50.0f, 96, 64, 0.05f, 100.0f);
  const GBuffer g = rt.primary_gbuffer(c, 0.0);
  const TraceResult r = trace_passes(rt, g, TraceSettings{});
  const glm::dvec3 lo(-0.5, 0.0, -0.5), hi(0.5, 1.0, 0.5);
  size_t judged = 0, shadowed = 0;
  for (size_t i = 0; i < g.depth.size(); ++i) {
    if (g.object_id[i] != 1) continue;
    const glm::dvec3 p(g.position[i]);
    const bool hit = segment_hits_box(p, light, lo, hi);
    bool robust = true;
    for (glm::dvec3 e :
         {glm::dvec3(0.02, 0, 0), glm::dvec3(-0.02, 0, 0), glm::dvec3(0, 0, 0.02), glm::dvec3(0, 0, -0.02)})
      robust = robust && segment_hits_box(p + e, light, lo, hi) == hit;
    if (!robust) continue;
    ++judged;
    shadowed += hit;
    EXPECT_EQ(bit(*r.find("visibility"), 0, i), !hit) << p.x << " " << p.z;
  }
  EXPECT_GT(judged, 1000u);
  EXPECT_GT(shadowed, 50u);
  // The box's top face is lit (nothing above it).
  for (size_t i = 0; i < g.depth.size(); ++i)
    if (g.object_id[i] == 2 && g.geo_normal[i].y > 0.9f) {
      EXPECT_TRUE(bit(*r.find("visibility"), 0, i));
    }
}

// The penumbra of a straight edge. A point at the origin, a sphere light (radius R) at height
// H above it, an opaque half-plane at height h covering x < e. A direction at angle theta from
// the vertical and azimuth phi crosses height h at x = h tan(theta) cos(phi): the visible
// fraction is the cone's solid-angle share with h tan(theta) cos(phi) >= e, integrated here by
// quadrature. MC with 64 pixels x 255 rays; tolerance 4 standard errors.
TEST(TraceShadows, SoftPenumbraMatchesAnalyticFraction) {
  const float R = 1.0f, H = 4.0f, h = 1.0f;
  const double s2 = double(R) * R / (double(H) * H);
  const double omc_max = s2 / (1.0 + std::sqrt(1.0 - s2));  // 1 - cos(theta_max)
  const double tan_max = std::sqrt(s2) / std::sqrt(1.0 - s2);
  const float e = float(0.4 * h * tan_max);
  double visible = 0;
  const int nq = 1000;
  for (int i = 0; i < nq; ++i) {
    const double omc = (i + 0.5) / nq * omc_max, cos_t = 1.0 - omc;
    const double tan_t = std::sqrt(omc * (2.0 - omc)) / cos_t;
    for (int j = 0; j < nq; ++j) {
      const double phi = (j + 0.5) / nq * 2.0 * std::numbers::pi;
      visible += h * tan_t * std::cos(phi) >= e;
    }
  }
  const double expected = visible / (double(nq) * nq);
  ASSERT_GT(expected, 0.1);
  ASSERT_LT(expected, 0.9);

  Scene s = base_scene();
  const float L = 50.0f;
  s.objects.push_back(make_object(1, make_quad({-L, 0, L}, {L, 0, L}, {L, 0, -L}, {-L, 0, -L}), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, make_quad({-L, h, L}, {e, h, L}, {e, h, -L}, {-L, h, -L}), glm::vec3(0.0f)));
  s.lights.push_back(sphere_light({0, H, 0}, R));
  RtScene rt(s);
  const GBuffer g = point_gbuffer(s, 1, {0.0f, 0.0f, 0.0f}, {0, 1, 0}, 64);
  TraceSettings ts;
  ts.samples_per_light = 255;
  const PassPlan plan = plan_passes(s, ts);
  TraceStats st;
  const VisibilityCounts vc = trace_visibility_counts(rt, g, plan, ts, st);
  double mean = 0;
  for (size_t i = 0; i < 64; ++i) mean += vc.fraction(0, i) / 64.0;
  const double se = std::sqrt(expected * (1 - expected) / (64.0 * 255.0));
  EXPECT_NEAR(mean, expected, 4.0 * se);
  EXPECT_EQ(st.shadow_rays, 64u * 255u);
  // The packed pass carries the same counts (full_scale = S = 255).
  const PassBuffer pb = pack_visibility(vc, plan);
  EXPECT_EQ(pb.desc.full_scale, 255);
  for (size_t i = 0; i < 64; ++i) EXPECT_EQ(pb.bytes[i], vc.visible[i]);
}

// visibility_fraction with one ray per light sends the same rays' results as the
// bitmask, 8 bits per light (0 or 1 of full scale 1): a penumbra of the half-plane occluder of
// SoftPenumbraMatchesAnalyticFraction, with a point light beside the sphere light.
TEST(TraceShadows, FractionFormatCarriesTheBitmaskBits) {
  Scene s = base_scene();
  const float L = 50.0f;
  s.objects.push_back(make_object(1, make_quad({-L, 0, L}, {L, 0, L}, {L, 0, -L}, {-L, 0, -L}), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, make_quad({-L, 1, L}, {0.1f, 1, L}, {0.1f, 1, -L}, {-L, 1, -L}), glm::vec3(0.0f)));
  s.lights.push_back(sphere_light({0, 4, 0}, 1.0f));
  s.lights.push_back(sphere_light({-0.5f, 3, 0}));  // a point light: hard, one ray to its centre
  RtScene rt(s);
  const int n = 97;
  const GBuffer g = point_gbuffer(s, 1, {0.0f, 0.0f, 0.0f}, {0, 1, 0}, n);
  TraceSettings bits, frac;
  frac.visibility_fraction = true;
  const PassPlan pb = plan_passes(s, bits), pf = plan_passes(s, frac);
  ASSERT_EQ(pb.shadow, ShadowMode::SoftBit);
  ASSERT_EQ(pf.shadow, ShadowMode::SoftFraction);
  EXPECT_EQ(pf.samples_per_light, 1);
  EXPECT_EQ(pf.visibility_desc(n, 1).kind, PassKind::SoftVisibility);
  EXPECT_EQ(pf.visibility_full_scale(), 1);
  TraceStats sb, sf;
  const PassBuffer b = trace_visibility(rt, g, pb, bits, sb);
  const PassBuffer f = trace_visibility(rt, g, pf, frac, sf);
  EXPECT_EQ(sb.shadow_rays, sf.shadow_rays);
  ASSERT_EQ(f.bytes.size(), size_t(n) * 2);
  int lit = 0;
  for (int i = 0; i < n; ++i)
    for (int l = 0; l < 2; ++l) {
      const int bit = (b.bytes[size_t(i)] >> l) & 1;
      EXPECT_EQ(f.bytes[size_t(l) * size_t(n) + size_t(i)], bit) << "pixel " << i << " light " << l;
      lit += l == 0 ? bit : 0;
    }
  EXPECT_GT(lit, 0);  // a penumbra: some rays of the sphere light pass, some do not
  EXPECT_LT(lit, n);
  // Hard shadows are sent as fractions too.
  frac.soft_shadows = false;
  EXPECT_EQ(plan_passes(s, frac).visibility_kind(), PassKind::SoftVisibility);
}

// The jittered rays are the cone sampling of core/trace/trace.h, ray by ray: sample k of light l at
// pixel p draws (u0, u1) from the key (seed, p, frame, k, kStreamLightBase + l) and goes
// 1 - cos = u0 (1 - cos theta_max) off the light's direction at angle 2 pi u1 in the basis of
// orthonormal_basis. Checked against a double-precision reference for a sphere and a distant
// light, for one sample per light (the row kernels) and four (the per-pair chunks), which must
// also agree bit for bit on their common sample 0; the AO rays likewise against Malley's method.
TEST(TraceShadows, JitteredRaysFollowTheConeSampling) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  const glm::vec3 centre(1.0f, 4.0f, -0.5f);
  s.lights.push_back(sphere_light(centre, 0.8f));
  s.lights.push_back(distant_light({-0.3f, 1.0f, 0.2f}, 6.0f));
  s.ao = AoSettings{1.0f, 5};
  RtScene rt(s);
  const int n = 37;  // not a multiple of the SIMD widths
  // Directions within 3e-5 of the double-precision reference: the polynomial sincos's error
  // bound is 2.5e-5 (core/trace/trace.cpp, sincos_2pi).
  const glm::vec3 point(0.3f, 0.0f, 0.2f);
  const GBuffer g = point_gbuffer(s, 1, point, {0, 1, 0}, n);
  TraceSettings one, four;
  one.seed = four.seed = 7;
  one.frame = four.frame = 3;
  four.samples_per_light = 4;
  const std::vector<RTCRay> r1 = collect_visibility_rays(rt, g, plan_passes(s, one), one);
  const std::vector<RTCRay> r4 = collect_visibility_rays(rt, g, plan_passes(s, four), four);
  ASSERT_EQ(r1.size(), size_t(n) * 2);
  ASSERT_EQ(r4.size(), size_t(n) * 2 * 4);
  const glm::vec3 origin(r1[0].org_x, r1[0].org_y, r1[0].org_z);
  for (int pixel = 0; pixel < n; ++pixel) {
    for (int l = 0; l < 2; ++l) {
      const RTCRay& a = r1[size_t(pixel) * 2 + size_t(l)];
      const RTCRay& b = r4[(size_t(pixel) * 2 + size_t(l)) * 4];
      EXPECT_EQ(std::memcmp(&a, &b, sizeof(RTCRay)), 0) << "pixel " << pixel << " light " << l;
      for (int k = 0; k < 4; ++k) {
        const RTCRay& r = r4[(size_t(pixel) * 2 + size_t(l)) * 4 + size_t(k)];
        const RngKey key{four.seed, uint32_t(pixel), four.frame, uint32_t(k), kStreamLightBase + uint32_t(l)};
        const double u0 = rng_uniform(key, 0), u1 = rng_uniform(key, 1);
        glm::dvec3 w;
        double omc_max;
        if (l == 0) {
          const glm::dvec3 to_c = glm::dvec3(centre) - glm::dvec3(point);
          const double d = glm::length(to_c), s2 = 0.64 / (d * d);
          w = to_c / d;
          omc_max = s2 / (1.0 + std::sqrt(1.0 - s2));
        } else {
          w = glm::dvec3(s.lights[1].direction);
          omc_max = 1.0 - std::cos(6.0 * std::numbers::pi / 180.0);
        }
        glm::vec3 t, bt;
        orthonormal_basis(glm::vec3(w), t, bt);
        const double omc = u0 * omc_max, sin_t = std::sqrt(omc * (2.0 - omc)), phi = 2.0 * std::numbers::pi * u1;
        const glm::dvec3 want = glm::normalize(glm::dvec3(t) * (std::cos(phi) * sin_t) +
                                               glm::dvec3(bt) * (std::sin(phi) * sin_t) + w * (1.0 - omc));
        EXPECT_NEAR(r.dir_x, want.x, 3e-5) << "pixel " << pixel << " light " << l << " sample " << k;
        EXPECT_NEAR(r.dir_y, want.y, 3e-5);
        EXPECT_NEAR(r.dir_z, want.z, 3e-5);
        if (l == 0) {
          // Ends (just short of) the sphere's surface along the ray.
          const glm::dvec3 end = glm::dvec3(origin) + glm::dvec3(r.dir_x, r.dir_y, r.dir_z) * double(r.tfar);
          EXPECT_NEAR(glm::length(end - glm::dvec3(centre)), 0.8, 1e-3);
        } else {
          EXPECT_TRUE(std::isinf(r.tfar));
        }
      }
    }
  }
  // AO: cosine-weighted about the normal (0, 1, 0): (r cos phi, z, r sin phi) in the basis.
  // 5 rays (packets that split pixels) and 8 (whole pixels per packet).
  for (const int rays : {5, 8}) {
    const std::vector<RTCRay> ao = collect_ao_rays(rt, g, rays, 1.0f, one);
    ASSERT_EQ(ao.size(), size_t(n) * size_t(rays));
    glm::vec3 t, bt;
    orthonormal_basis({0, 1, 0}, t, bt);
    for (int pixel = 0; pixel < n; ++pixel) {
      for (int k = 0; k < rays; ++k) {
        const RTCRay& r = ao[size_t(pixel) * size_t(rays) + size_t(k)];
        const RngKey key{one.seed, uint32_t(pixel), one.frame, uint32_t(k), kStreamAo};
        const double u0 = rng_uniform(key, 0), u1 = rng_uniform(key, 1), phi = 2.0 * std::numbers::pi * u1;
        const glm::dvec3 want = glm::dvec3(t) * (std::sqrt(u0) * std::cos(phi)) +
                                glm::dvec3(bt) * (std::sqrt(u0) * std::sin(phi)) +
                                glm::dvec3(0, 1, 0) * std::sqrt(1.0 - u0);
        EXPECT_NEAR(r.dir_x, want.x, 3e-5) << "pixel " << pixel << " ray " << k;
        EXPECT_NEAR(r.dir_y, want.y, 3e-5);
        EXPECT_NEAR(r.dir_z, want.z, 3e-5);
        EXPECT_EQ(r.tfar, 1.0f);
      }
    }
  }
}

// A moving object (an instance) is placed at the G-buffer's time.
TEST(TraceShadows, MovingOccluderFollowsTime) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  Object box = make_object(2, make_box({1, 1, 1}), glm::vec3(0.0f));
  Animation anim;
  TransformKey k0, k1;
  k0.time_s = 0.0;
  k0.translation = {-3.0f, 1.0f, 0.0f};
  k1.time_s = 1.0;
  k1.translation = {3.0f, 1.0f, 0.0f};
  anim.keys = {k0, k1};
  box.animation = anim;
  s.objects.push_back(box);
  s.lights.push_back(sphere_light({0, 6, 0}));
  RtScene rt(s);
  const Camera c = cam({0, 8, 3}, {0, 0, 0});
  for (double t : {0.0, 0.5, 1.0}) {
    const GBuffer g = rt.primary_gbuffer(c, t);
    const float box_x = -3.0f + 6.0f * float(t);
    const TraceResult r = trace_passes(rt, g, TraceSettings{});
    size_t box_pixels = 0;
    for (size_t i = 0; i < g.depth.size(); ++i) {
      if (g.object_id[i] == 2) {
        ++box_pixels;
        EXPECT_NEAR(g.position[i].x, box_x, 0.51f);
      }
      // Floor right below the box centre is in its shadow; far from it, lit.
      if (g.object_id[i] == 1) {
        const float dx = g.position[i].x - box_x, dz = g.position[i].z;
        if (std::abs(dx) < 0.3f && std::abs(dz) < 0.3f) {
          EXPECT_FALSE(bit(*r.find("visibility"), 0, i));
        }
        if (std::abs(dx) > 2.5f && std::abs(g.position[i].x) < 4.0f) {
          EXPECT_TRUE(bit(*r.find("visibility"), 0, i));
        }
      }
    }
    EXPECT_GT(box_pixels, 10u) << t;
  }
}

// Emitter geometry (the light's own proxy sphere) does not shadow its light; an alpha
// cut-out hole lets light through.
TEST(TraceShadows, EmittersAndCutoutsDoNotOcclude) {
  Scene s = base_scene();
  Material emitter;
  emitter.name = "lamp";
  emitter.emitter = true;
  Material leaves;
  leaves.name = "leaves";
  leaves.alpha_cutout = true;
  leaves.texture = 0;
  s.materials = {s.materials[0], emitter, leaves};
  Texture tex;
  tex.path = "transparent";
  tex.width = tex.height = 2;
  tex.has_alpha = true;
  tex.texels.assign(4, glm::u8vec4(255, 255, 255, 0));  // fully transparent
  s.textures.push_back(tex);
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, make_sphere(0.3f, 12, 6), glm::vec3(0, 4, 0), 1));
  s.objects.push_back(make_object(3, make_plane(3.0f, 3.0f), glm::vec3(0, 2, 0), 2));
  s.lights.push_back(sphere_light({0, 4, 0}, 0.3f));
  s.ao = AoSettings{3.0f, 16};
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 1.5f, 4}, {0, 0, 0}), 0.0);
  for (size_t i = 0; i < g.depth.size(); ++i) EXPECT_NE(g.object_id[i], 3u);  // the hole is invisible
  for (bool soft : {false, true}) {
    TraceSettings ts;
    ts.soft_shadows = soft;
    const TraceResult r = trace_passes(rt, g, ts);
    for (size_t i = 0; i < g.depth.size(); ++i)
      if (g.object_id[i] == 1) {
        EXPECT_TRUE(bit(*r.find("visibility"), 0, i)) << i;
      }
  }
  // Without the cut-out the quad does shadow the floor below it.
  s.materials[2].alpha_cutout = false;
  RtScene rt2(s);
  const GBuffer g2 = rt2.primary_gbuffer(cam({0, 1.5f, 4}, {0, 0, 0}), 0.0);
  size_t quad = 0;
  for (size_t i = 0; i < g2.depth.size(); ++i) quad += g2.object_id[i] == 3;
  EXPECT_GT(quad, 0u);
}

// ---- composite ----

TEST(Composite, ToneMapIsExactSrgb) {
  EXPECT_EQ(tonemap_srgb8(0.0f), 0);
  EXPECT_EQ(tonemap_srgb8(-1.0f), 0);
  EXPECT_EQ(tonemap_srgb8(std::nanf("")), 0);
  EXPECT_EQ(tonemap_srgb8(1.0f), 255);
  EXPECT_EQ(tonemap_srgb8(1e30f), 255);
  for (int i = 0; i <= 1000; ++i) {
    const double v = i / 1000.0;
    const double enc = 255.0 * (v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055);
    if (std::abs(enc - std::floor(enc) - 0.5) < 1e-4) continue;  // a tie: either code is right
    EXPECT_EQ(tonemap_srgb8(float(v)), std::lround(enc)) << v;
  }
}

// The code is the number of boundaries <= the value (std::upper_bound over the table of
// core/pass/composite.cpp, rebuilt here the same way): at every boundary, the floats next to it and
// a million random floats (half over every finite positive float, half over [0, 1.2)).
TEST(Composite, ToneMapCountsBoundariesLikeUpperBound) {
  std::array<float, 255> b{};
  for (int k = 1; k <= 255; ++k) {
    const double v = (k - 0.5) / 255.0;
    b[size_t(k - 1)] = float(v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4));
  }
  auto want = [&](float v) { return v > 0.0f ? int(std::upper_bound(b.begin(), b.end(), v) - b.begin()) : 0; };
  for (float x : b)
    for (float v : {std::nextafter(x, 0.0f), x, std::nextafter(x, 2.0f)})
      EXPECT_EQ(int(tonemap_srgb8(v)), want(v)) << v;
  uint32_t state = 12345;
  for (int i = 0; i < 1000000; ++i) {
    state = state * 1664525u + 1013904223u;
    float v;
    if (i % 2 == 0) {
      const uint32_t bits = state & 0x7f7fffffu;  // any finite positive float
      std::memcpy(&v, &bits, sizeof v);
    } else {
      v = float(state >> 8) * (1.2f / 16777216.0f);  // the codes' range, densely
    }
    ASSERT_EQ(int(tonemap_srgb8(v)), want(v)) << v;
  }
  EXPECT_EQ(int(tonemap_srgb8(std::numeric_limits<float>::infinity())), 255);
  // Every float from 2^-14 to 1 (the codes' range; the tone map looks its code up by the float's
  // bits), against a running count of the boundaries passed.
  int count = 0;
  for (uint32_t bits = std::bit_cast<uint32_t>(0x1p-14f); bits <= std::bit_cast<uint32_t>(1.0f); ++bits) {
    const float v = std::bit_cast<float>(bits);
    while (count < 255 && b[size_t(count)] <= v) ++count;
    if (int(tonemap_srgb8(v)) != count) {
      ADD_FAILURE() << "tone map of " << v << ": " << int(tonemap_srgb8(v)) << ", expected " << count;
      break;
    }
  }
  EXPECT_EQ(count, 255);
}

TEST(Composite, NoLightsIsAlbedoTimesAmbient) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.background = glm::vec3(0.1f, 0.2f, 0.3f);
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 3, 5}, {0, 0, -5}), 0.0);
  PassBuffer ao;
  ao.desc = {PassKind::Ao, g.width(), g.height(), 1, 8};
  ao.bytes.assign(size_t(g.width() * g.height()), 8);  // AO = 1
  const ImageRGB8 with_ao = composite(g, s, nullptr, &ao);
  const ImageRGB8 without = composite(g, s, nullptr, nullptr);
  EXPECT_EQ(with_ao, without);
  const Rgb8 expected = tonemap_srgb8(s.materials[0].albedo * s.ambient);
  size_t cov = 0;
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x) {
      cov += g.covered(x, y);
      EXPECT_EQ(with_ao(x, y), g.covered(x, y) ? expected : tonemap_srgb8(s.background));
    }
  EXPECT_GT(cov, 0u);
  // Half the AO rays unoccluded halves the ambient term.
  std::fill(ao.bytes.begin(), ao.bytes.end(), 4);
  const ImageRGB8 half = composite(g, s, nullptr, &ao);
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x)
      if (g.covered(x, y)) {
        EXPECT_EQ(half(x, y), tonemap_srgb8(s.materials[0].albedo * s.ambient * 0.5f));
      }
}

// Clearing one light's bit removes exactly that light's term.
TEST(Composite, ShadowRemovesExactlyThatLight) {
  Scene s = base_scene();
  s.lights = {sphere_light({1, 3, 0}, 0.0f, 2.0f), distant_light({-0.3f, 1.0f, 0.2f})};
  s.lights[1].intensity = 0.4f;
  s.lights[1].colour = {1.0f, 0.5f, 0.25f};
  GBuffer g;
  g.camera = cam({0, 2, 2}, {0, 0, 0});
  g.resize(2, 1);
  for (int x = 0; x < 2; ++x) {
    g.object_id(x, 0) = 1;
    g.position(x, 0) = {0.2f * float(x), 0.0f, 0.1f};
    g.normal(x, 0) = g.geo_normal(x, 0) = {0, 1, 0};
    g.albedo(x, 0) = {0.5f, 0.6f, 0.7f};
  }
  PassBuffer vis;
  vis.desc = {PassKind::Visibility, 2, 1, 2, 255};
  vis.bytes = {0b11, 0b10};  // pixel 1: light 0 shadowed
  const ImageRGB8 img = composite(g, s, &vis, nullptr);
  auto term = [&](int l, glm::vec3 p) {
    const Light& L = s.lights[size_t(l)];
    if (L.type == LightType::Distant) return L.colour * L.intensity * glm::normalize(L.direction).y;
    const glm::vec3 d = L.position - p;
    return L.colour * L.intensity * (glm::normalize(d).y / glm::dot(d, d));
  };
  const glm::vec3 a = g.albedo(0, 0);
  const glm::vec3 p0 = g.position(0, 0), p1 = g.position(1, 0);
  EXPECT_EQ(img(0, 0), tonemap_srgb8(a * (s.ambient + term(0, p0) + term(1, p0))));
  EXPECT_EQ(img(1, 0), tonemap_srgb8(a * (s.ambient + term(1, p1))));
  // A soft pass with fractions scales the term.
  PassBuffer soft;
  soft.desc = {PassKind::SoftVisibility, 2, 1, 2, 4};
  soft.bytes = {4, 2, 4, 4};  // light 0: pixel 0 full, pixel 1 half; light 1: full
  const ImageRGB8 img2 = composite(g, s, &soft, nullptr);
  EXPECT_EQ(img2(1, 0), tonemap_srgb8(a * (s.ambient + 0.5f * term(0, p1) + term(1, p1))));
  // Mismatched passes are errors, not silent garbage.
  PassBuffer wrong = vis;
  wrong.desc.channels = 3;
  EXPECT_THROW(composite(g, s, &wrong, nullptr), Error);
}

// The composite shades eight pixels at a time on its row path and sixteen where the CPU has
// AVX-512 (core/pass/composite.cpp); every pixel of both must be what the scalar kernel,
// shade_lambert, gives it, bit for bit, also in the hard cases: points inside or at the centre
// of a sphere light, beyond its range, facing away, zero normals (the geometric normal then), a
// distant light without a direction, zero and tiny radii, huge and tiny distances, odd widths
// (partial groups of eight and sixteen), NaN normals, points at exactly a light's range, with
// bitmask (one and two bytes a pixel), 8-bit and float visibility. (On a CPU without AVX-512
// both runs take the row path.) copies: the five hard-case lights once (5 lights, one bitmask
// byte a pixel) or twice (10, two bytes).
void expect_composite_matches_shade_lambert(int copies) {
  Scene s = base_scene();
  s.ambient = {0.05f, 0.06f, 0.07f};
  s.lights = {sphere_light({0.3f, 1.5f, -0.2f}, 0.25f, 3.0f), sphere_light({-2.0f, 0.5f, 1.0f}, 0.0f, 40.0f),
              distant_light({-0.3f, 1.0f, 0.2f}), distant_light({0.0f, 0.0f, 0.0f}),
              sphere_light({0.0f, 0.0f, 0.0f}, 1e-4f, 0.5f)};
  s.lights[0].range_m = 2.5f;
  s.lights[2].colour = {1.0f, 0.5f, 0.25f};
  s.lights[4].range_m = 1e-3f;
  if (copies == 2)
    for (int l = 0; l < 5; ++l) {
      Light copy = s.lights[size_t(l)];
      copy.position += glm::vec3(0.5f, 0.25f, 0.0f);
      s.lights.push_back(copy);
    }
  const int nl = int(s.lights.size());
  for (const int w : {1, 7, 8, 13, 16, 37, 50}) {
    const int h = 9;
    GBuffer g;
    g.camera = cam({0, 2, 2}, {0, 0, 0});
    g.resize(w, h);
    const size_t n = size_t(w) * size_t(h);
    PassBuffer bits, planes, ao;
    bits.desc = {PassKind::Visibility, w, h, nl, 255};
    planes.desc = {PassKind::SoftVisibility, w, h, nl, 200};
    ao.desc = {PassKind::Ao, w, h, 1, 8};
    bits.bytes.assign(bits.desc.byte_size(), 0);
    planes.bytes.assign(planes.desc.byte_size(), 0);
    ao.bytes.assign(n, 0);
    std::vector<float> fractions(n * size_t(nl)), ao_fractions(n);
    auto u = [&](size_t i, uint32_t k) {
      return float(rng_bits({77, uint32_t(i), uint32_t(w), k, 3}) >> 40) / 16777216.0f;
    };
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * size_t(w) + size_t(x);
        const uint32_t kind = uint32_t(rng_bits({78, uint32_t(i), uint32_t(w), 0, 3}) % 12);
        g.object_id(x, y) = kind == 0 ? kBackgroundId : 1;
        glm::vec3 p{4.0f * u(i, 1) - 2.0f, 2.0f * u(i, 2), 4.0f * u(i, 3) - 2.0f};
        if (kind == 1) p = s.lights[0].position;                                 // at a light's centre
        if (kind == 2) p = s.lights[0].position + glm::vec3(0.0f, 0.1f, 0.0f);   // inside its sphere
        if (kind == 3) p = {1e6f, -3e5f, 2e5f};                                  // far away
        if (kind == 4) p = s.lights[4].position + glm::vec3(1e-7f, 0.0f, 0.0f);  // within the clamp
        if (kind == 8) p = s.lights[4].position + glm::vec3(1e-3f, 0.0f, 0.0f);  // d^2 = range^2 exactly
        g.position(x, y) = p;
        glm::vec3 nrm = glm::normalize(glm::vec3(u(i, 4) - 0.5f, u(i, 5), u(i, 6) - 0.5f) + glm::vec3(0, 0.1f, 0));
        if (kind == 5) nrm = -nrm;                                             // facing away from most lights
        if (kind == 8) nrm = glm::normalize(glm::vec3(-1.0f, u(i, 5), 0.0f));  // towards light 4
        g.geo_normal(x, y) = glm::normalize(glm::vec3(0.1f, 1.0f, 0.2f));
        g.normal(x, y) = kind == 6 ? glm::vec3(0.0f) : nrm;                    // zero: the geometric normal
        if (kind == 7) g.normal(x, y) = glm::vec3(std::nanf(""), 0.0f, 1.0f);  // NaN: the geometric normal too
        g.albedo(x, y) = {u(i, 7), u(i, 8), u(i, 9)};
        ao.bytes[i] = uint8_t(rng_bits({79, uint32_t(i), 0, 0, 3}) % 9);
        ao_fractions[i] = u(i, 10);
        for (int l = 0; l < nl; ++l) {
          const uint64_t r = rng_bits({80, uint32_t(i), uint32_t(l), 0, 3});
          if (r & 1) bits.bytes[i * size_t((nl + 7) / 8) + size_t(l / 8)] |= uint8_t(1u << (l % 8));
          planes.bytes[size_t(l) * n + i] = uint8_t((r >> 8) % 201);
          fractions[size_t(l) * n + i] = (r >> 16 & 3) == 0 ? 0.0f : u(i, 20 + uint32_t(l));
        }
      }
    auto expect = [&](const ImageRGB8& img, auto&& vis_at, auto&& ao_at, const char* what) {
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          const size_t i = size_t(y) * size_t(w) + size_t(x);
          Rgb8 want = tonemap_srgb8(s.background);
          if (g.covered(x, y)) {
            glm::vec3 nrm = g.normal(x, y);
            if (!(glm::dot(nrm, nrm) > 0.0f)) nrm = g.geo_normal(x, y);
            want = tonemap_srgb8(shade_lambert(s, g.albedo(x, y), g.position(x, y), nrm, PixelTerms{ao_at(i)},
                                               [&](size_t l) { return vis_at(l, i); }));
          }
          ASSERT_EQ(img(x, y), want) << what << " width " << w << " at " << x << "," << y;
        }
    };
    const size_t bpp = size_t((nl + 7) / 8);
    auto ao_byte = [&](size_t i) { return std::min(1.0f, float(ao.bytes[i]) * (1.0f / 8.0f)); };
    expect(
        composite(g, s, &bits, &ao),
        [&](size_t l, size_t i) { return float((bits.bytes[i * bpp + (l >> 3)] >> (l & 7)) & 1u); }, ao_byte,
        "bitmask");
    expect(
        composite(g, s, &planes, nullptr),
        [&](size_t l, size_t i) { return std::min(1.0f, float(planes.bytes[l * n + i]) * (1.0f / 200.0f)); },
        [](size_t) { return 1.0f; }, "planes");
    const CompositeFractions est[] = {{PassMeaning::Visibility, fractions}, {PassMeaning::Ao, ao_fractions}};
    expect(
        composite_fractions(g, s, est), [&](size_t l, size_t i) { return fractions[l * n + i]; },
        [&](size_t i) { return ao_fractions[i]; }, "fractions");
  }
}

TEST(Composite, RowKernelMatchesShadeLambert) {
  for (const bool row_path : {false, true}) {
    composite_row_path_only(row_path);
    for (const int copies : {1, 2}) expect_composite_matches_shade_lambert(copies);
  }
  composite_row_path_only(false);
}

// The tone map of many values (16 at a time where the CPU has AVX-512, by arithmetic and a
// lookup only near a code boundary) gives each value's code one at a time: every float from
// 2^-14 to 2, and the values outside it. (On a CPU without AVX-512 both sides are the
// one-at-a-time code.)
TEST(Composite, ToneMapManyMatchesOneAtATime) {
  std::vector<float> v;
  for (float x :
       {0.0f, -0.0f, -1.0f, 1e-30f, 0x1p-13f, std::nextafter(0x1p-13f, 0.0f), 1.0f, std::nextafter(1.0f, 0.0f), 1e30f,
        std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(), std::nanf(""), -std::nanf(""),
        std::numeric_limits<float>::denorm_min(), 0.0031308f, std::nextafter(0.0031308f, 0.0f)})
    v.push_back(x);
  std::vector<uint8_t> codes;
  auto check = [&](const char* what) {
    codes.assign(v.size(), 0);
    tonemap_srgb8(v, codes);
    for (size_t i = 0; i < v.size(); ++i)
      if (codes[i] != tonemap_srgb8(v[i])) {
        ADD_FAILURE() << what << ": " << v[i] << " maps to " << int(codes[i]) << ", one at a time to "
                      << int(tonemap_srgb8(v[i]));
        return false;
      }
    return true;
  };
  ASSERT_TRUE(check("special values"));
  const uint32_t last = std::bit_cast<uint32_t>(2.0f);
  for (uint32_t bits = std::bit_cast<uint32_t>(0x1p-14f); bits <= last;) {
    v.clear();
    for (; bits <= last && v.size() < (1u << 20) + 5; ++bits)
      v.push_back(std::bit_cast<float>(bits));  // not a multiple of 16
    ASSERT_TRUE(check("the codes' range"));
  }
  EXPECT_THROW(tonemap_srgb8(v, std::span<uint8_t>(codes).first(1)), Error);
}

// ---- references ----

// DHR_MAX_ISA caps the kernels Embree traverses with (core/trace/rt_scene.h); embree_isa()
// names the ones it picks, and Embree agrees: its native 16-wide packets exist only with AVX-512.
TEST(EmbreeIsa, CapIsCheckedAndApplied) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  const auto native16 = [](const RtScene& rt) {
    return rtcGetDeviceProperty(rt.device(), RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED) != 0;
  };
  // "embree <version> <isa>[ rcp:<signature>]": the ISA, and the rcpps signature below AVX-512.
  const auto tracer_isa = [](const std::string& t) {
    const size_t a = t.find(' ', t.find(' ') + 1) + 1;
    return t.substr(a, t.find(' ', a) - a);
  };
  const auto check_rcp = [](const std::string& t, const std::string& isa) {
    const std::string rcp = " rcp:" + cpu_rcp_signature();
    EXPECT_EQ(t.ends_with(rcp), isa != "avx512") << t;
  };
  ScopedEnv unset("DHR_MAX_ISA", "");  // empty: as unset (ctest may run this with a cap)
  const std::string best = embree_isa();
  {
    RtScene rt(s);
    EXPECT_EQ(tracer_isa(rt.tracer()), best);
    check_rcp(rt.tracer(), best);
    EXPECT_EQ(native16(rt), best == "avx512") << rt.tracer();
  }
  for (const char* isa : {"sse2", "avx2"}) {
    ScopedEnv cap("DHR_MAX_ISA", isa);
    const std::string got = embree_isa();
    if (std::string(isa) == "sse2" || best == "avx512") {
      EXPECT_EQ(got, isa);
    }
    RtScene rt(s);
    EXPECT_EQ(tracer_isa(rt.tracer()), got);
    check_rcp(rt.tracer(), got);
    EXPECT_FALSE(native16(rt)) << rt.tracer();
    // It still traces: a ray down onto the plane hits it.
    const GBuffer g = rt.primary_gbuffer(cam({0, 3, 4}, {0, 0, 0}), 0.0);
    EXPECT_EQ(g.object_id(g.width() / 2, g.height() / 2), 1u) << isa;
  }
  for (const char* bad : {"avx3", "AVX2", "avx2 ", "isa=avx2"}) {
    ScopedEnv cap("DHR_MAX_ISA", bad);
    const std::string message = test::error_of([] { embree_isa(); });
    EXPECT_NE(message.find("DHR_MAX_ISA"), std::string::npos) << bad << ": " << message;
    EXPECT_NE(message.find("sse2, sse4.2, avx, avx2, avx512"), std::string::npos) << message;
    EXPECT_EQ(test::error_of([&] { RtScene rt(s); }), message);
  }
  EXPECT_EQ(embree_isa(), best);
}

// The cap reaches dhrbench's own kernels too (ctest runs this binary under DHR_MAX_ISA=avx2:
// test_trace_avx2), read as the process started.
TEST(EmbreeIsa, CapReachesDhrbenchKernels) {
  const Isa cap = usable_isa();
  std::printf("DHR_MAX_ISA: %s; usable ISA %s\n", std::getenv("DHR_MAX_ISA") ? std::getenv("DHR_MAX_ISA") : "(unset)",
              isa_name(cap));
#if DHR_AVX512_KERNELS
  if (cap < Isa::kAvx512) {
    EXPECT_FALSE(cpu_has_avx512dq());
  }
#endif
  EXPECT_EQ(trace_detail::cpu_has_avx2(), cap >= Isa::kAvx2);
  EXPECT_EQ(kernels_may_use(Isa::kAvx512), cap >= Isa::kAvx512);
  // The kernels' cap is the variable as the process started; a later value caps Embree only.
  ScopedEnv later("DHR_MAX_ISA", "sse2");
  EXPECT_EQ(usable_isa(), Isa::kSse2);
  EXPECT_TRUE(isa_capped());
  EXPECT_EQ(kernels_may_use(Isa::kAvx2), cap >= Isa::kAvx2);
}

TEST(Reference, GroundTruthIsCachedAndKeyed) {
  Scene s = base_scene();
  s.objects.push_back(make_object(1, make_plane(20.0f, 20.0f), glm::vec3(0.0f)));
  s.objects.push_back(make_object(2, make_box({1, 1, 1}), glm::vec3(0.0f, 0.5f, 0.0f)));
  s.lights.push_back(sphere_light({1, 4, 1}, 0.5f));
  s.ao = AoSettings{1.0f, 8};
  RtScene rt(s);
  const GBuffer g = rt.primary_gbuffer(cam({0, 3, 4}, {0, 0.3f, 0}), 0.0);
  // Per process: ctest runs this binary twice at once (as itself and under DHR_MAX_ISA=avx2),
  // and a shared folder would be emptied by one run while the other writes to it.
  const auto dir = std::filesystem::temp_directory_path() / ("dhr_test_reference_cache_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  ReferenceSettings rs;
  rs.ao_rays = 64;
  rs.samples_per_light = 32;
  rs.cache_dir = dir.string();
  const ReferenceResult a = ground_truth(rt, g, rs);
  EXPECT_FALSE(a.from_cache);
  EXPECT_GT(a.stats.ao_rays, 0u);
  EXPECT_GT(a.stats.shadow_rays, 0u);
  EXPECT_TRUE(std::filesystem::exists(a.path));
  const ReferenceResult b = ground_truth(rt, g, rs);
  EXPECT_TRUE(b.from_cache);
  EXPECT_EQ(b.stats.ao_rays, 0u);
  EXPECT_EQ(a.image, b.image);
  // A damaged file (a write cut short; a flipped bit, found by PNG's CRC-32 per chunk) is
  // computed again and replaced, not an error: processes on several machines share the folder.
  const std::string good = [&] {
    std::ifstream in(a.path, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  }();
  std::string flipped = good;
  flipped[flipped.size() / 2] ^= 0x04;
  for (const std::string& damaged : {good.substr(0, good.size() / 2), flipped}) {
    std::ofstream(a.path, std::ios::binary) << damaged;
    const ReferenceResult c = ground_truth(rt, g, rs);
    EXPECT_FALSE(c.from_cache);
    EXPECT_EQ(c.image, a.image);
    EXPECT_TRUE(ground_truth(rt, g, rs).from_cache);
  }
  // Any input change is a different key.
  ReferenceSettings rs2 = rs;
  rs2.ao_rays = 65;
  EXPECT_EQ(reference_key(s, g, rs, rt.tracer()), a.key);
  EXPECT_NE(reference_key(s, g, rs2, rt.tracer()), a.key);
  Scene s2 = s;
  s2.lights[0].intensity = 11.0f;
  EXPECT_NE(reference_key(s2, g, rs, rt.tracer()), a.key);
  GBuffer g2 = g;
  g2.time_s = 0.5;
  EXPECT_NE(reference_key(s, g2, rs, rt.tracer()), a.key);
  // The samples' kind (ReferenceRays::lattice) too; both images are cached, and differ.
  ReferenceSettings random = rs;
  random.lattice = !rs.lattice;
  EXPECT_NE(reference_key(s, g, random, rt.tracer()), a.key);
  const ReferenceResult other_kind = ground_truth(rt, g, random);
  EXPECT_FALSE(other_kind.from_cache);
  EXPECT_NE(other_kind.image, a.image);
  EXPECT_TRUE(ground_truth(rt, g, random).from_cache);
  // Another Embree ISA is another entry: a folder shared by two CPU kinds never hands one the
  // other's image (their kernels can answer a ray on an edge differently).
  EXPECT_NE(reference_key(s, g, rs, rt.tracer() + "x"), a.key);
  const std::string isa = embree_isa();
  {
    ScopedEnv cap("DHR_MAX_ISA", isa == "sse2" ? "sse4.2" : "sse2");
    if (embree_isa() != isa) {  // else this CPU has no other ISA to compare with
      RtScene other(s);
      const ReferenceResult d = ground_truth(other, g, rs);
      EXPECT_NE(d.key, a.key);
      EXPECT_FALSE(d.from_cache);
      EXPECT_TRUE(ground_truth(other, g, rs).from_cache);
    }
  }
  // The converged image is close to the local reference with the scene's own settings, and
  // the local reference is exactly trace + composite.
  TraceSettings ts;
  const ImageRGB8 local = local_reference(rt, g, ts);
  const TraceResult r = trace_passes(rt, g, ts);
  EXPECT_EQ(local, composite(g, s, r.find("visibility"), r.find("ao")));
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace dhr
