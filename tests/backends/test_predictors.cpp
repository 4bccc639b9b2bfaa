// Predictors: reprojection and rotation_warp on small synthetic G-buffers, plus conformance
// tests over every registered predictor (one test per predictor, by name). The G-buffers come
// from a tiny analytic scene (a finite ground plane and boxes) intersected with
// Camera::primary_ray, so no rasterizer is needed and every pixel's world point is known exactly.
#include "backends/predict/warp.h"
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "core/base/checksum.h"
#include "core/base/rng.h"
#include "core/buffers/depth_pass.h"

#include <fmt/format.h>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtx/rotate_vector.hpp>
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <limits>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace dhr {
namespace {

constexpr int kW = 64, kH = 48;
constexpr uint32_t kGroundId = 1, kBoxId = 2;

// ---------------------------------------------------------------- the analytic scene

struct Box {
  glm::vec3 lo, hi;
  uint32_t id;
};

struct Scene {
  float ground_half_m = 20.0f;  // ground: y = 0, |x|, |z| <= half
  std::vector<Box> boxes{{{-1.3f, 0.0f, -1.1f}, {0.9f, 2.3f, 1.2f}, kBoxId}};
};

struct Hit {
  float t = INFINITY;
  glm::vec3 normal{0.0f};
  uint32_t id = kBackgroundId;
};

Hit intersect(const Scene& s, const Ray& r) {
  Hit h;
  if (r.direction.y != 0.0f) {
    const float t = -r.origin.y / r.direction.y;
    const glm::vec3 p = r.origin + t * r.direction;
    if (t > 1e-4f && std::fabs(p.x) <= s.ground_half_m && std::fabs(p.z) <= s.ground_half_m)
      h = {t, {0.0f, r.direction.y < 0.0f ? 1.0f : -1.0f, 0.0f}, kGroundId};
  }
  for (const Box& b : s.boxes) {  // slabs; the camera is outside every box
    float t0 = -INFINITY, t1 = INFINITY;
    int axis = -1;
    for (int a = 0; a < 3; ++a) {
      if (r.direction[a] == 0.0f) {
        if (r.origin[a] < b.lo[a] || r.origin[a] > b.hi[a]) t0 = INFINITY;
        continue;
      }
      float ta = (b.lo[a] - r.origin[a]) / r.direction[a], tb = (b.hi[a] - r.origin[a]) / r.direction[a];
      if (ta > tb) std::swap(ta, tb);
      if (ta > t0) {
        t0 = ta;
        axis = a;
      }
      t1 = std::min(t1, tb);
    }
    if (axis >= 0 && t0 <= t1 && t0 > 1e-4f && t0 < h.t) {
      glm::vec3 n(0.0f);
      n[axis] = r.direction[axis] > 0.0f ? -1.0f : 1.0f;
      h = {t0, n, b.id};
    }
  }
  return h;
}

GBuffer render(const Scene& s, const Camera& cam) {
  GBuffer g;
  g.camera = cam;
  g.resize(cam.width, cam.height);
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const Ray r = cam.primary_ray(float(x) + 0.5f, float(y) + 0.5f);
      const Hit h = intersect(s, r);
      if (h.id == kBackgroundId) continue;
      const glm::vec3 p = r.origin + h.t * r.direction;
      g.position(x, y) = p;
      g.depth(x, y) = cam.view_depth(p);
      g.normal(x, y) = h.normal;
      g.geo_normal(x, y) = h.normal;
      g.albedo(x, y) = glm::vec3(0.5f);
      g.object_id(x, y) = h.id;
    }
  return g;
}

Camera look(const glm::vec3& eye, const glm::vec3& target, const glm::vec3& up = {0, 1, 0}, int w = kW, int h = kH) {
  return Camera::look_at(eye, target, up, 60.0f, w, h, 0.05f, 100.0f);
}

Camera oblique() { return look({0.5f, 3.5f, 5.5f}, {0.0f, 0.8f, 0.0f}); }
Camera translated(Camera c, const glm::vec3& d) {
  c.position += d;
  return c;
}

// ---------------------------------------------------------------- painted server buffers

// AO painted on the world: a 1 m checker, different values on ground and box, never 255
// (255 is the local fallback, so a 255 at a covered pixel marks a disocclusion).
uint8_t ao_value(const glm::vec3& p, uint32_t id) {
  const int c = (int(std::floor(p.x)) + int(std::floor(p.y)) + int(std::floor(p.z))) & 1;
  return id == kGroundId ? (c ? 60 : 180) : (c ? 20 : 100);
}

PassBuffer make_ao(const GBuffer& g, int full_scale = 255) {
  PassBuffer b;
  b.desc = {PassKind::Ao, g.width(), g.height(), 1, full_scale};
  b.bytes.resize(b.desc.byte_size());
  for (size_t i = 0; i < g.object_id.size(); ++i)
    b.bytes[i] = g.object_id[i] == kBackgroundId ? uint8_t(full_scale)
                                                 : uint8_t(ao_value(g.position[i], g.object_id[i]) * full_scale / 255);
  return b;
}

// A server-like buffer of any kind: random values at covered pixels, fully lit at the
// background (what the server writes where it traces no ray).
PassBuffer make_random(const GBuffer& g, PassKind kind, int channels, int full_scale, uint64_t seed) {
  PassBuffer b;
  b.desc = {kind, g.width(), g.height(), channels, full_scale};
  b.bytes.resize(b.desc.byte_size());
  const size_t n = g.object_id.size();
  for (size_t i = 0; i < n; ++i) {
    const bool bg = g.object_id[i] == kBackgroundId;
    const uint64_t r = rng_bits({seed, uint32_t(i), 0, 0, 7});
    switch (pass_layout(kind)) {
      case PassLayout::Bitmask: {
        const int bpp = (channels + 7) / 8;
        const uint64_t mask = channels >= 64 ? ~0ull : (1ull << channels) - 1;
        const uint64_t v = bg ? mask : (r & mask);
        for (int k = 0; k < bpp; ++k) b.bytes[i * bpp + k] = uint8_t(v >> (8 * k));
        break;
      }
      case PassLayout::Planes8:
        for (int c = 0; c < channels; ++c)
          b.bytes[size_t(c) * n + i] = bg ? uint8_t(full_scale) : uint8_t((r >> (8 * c)) % uint64_t(full_scale + 1));
        break;
      case PassLayout::Rgb8:
        for (int c = 0; c < 3; ++c) b.bytes[i * 3 + c] = uint8_t(r >> (8 * c));
        break;
      case PassLayout::Code16:
        for (int c = 0; c < 2; ++c) b.bytes[size_t(c) * n + i] = uint8_t(r >> (8 * c));
        break;
    }
  }
  return b;
}

std::unique_ptr<Predictor> make(const std::string& name, const nlohmann::json& params = nlohmann::json::object()) {
  return registries().predictors.create(name, params);
}

size_t covered_count(const GBuffer& g) {
  size_t c = 0;
  for (uint32_t id : g.object_id.pixels()) c += id != kBackgroundId;
  return c;
}

template <class F>
void with_threads(int n, F&& f) {
  tbb::task_arena arena(n);
  arena.execute(f);
}

// ---------------------------------------------------------------- reprojection

TEST(Reprojection, IdentityReturnsInputExactlyForEveryPassKind) {
  const GBuffer g = render(Scene{}, oblique());
  const GBuffer g2 = g;  // a distinct but equal dst
  struct Case {
    PassKind kind;
    int channels, full_scale;
  };
  const Case cases[] = {{PassKind::Visibility, 4, 255},
                        {PassKind::Visibility, 40, 255},
                        {PassKind::Visibility, 64, 255},
                        {PassKind::SoftVisibility, 3, 255},
                        {PassKind::SoftVisibility, 2, 16},
                        {PassKind::Ao, 1, 8},
                        {PassKind::Ao, 1, 255}};
  for (const char* filter : {"nearest", "bilinear"})
    for (const char* fill : {"nearest_valid", "local"}) {
      auto p = make("reprojection", {{"filter", filter}, {"fill", fill}});
      for (const Case& c : cases) {
        const PassBuffer in = make_random(g, c.kind, c.channels, c.full_scale, 11);
        PassBuffer out;
        const PredictStats st = p->predict({in, g, g2}, out);
        SCOPED_TRACE(
            fmt::format("{} {} ch {} fs {} {}", filter, fill, c.channels, c.full_scale, pass_kind_name(c.kind)));
        EXPECT_EQ(out.desc, in.desc);
        EXPECT_TRUE(out.bytes == in.bytes);
        EXPECT_EQ(st.disoccluded, 0u);
        EXPECT_EQ(st.pixels, covered_count(g));
      }
    }
}

// A top-down camera moved by exactly 3 ground-pixel footprints: every ground point lands on a
// pixel centre of the source, so nearest reprojection must find the painted value again.
TEST(Reprojection, CameraTranslationFindsWorldPaintedValuesAgain) {
  const Scene scene;
  const Camera c0 = look({0.0f, 10.0f, 0.0f}, {0.0f, 0.0f, 0.0f}, {0, 0, -1});
  const float footprint_m = 2.0f * 10.0f * std::tan(glm::radians(30.0f)) / float(kH);
  const Camera c1 = translated(c0, c0.right() * (3.0f * footprint_m));
  const GBuffer src = render(scene, c0), dst = render(scene, c1);
  const PassBuffer in = make_ao(src);
  PassBuffer out;
  const PredictStats st =
      make("reprojection", {{"filter", "nearest"}, {"fill", "local"}})->predict({in, src, dst}, out);
  ASSERT_EQ(out.desc, in.desc);
  size_t kept = 0, exact = 0, filled = 0;
  for (size_t i = 0; i < out.bytes.size(); ++i) {
    if (dst.object_id[i] == kBackgroundId) {
      EXPECT_EQ(out.bytes[i], 255);
      continue;
    }
    if (out.bytes[i] == 255) {
      ++filled;
      continue;
    }
    ++kept;
    exact += out.bytes[i] == ao_value(dst.position[i], dst.object_id[i]);
  }
  EXPECT_EQ(filled, st.disoccluded);
  EXPECT_EQ(st.pixels, covered_count(dst));
  // The 3 columns entering on the right were off-screen in the source.
  EXPECT_GE(st.disoccluded, 3u * kH);
  EXPECT_LT(st.disoccluded, 6u * kH);
  ASSERT_GT(kept, size_t(kW * kH / 2));
  EXPECT_GE(double(exact), 0.99 * double(kept)) << exact << " of " << kept;
}

// The ray from the src camera to P is blocked by something closer than P.
bool hidden_from(const Scene& s, const Camera& cam, const glm::vec3& p) {
  const glm::vec3 d = p - cam.position;
  const float dist = glm::length(d);
  const Hit h = intersect(s, {cam.position, d / dist});
  return h.t < dist * (1.0f - 1e-3f);
}

struct Located {
  size_t disoccluded = 0, explained = 0, visible_disoccluded = 0, deep_hidden = 0, deep_hidden_disoccluded = 0,
         offscreen = 0;
};

// Classifies every covered dst pixel: disoccluded (output 255), hidden from the src camera,
// off-screen in src, and whether the 3x3 source pixels around its projection all show
// another object ("deep" inside the old silhouette).
Located locate(const Scene& scene, const GBuffer& src, const GBuffer& dst, const PassBuffer& out) {
  Located r;
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      const uint32_t id = dst.object_id(x, y);
      if (id == kBackgroundId) continue;
      const bool dis = out.bytes[size_t(y) * kW + x] == 255;
      const glm::vec3 p = dst.position(x, y);
      const glm::vec3 q = src.camera.project(p);
      const bool offscreen = !(q.z > 0.0f && q.x >= 0.0f && q.x < kW && q.y >= 0.0f && q.y < kH);
      const bool hidden = hidden_from(scene, src.camera, p);
      bool any_other = false, all_other = !offscreen;
      if (!offscreen) {
        const int qx = int(q.x), qy = int(q.y);
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const int sx = std::clamp(qx + dx, 0, kW - 1), sy = std::clamp(qy + dy, 0, kH - 1);
            const bool other = src.object_id(sx, sy) != id;
            any_other |= other;
            all_other &= other;
          }
      }
      r.offscreen += offscreen && dis;
      if (dis) {
        ++r.disoccluded;
        r.explained += hidden || offscreen || any_other;
        r.visible_disoccluded += !hidden && !offscreen;
      }
      if (hidden && all_other) {
        ++r.deep_hidden;
        r.deep_hidden_disoccluded += dis;
      }
    }
  return r;
}

TEST(Reprojection, DisocclusionsLieWhereTheBoxUncoveredTheGround) {
  const Scene scene;
  const Camera c0 = oblique();
  const Camera c1 = translated(c0, {2.0f, 0.0f, 0.0f});
  const GBuffer src = render(scene, c0), dst = render(scene, c1);
  const PassBuffer in = make_ao(src);
  PassBuffer local_out, nearest_out;
  const PredictStats st_local = make("reprojection", {{"fill", "local"}})->predict({in, src, dst}, local_out);
  const Located loc = locate(scene, src, dst, local_out);
  EXPECT_EQ(loc.disoccluded, st_local.disoccluded);
  EXPECT_GT(st_local.disoccluded, loc.offscreen + 10) << "no disocclusion besides the screen edge";
  EXPECT_EQ(loc.explained, loc.disoccluded) << "disoccluded pixels away from the box's old silhouette";
  EXPECT_LE(loc.visible_disoccluded, 5u) << "points the src camera saw, reported as disoccluded";
  EXPECT_GT(loc.deep_hidden, 10u) << "the test scene should uncover ground behind the box";
  EXPECT_EQ(loc.deep_hidden_disoccluded, loc.deep_hidden) << "hidden ground reported as valid";

  // nearest_valid: the same pixels are disoccluded; each is filled from a source pixel of its
  // own object (painted values of that object), or by the fallback when none is in reach.
  const PredictStats st_near =
      make("reprojection", {{"fill", "nearest_valid"}, {"fill_radius_px", 3}})->predict({in, src, dst}, nearest_out);
  EXPECT_EQ(st_near.disoccluded, st_local.disoccluded);
  size_t filled_from_source = 0;
  for (size_t i = 0; i < in.bytes.size(); ++i) {
    if (local_out.bytes[i] != 255 || dst.object_id[i] == kBackgroundId) {
      EXPECT_EQ(nearest_out.bytes[i], local_out.bytes[i]) << "pixel " << i;
      continue;
    }
    const uint8_t v = nearest_out.bytes[i];
    if (v == 255) continue;
    ++filled_from_source;
    if (dst.object_id[i] == kGroundId)
      EXPECT_TRUE(v == 60 || v == 180) << "ground pixel " << i << " filled with " << int(v);
    else
      EXPECT_TRUE(v == 20 || v == 100) << "box pixel " << i << " filled with " << int(v);
  }
  EXPECT_GT(filled_from_source, loc.deep_hidden / 2);
}

TEST(Reprojection, BitmasksAreNeverBlended) {
  const Scene scene;
  const Camera c0 = oblique();
  const GBuffer src = render(scene, c0);
  for (const glm::vec3& move : {glm::vec3(0.7f, 0.0f, 0.0f), glm::vec3(-0.3f, 0.4f, 0.5f)}) {
    const GBuffer dst = render(scene, translated(c0, move));
    for (int lights : {4, 40}) {
      const PassBuffer in = make_random(src, PassKind::Visibility, lights, 255, 5);
      const int bpp = (lights + 7) / 8;
      auto value = [&](const std::vector<uint8_t>& b, size_t i) {
        uint64_t v = 0;
        for (int k = 0; k < bpp; ++k) v |= uint64_t(b[i * bpp + k]) << (8 * k);
        return v;
      };
      std::set<uint64_t> source_values;
      for (size_t i = 0; i < src.object_id.size(); ++i) source_values.insert(value(in.bytes, i));
      const uint64_t lit = (uint64_t(1) << lights) - 1;
      for (const char* fill : {"nearest_valid", "local"}) {
        PassBuffer out;
        const PredictStats st =
            make("reprojection", {{"filter", "bilinear"}, {"fill", fill}})->predict({in, src, dst}, out);
        ASSERT_EQ(out.bytes.size(), in.bytes.size());
        EXPECT_GT(st.disoccluded, 0u);
        size_t foreign = 0;
        for (size_t i = 0; i < dst.object_id.size(); ++i) {
          const uint64_t v = value(out.bytes, i);
          if (dst.object_id[i] == kBackgroundId)
            EXPECT_EQ(v, lit);
          else
            foreign += v != lit && !source_values.count(v);
        }
        EXPECT_EQ(foreign, 0u) << lights << " lights, fill " << fill;
      }
    }
  }
}

// Planes of a SoftVisibility buffer share one mapping: plane 1 = full - plane 0 stays so.
TEST(Reprojection, SoftVisibilityPlanesMoveTogether) {
  const Scene scene;
  const GBuffer src = render(scene, oblique()), dst = render(scene, translated(oblique(), {0.5f, 0.2f, 0.0f}));
  PassBuffer in = make_random(src, PassKind::SoftVisibility, 2, 200, 3);
  const size_t n = size_t(kW) * kH;
  for (size_t i = 0; i < n; ++i) in.bytes[n + i] = uint8_t(200 - in.bytes[i]);
  PassBuffer out;
  make("reprojection", {{"filter", "nearest"}})->predict({in, src, dst}, out);
  ASSERT_EQ(out.bytes.size(), 2 * n);
  size_t checked = 0;
  for (size_t i = 0; i < n; ++i) {
    if (dst.object_id[i] == kBackgroundId || (out.bytes[i] == 200 && out.bytes[n + i] == 200)) continue;  // lit
    ASSERT_EQ(out.bytes[n + i], 200 - out.bytes[i]) << i;
    ++checked;
  }
  EXPECT_GT(checked, n / 2);
}

TEST(Reprojection, GarbageInBackgroundPixelsChangesNothing) {
  const Scene scene;
  const GBuffer src = render(scene, oblique()), dst = render(scene, translated(oblique(), {1.0f, 0.3f, -0.5f}));
  auto dirty = [](GBuffer g) {
    const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
    for (size_t i = 0; i < g.object_id.size(); ++i) {
      if (g.object_id[i] != kBackgroundId) continue;
      g.position[i] = glm::vec3(nan, inf, -inf);
      g.normal[i] = glm::vec3(inf, nan, 0.0f);
      g.geo_normal[i] = glm::vec3(nan);
      g.depth[i] = nan;
      g.motion[i] = glm::vec2(nan);
    }
    return g;
  };
  const GBuffer src_dirty = dirty(src), dst_dirty = dirty(dst);
  for (PassKind kind : {PassKind::Ao, PassKind::Visibility, PassKind::SoftVisibility}) {
    const PassBuffer in = make_random(src, kind, kind == PassKind::Ao ? 1 : 3, 255, 9);
    for (const char* filter : {"nearest", "bilinear"}) {
      auto p = make("reprojection", {{"filter", filter}});
      PassBuffer clean_out, dirty_out;
      const PredictStats a = p->predict({in, src, dst}, clean_out);
      const PredictStats b = p->predict({in, src_dirty, dst_dirty}, dirty_out);
      EXPECT_TRUE(clean_out.bytes == dirty_out.bytes) << pass_kind_name(kind) << " " << filter;
      EXPECT_EQ(a.disoccluded, b.disoccluded);
      EXPECT_EQ(a.pixels, b.pixels);
    }
  }
  // A covered dst pixel with non-finite data and a covered src pixel with a broken normal:
  // no crash, the dst pixel counts as disoccluded and gets the local fallback.
  GBuffer dst_bad = dst_dirty, src_bad = src_dirty;
  const int bx = kW / 2, by = kH - 3;
  ASSERT_NE(dst_bad.object_id(bx, by), kBackgroundId);
  dst_bad.position(bx, by) = glm::vec3(std::numeric_limits<float>::quiet_NaN());
  src_bad.normal(bx, by) = glm::vec3(std::numeric_limits<float>::infinity());
  const PassBuffer in = make_ao(src);
  PassBuffer out_ref, out_bad;
  auto p = make("reprojection");
  const PredictStats ref = p->predict({in, src, dst}, out_ref);
  const PredictStats bad = p->predict({in, src_bad, dst_bad}, out_bad);
  EXPECT_EQ(out_bad.bytes[size_t(by) * kW + bx], 255);
  EXPECT_GE(bad.disoccluded, ref.disoccluded + 1);
}

TEST(Reprojection, RefusesMismatchedSizesColourAndMalformedBuffers) {
  const Scene scene;
  const GBuffer big = render(scene, oblique());
  const GBuffer small = render(scene, look({0.5f, 4.0f, 9.0f}, {0.0f, 0.5f, 0.0f}, {0, 1, 0}, 32, 24));
  auto p = make("reprojection");
  auto message = [&](const PassBuffer& in, const GBuffer& s, const GBuffer& d) -> std::string {
    PassBuffer out;
    try {
      p->predict({in, s, d}, out);
    } catch (const Error& e) {
      return e.what();
    }
    return "(no error)";
  };
  const PassBuffer in_big = make_ao(big), in_small = make_ao(small);
  for (const std::string& m : {message(in_big, big, small), message(in_small, big, big), message(in_big, small, big)}) {
    EXPECT_NE(m.find("64x48"), std::string::npos) << m;
    EXPECT_NE(m.find("32x24"), std::string::npos) << m;
    EXPECT_NE(m.find("reprojection"), std::string::npos) << m;
  }
  GBuffer wrong_camera = big;
  wrong_camera.camera.width = 1280;
  EXPECT_NE(message(in_big, big, wrong_camera).find("camera is 1280x48"), std::string::npos);
  const std::string colour = message(make_random(big, PassKind::Colour, 3, 255, 1), big, big);
  EXPECT_NE(colour.find("refuses a colour buffer"), std::string::npos) << colour;
  PassBuffer short_buf = in_big;
  short_buf.bytes.pop_back();
  EXPECT_NE(message(short_buf, big, big).find("bytes"), std::string::npos);
}

TEST(Reprojection, SameResultAtOneAndTwoThreadsAndWhenOutputAliasesInput) {
  const Scene scene;
  const GBuffer src = render(scene, oblique()), dst = render(scene, translated(oblique(), {1.2f, -0.2f, 0.4f}));
  for (PassKind kind : {PassKind::Ao, PassKind::Visibility, PassKind::SoftVisibility}) {
    const PassBuffer in = make_random(src, kind, kind == PassKind::Ao ? 1 : 5, 255, 21);
    auto p = make("reprojection");
    PassBuffer out1, out2;
    PredictStats s1, s2;
    with_threads(1, [&] { s1 = p->predict({in, src, dst}, out1); });
    with_threads(2, [&] { s2 = p->predict({in, src, dst}, out2); });
    EXPECT_TRUE(out1.bytes == out2.bytes) << pass_kind_name(kind);
    EXPECT_EQ(s1.disoccluded, s2.disoccluded);
    EXPECT_GT(s1.disoccluded, 0u);
    PassBuffer alias = in;
    p->predict({alias, src, dst}, alias);
    EXPECT_TRUE(alias.bytes == out1.bytes) << pass_kind_name(kind);
  }
}

// The tap tests on hard inputs, pinned: src and dst G-buffers perturbed so that many taps sit
// at the edges of the tests (normals near the threshold angle and the length limits, zero and
// NaN normals, geometric normals missing so that the depth fallback decides, points near the
// tolerance from the tap's plane, mixed ids, NaN dst points), predicted with thresholds of
// either sign and two tolerances, bilinear and nearest, an AO pass and a bitmask together.
// The CRC-32C of every output byte and statistic is pinned (recorded at commit 5950420): a
// faster tap test must decide every tap the same way. (Checked: the test fails when the plane
// test loses a factor z, the length range its equality, or the depth fallback or either
// threshold branch moves by a few per cent.)
TEST(Reprojection, HardTapTestsKeepTheirBits) {
  const Scene scene;
  auto u = [](uint64_t seed, size_t i, uint32_t dim) { return rng_uniform(RngKey{seed, uint32_t(i), 0, 0, 9}, dim); };
  auto roughen = [&](GBuffer& g, uint64_t seed, bool is_src) {
    for (size_t i = 0; i < g.object_id.size(); ++i) {
      if (g.object_id[i] == kBackgroundId) continue;
      const float pick = u(seed, i, 0);
      glm::vec3 n = g.normal[i];
      // Tilt about a random axis by up to 40 degrees (the threshold 0.9 is 25.8 degrees), or for
      // a quarter of the pixels by 90-125 degrees (-0.3 is 107.5), and scale the length across
      // the accepted [0.5, 2] (squared [0.25, 4]).
      const glm::vec3 axis = glm::normalize(
          glm::vec3(u(seed, i, 1) - 0.5f, u(seed, i, 2) - 0.5f, u(seed, i, 3) - 0.5f) + glm::vec3(1e-3f));
      const float tilt = u(seed, i, 12) < 0.25f ? 90.0f + 35.0f * u(seed, i, 4) : 40.0f * u(seed, i, 4);
      n = glm::rotate(n, glm::radians(tilt), axis) * (0.45f + 1.65f * u(seed, i, 5));
      if (pick < 0.03f) n = glm::vec3(0.0f);
      if (pick > 0.97f) n.y = NAN;
      g.normal[i] = n;
      if (!is_src) {
        if (u(seed, i, 6) < 0.02f) g.position[i].x = NAN;
        continue;
      }
      glm::vec3 geo = g.geo_normal[i] * (0.45f + 1.65f * u(seed, i, 7));
      if (u(seed, i, 8) < 0.2f) geo = glm::vec3(0.0f);  // the depth fallback decides
      g.geo_normal[i] = geo;
      // Off the plane by up to 1.5x a 0.02 tolerance of the view depth, either side.
      g.position[i] += g.geo_normal[i] * (0.06f * g.depth[i] * (u(seed, i, 9) - 0.5f));
      g.depth[i] *= 1.0f + 0.06f * (u(seed, i, 10) - 0.5f);
      if (u(seed, i, 11) < 0.05f) g.object_id[i] = g.object_id[i] == kBoxId ? kGroundId : kBoxId;
    }
  };
  for (bool scalar : {false, true}) {
    SCOPED_TRACE(scalar ? "scalar path" : "the CPU's path");
    predict::force_scalar_reprojection(scalar);
    std::vector<std::string> hashes;
    for (uint64_t seed : {1u, 2u}) {
      GBuffer src = render(scene, oblique());
      GBuffer dst = render(scene, translated(oblique(), {0.15f * float(seed), -0.05f, 0.1f}));
      roughen(src, seed, true);
      roughen(dst, seed + 10, false);
      const PassBuffer ao = make_random(src, PassKind::Ao, 1, 255, 40 + seed);
      const PassBuffer vis = make_random(src, PassKind::Visibility, 5, 1, 50 + seed);
      for (const nlohmann::json& params : {nlohmann::json::object(), nlohmann::json{{"normal_threshold", -0.3}},
                                           nlohmann::json{{"normal_threshold", 0.0}, {"depth_tolerance", 0.005}},
                                           nlohmann::json{{"filter", "nearest"}, {"fill", "local"}}}) {
        PassBuffer out_ao, out_vis;
        const PassBuffer* received[2] = {&ao, &vis};
        PassBuffer* out[2] = {&out_ao, &out_vis};
        const std::vector<PredictStats> st = make("reprojection", params)->predict_passes(src, dst, received, out);
        uint32_t crc = crc32c(out_ao.bytes);
        crc = crc32c(out_vis.bytes, crc);
        const uint64_t counts[2] = {st[0].pixels, st[0].disoccluded};
        crc = crc32c({reinterpret_cast<const uint8_t*>(counts), sizeof counts}, crc);
        EXPECT_GT(st[0].disoccluded, 20u) << "the perturbations must reject taps";
        hashes.push_back(fmt::format("{:08x}", crc));
      }
    }
    const std::vector<std::string> pinned = {"44182ed8", "b34a8075", "469f8242", "a885e2b0",
                                             "e4578a9e", "b958178f", "e9fac855", "0c9a0ab4"};
    EXPECT_EQ(hashes, pinned);
  }
  predict::force_scalar_reprojection(false);
}

// One pass of each layout the client predicts together: bitmasks of one and two bytes (5 and 12
// lights), soft visibility of three planes, AO; random bytes from seeds seed + 1 .. seed + 4.
std::vector<PassBuffer> pass_layouts(const GBuffer& src, uint64_t seed) {
  return {
      make_random(src, PassKind::Visibility, 5, 1, seed + 1), make_random(src, PassKind::Visibility, 12, 1, seed + 2),
      make_random(src, PassKind::SoftVisibility, 3, 64, seed + 3), make_random(src, PassKind::Ao, 1, 255, seed + 4)};
}

// A camera turned about its view axis by `deg` degrees, its vertical field of view scaled by
// `fov_scale`.
Camera rolled(Camera c, float deg, float fov_scale) {
  c.up = glm::normalize(glm::rotate(c.up, glm::radians(deg), c.forward));
  c.vfov_deg *= fov_scale;
  return c;
}

// The 16-lane path against the scalar one on every pass layout it writes or leaves to the
// lane-by-lane writes: bitmasks of one and two bytes, soft visibility of three planes, AO, each
// filter, predicted together. The dst cameras give each way the kernel reads a block's taps
// (plan_x16): moved (mostly side by side, or within one row of 32 columns), turned by 2 degrees
// (a block's taps on two rows) and by 20 with a wider view (over more than 32 columns or two
// rows: gathered). (On a CPU without AVX-512 both runs take the scalar path.)
TEST(Reprojection, SameBytesOnTheVectorAndScalarPaths) {
  const Scene scene;
  const GBuffer src = render(scene, oblique());
  const std::vector<PassBuffer> passes = pass_layouts(src, 60);
  const std::pair<const char*, Camera> cameras[] = {{"moved", translated(oblique(), {0.9f, -0.1f, 0.3f})},
                                                    {"rolled 2 degrees", rolled(oblique(), 2.0f, 1.0f)},
                                                    {"rolled 20 degrees, wider", rolled(oblique(), 20.0f, 1.6f)}};
  for (const auto& [camera, cam] : cameras) {
    const GBuffer dst = render(scene, cam);
    for (const char* filter : {"bilinear", "nearest"}) {
      std::vector<PassBuffer> outs[2];
      for (int scalar = 0; scalar < 2; ++scalar) {
        predict::force_scalar_reprojection(scalar == 1);
        outs[scalar].resize(passes.size());
        std::vector<const PassBuffer*> received;
        std::vector<PassBuffer*> out;
        for (size_t k = 0; k < passes.size(); ++k) {
          received.push_back(&passes[k]);
          out.push_back(&outs[scalar][k]);
        }
        make("reprojection", {{"filter", filter}})->predict_passes(src, dst, received, out);
      }
      predict::force_scalar_reprojection(false);
      for (size_t k = 0; k < passes.size(); ++k)
        EXPECT_TRUE(outs[0][k].bytes == outs[1][k].bytes) << filter << " pass " << k << ", dst camera " << camera;
    }
  }
}

// The client predicts the passes received for one frame in one call (Predictor::predict_passes):
// the taps are found once per pixel. Every pass must come out as when it is predicted alone, by
// an instance of its own: bitmasks of one and two bytes, soft visibility and AO of other full
// scales, each filter and fill, with disocclusions, and an output that is its own input.
TEST(Reprojection, PassesPredictedTogetherAreEachPredictedAlone) {
  const Scene scene;
  const GBuffer src = render(scene, oblique()), dst = render(scene, translated(oblique(), {1.2f, -0.2f, 0.4f}));
  const std::vector<PassBuffer> passes = pass_layouts(src, 30);
  for (const nlohmann::json& params : {nlohmann::json::object(), nlohmann::json{{"filter", "nearest"}},
                                       nlohmann::json{{"fill", "local"}}, nlohmann::json{{"fill_radius_px", 6}}}) {
    EXPECT_TRUE(make("reprojection", params)->predicts_passes_together());
    std::vector<PassBuffer> alone(passes.size());
    std::vector<PredictStats> alone_stats;
    for (size_t k = 0; k < passes.size(); ++k)
      alone_stats.push_back(make("reprojection", params)->predict({passes[k], src, dst}, alone[k]));
    // Each subset of two or more passes, the last one predicted in place.
    for (unsigned subset = 3; subset < (1u << passes.size()); ++subset) {
      if (std::popcount(subset) < 2) continue;
      std::vector<PassBuffer> together(passes.size());
      std::vector<const PassBuffer*> received;
      std::vector<PassBuffer*> out;
      std::vector<size_t> which;
      for (size_t k = 0; k < passes.size(); ++k)
        if (subset & (1u << k)) which.push_back(k);
      for (size_t k : which) {
        if (k == which.back()) together[k] = passes[k];
        received.push_back(k == which.back() ? &together[k] : &passes[k]);
        out.push_back(&together[k]);
      }
      const std::vector<PredictStats> stats = make("reprojection", params)->predict_passes(src, dst, received, out);
      ASSERT_EQ(stats.size(), which.size());
      for (size_t g = 0; g < which.size(); ++g) {
        const size_t k = which[g];
        EXPECT_EQ(together[k].desc, alone[k].desc) << params.dump() << " subset " << subset << " pass " << k;
        EXPECT_TRUE(together[k].bytes == alone[k].bytes) << params.dump() << " subset " << subset << " pass " << k;
        EXPECT_EQ(stats[g].pixels, alone_stats[k].pixels);
        EXPECT_EQ(stats[g].disoccluded, alone_stats[k].disoccluded);
      }
    }
    EXPECT_GT(alone_stats[0].disoccluded, 0u);
  }
  for (const char* other : {"none", "rotation_warp", "depth_warp"})
    EXPECT_FALSE(make(other)->predicts_passes_together()) << other;
}

// ---------------------------------------------------------------- rotation_warp

// The remote client has cameras only: G-buffers with no images.
GBuffer cameras_only(const Camera& c) {
  GBuffer g;
  g.camera = c;
  return g;
}

Camera yawed(const Camera& c, float deg) {
  const glm::mat3 r(glm::rotate(glm::mat4(1.0f), glm::radians(deg), glm::vec3(0, 1, 0)));
  Camera out = c;
  out.forward = glm::normalize(r * c.forward);
  out.up = glm::normalize(r * c.up);
  return out;
}

// r = 3 x + 20, g = 5 y, b = 7: the source column is readable from r.
PassBuffer ramp_colour(int w, int h) {
  PassBuffer b;
  b.desc = {PassKind::Colour, w, h, 3, 255};
  b.bytes.resize(b.desc.byte_size());
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      uint8_t* p = &b.bytes[(size_t(y) * w + x) * 3];
      p[0] = uint8_t(3 * x + 20);
      p[1] = uint8_t(5 * y);
      p[2] = 7;
    }
  return b;
}

TEST(RotationWarp, IdentityIsExactForEveryAcceptedKind) {
  const Camera c = look({1.0f, 2.0f, 3.0f}, {0.0f, 0.0f, 0.0f});
  const GBuffer g = cameras_only(c);
  const GBuffer scene_g = render(Scene{}, c);  // for the fully-lit background of lighting passes
  for (const char* fill : {"clamp", "black"}) {
    auto p = make("rotation_warp", {{"fill", fill}});
    for (const PassBuffer& in :
         {make_random(scene_g, PassKind::Colour, 3, 255, 2), make_random(scene_g, PassKind::Ao, 1, 255, 2),
          make_random(scene_g, PassKind::SoftVisibility, 3, 100, 2)}) {
      PassBuffer out;
      const PredictStats st = p->predict({in, g, g}, out);
      EXPECT_EQ(out.desc, in.desc);
      EXPECT_TRUE(out.bytes == in.bytes) << pass_kind_name(in.desc.kind) << " " << fill;
      EXPECT_EQ(st.disoccluded, 0u);
      EXPECT_EQ(st.pixels, uint64_t(kW) * kH);
    }
  }
}

TEST(RotationWarp, YawShiftsTheCentreByFocalTimesTan) {
  const Camera c0 = look({0.0f, 1.0f, 0.0f}, {0.0f, 1.0f, -5.0f});
  const PassBuffer in = ramp_colour(kW, kH);
  const float f_px = 0.5f * kH / std::tan(glm::radians(30.0f));
  for (float yaw_deg : {3.0f, -5.0f}) {
    const Camera c1 = yawed(c0, yaw_deg);
    PassBuffer out;
    make("rotation_warp")->predict({in, cameras_only(c0), cameras_only(c1)}, out);
    // dst pixel centre (31.5, 23.5) looks at angle atan(-0.5 / f) left of dst's axis; a yaw
    // of +a turns the camera left, so src sees it at that angle minus a.
    const float expected_x = 0.5f * kW + f_px * std::tan(std::atan(-0.5f / f_px) - glm::radians(yaw_deg));
    const uint8_t* px = &out.bytes[(size_t(23) * kW + 31) * 3];
    const float found_x = (float(px[0]) - 20.0f) / 3.0f + 0.5f;  // r = 3 (x_centre - 0.5) + 20
    EXPECT_NEAR(found_x, expected_x, 0.34f) << "yaw " << yaw_deg;
    EXPECT_NEAR(31.5f - found_x, f_px * std::tan(glm::radians(yaw_deg)), 0.4f) << "yaw " << yaw_deg;
    EXPECT_NEAR(px[1], 5 * 23, 1) << "a yaw must not move the centre row";
    EXPECT_EQ(px[2], 7);
  }
}

TEST(RotationWarp, OutsideTheSourceIsClampedOrBlack) {
  const Camera c0 = look({0.0f, 1.0f, 0.0f}, {0.0f, 1.0f, -5.0f});
  const Camera c1 = yawed(c0, 20.0f);  // turned left: the left part of dst was never seen
  const PassBuffer in = ramp_colour(kW, kH);
  PassBuffer clamp_out, black_out;
  const PredictStats sc =
      make("rotation_warp", {{"fill", "clamp"}})->predict({in, cameras_only(c0), cameras_only(c1)}, clamp_out);
  const PredictStats sb =
      make("rotation_warp", {{"fill", "black"}})->predict({in, cameras_only(c0), cameras_only(c1)}, black_out);
  EXPECT_EQ(sc.disoccluded, sb.disoccluded);
  EXPECT_GT(sb.disoccluded, uint64_t(5 * kH));
  size_t black = 0;
  for (int y = 0; y < kH; ++y) {
    const uint8_t* c = &clamp_out.bytes[size_t(y) * kW * 3];  // dst column 0
    const uint8_t* b = &black_out.bytes[size_t(y) * kW * 3];
    EXPECT_EQ(c[0], 20) << "clamped to the source's left edge (r = 20), row " << y;
    EXPECT_EQ(b[0] + b[1] + b[2], 0) << "row " << y;
    for (int x = 0; x < kW; ++x) {
      const uint8_t* q = &black_out.bytes[(size_t(y) * kW + x) * 3];
      black += q[0] == 0 && q[1] == 0 && q[2] == 0;
    }
  }
  EXPECT_EQ(black, sb.disoccluded);
  // The right part was seen: both fills agree there.
  for (int y = 0; y < kH; ++y)
    EXPECT_EQ(clamp_out.bytes[(size_t(y) * kW + kW - 1) * 3], black_out.bytes[(size_t(y) * kW + kW - 1) * 3]);
}

TEST(RotationWarp, RefusesBitmasksAndMismatchedSizesAndIsThreadCountIndependent) {
  const Camera c0 = look({0.0f, 1.0f, 0.0f}, {0.0f, 1.0f, -5.0f});
  auto p = make("rotation_warp");
  PassBuffer out;
  const GBuffer g = render(Scene{}, c0);
  try {
    p->predict({make_random(g, PassKind::Visibility, 4, 255, 1), g, g}, out);
    ADD_FAILURE() << "a bitmask was warped";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bitmask"), std::string::npos) << e.what();
  }
  const PassBuffer small = ramp_colour(32, 24);
  try {
    p->predict({small, cameras_only(c0), cameras_only(c0)}, out);
    ADD_FAILURE() << "a 32x24 buffer was warped as if rendered for a 64x48 camera";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("32x24"), std::string::npos) << m;
    EXPECT_NE(m.find("64x48"), std::string::npos) << m;
  }
  // A different display size is allowed: the output takes the dst camera's size.
  Camera wide = yawed(c0, 7.0f);
  wide.width = 80;
  wide.height = 40;
  const PassBuffer in = ramp_colour(kW, kH);
  PassBuffer o1, o2;
  with_threads(1, [&] { p->predict({in, cameras_only(c0), cameras_only(wide)}, o1); });
  with_threads(2, [&] { p->predict({in, cameras_only(c0), cameras_only(wide)}, o2); });
  EXPECT_EQ(o1.desc.width, 80);
  EXPECT_EQ(o1.desc.height, 40);
  EXPECT_EQ(o1.bytes.size(), size_t(80 * 40 * 3));
  EXPECT_TRUE(o1.bytes == o2.bytes);
}

// ---------------------------------------------------------------- depth pass and depth_warp

TEST(DepthPass, CodesRoundTripWithinHalfAStepAndKeepTheBackground) {
  const Camera c = look({1.0f, 2.0f, 3.0f}, {0.0f, 0.0f, 0.0f});  // near 0.05
  // Inverse depth: q = M near / z, so half a step of q is z^2 / (2 M near) in z (M = 65535).
  auto half_step = [&](double z) { return z * z / (2.0 * 65535.0 * 0.05); };
  uint16_t last = 65535;
  for (float z = 0.06f; z <= 500.0f; z *= 1.37f) {
    const uint16_t q = depth_code(z, c, 16);
    EXPECT_LT(q, last) << "codes fall with depth";
    last = q;
    EXPECT_LE(std::fabs(double(depth_of_code(q, c, 16)) - z), half_step(z) * 1.001 + 1e-6 * z) << z;
  }
  EXPECT_EQ(depth_code(kBackgroundDepth, c, 16), 0);
  EXPECT_EQ(depth_code(std::nanf(""), c, 16), 0);
  EXPECT_EQ(depth_code(-1.0f, c, 16), 0);
  EXPECT_TRUE(std::isinf(depth_of_code(0, c, 16)));
  EXPECT_EQ(depth_code(0.001f, c, 16), 65535) << "nearer than near: clamped";
  EXPECT_EQ(depth_code(1e6f, c, 16), 1) << "beyond 65535 near: clamped";

  const GBuffer g = render(Scene{}, oblique());
  EXPECT_EQ(depth_code(0.001f, c, 12), 4095);
  EXPECT_EQ(depth_code(0.5f, c, 12), 410) << "round(4095 * 0.05 / 0.5)";
  EXPECT_THROW(depth_code(1.0f, c, 17), Error);
  EXPECT_THROW(depth_code(1.0f, c, 7), Error);

  const PassBuffer pass = pack_depth(g.depth, g.camera, 16);
  EXPECT_EQ(pass.desc, (PassDesc{PassKind::Depth, kW, kH, 2, 16}));
  EXPECT_EQ(pass.bytes.size(), pass.desc.byte_size());
  const ImageF back = unpack_depth(pass, g.camera);
  for (size_t i = 0; i < back.size(); ++i) {
    if (std::isinf(g.depth[i]))
      EXPECT_TRUE(std::isinf(back[i]));
    else
      EXPECT_LE(std::fabs(double(back[i]) - g.depth[i]), half_step(g.depth[i]) * 1.001 + 1e-6 * g.depth[i]);
  }
  PassBuffer wrong = pass;
  wrong.bytes.pop_back();
  EXPECT_THROW(unpack_depth(wrong, g.camera), Error);
  EXPECT_THROW(unpack_depth(make_ao(g), g.camera), Error);
}

// Colour painted on the world, in cells of 1/2 m: r from x, g from z, b from y and the object.
Rgb8 painted(const glm::vec3& p, uint32_t id) {
  auto cell = [](float v) { return uint8_t(((int(std::floor(v * 2.0f)) % 200) + 200) % 200); };
  return {cell(p.x), cell(p.z), uint8_t(id * 40 + cell(p.y) % 40)};
}

PassBuffer paint_colour(const GBuffer& g) {
  PassBuffer b;
  b.desc = {PassKind::Colour, g.width(), g.height(), 3, 255};
  b.bytes.resize(b.desc.byte_size());
  for (size_t i = 0; i < g.object_id.size(); ++i) {
    const Rgb8 c = g.object_id[i] == kBackgroundId ? Rgb8{0, 0, 250} : painted(g.position[i], g.object_id[i]);
    b.bytes[3 * i] = c.r;
    b.bytes[3 * i + 1] = c.g;
    b.bytes[3 * i + 2] = c.b;
  }
  return b;
}

// Over the pixels of `dst` inside a painted cell (their 3x3 neighbourhood has one colour, so a
// sub-pixel error cannot change what they should show): the fraction that `out` shows exactly.
double painted_match(const PassBuffer& out, const GBuffer& dst) {
  const PassBuffer truth = paint_colour(dst);
  const int w = dst.width(), h = dst.height();
  auto at = [&](const PassBuffer& b, int x, int y) {
    const uint8_t* p = &b.bytes[3 * (size_t(y) * size_t(w) + size_t(x))];
    return Rgb8{p[0], p[1], p[2]};
  };
  size_t inside = 0, ok = 0;
  for (int y = 1; y + 1 < h; ++y)
    for (int x = 1; x + 1 < w; ++x) {
      bool flat = true;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) flat = flat && at(truth, x + dx, y + dy) == at(truth, x, y);
      if (!flat) continue;
      ++inside;
      ok += at(out, x, y) == at(truth, x, y);
    }
  return inside ? double(ok) / double(inside) : 0.0;
}

// A translated and turned camera: reprojecting with depth lands the world-painted colours where
// the frame rendered at the new camera has them; the rotation-only warp cannot.
TEST(DepthWarp, TranslationLandsWorldPaintedColoursWhereTheNewFrameHasThem) {
  const Scene scene;
  const Camera c0 = look({0.5f, 3.5f, 5.5f}, {0.0f, 0.8f, 0.0f}, {0, 1, 0}, 256, 192);
  Camera c1 = yawed(translated(c0, c0.right() * 0.5f + c0.forward * 0.4f), 3.0f);
  const GBuffer src = render(scene, c0), dst = render(scene, c1);
  const PassBuffer in = paint_colour(src);
  GBuffer src_received = cameras_only(c0);
  src_received.depth = unpack_depth(pack_depth(src.depth, c0, 12), c0);  // what the remote client receives
  PassBuffer by_depth, by_rotation;
  const PredictStats st = make("depth_warp")->predict({in, src_received, cameras_only(c1)}, by_depth);
  make("rotation_warp")->predict({in, cameras_only(c0), cameras_only(c1)}, by_rotation);
  const double d = painted_match(by_depth, dst), r = painted_match(by_rotation, dst);
  std::printf("painted colours within one cell: depth_warp %.3f (%llu holes), rotation_warp %.3f\n", d,
              (unsigned long long)st.disoccluded, r);
  EXPECT_GE(d, 0.95);
  EXPECT_LT(r, d - 0.2);
  EXPECT_GT(st.disoccluded, 0u) << "moving beside the box uncovers ground";
  EXPECT_LT(st.disoccluded, st.pixels / 10);
}

TEST(DepthWarp, WithoutDepthItIsTheRotationWarp) {
  const Camera c0 = look({0.0f, 1.0f, 0.0f}, {0.0f, 1.0f, -5.0f});
  const Camera c1 = yawed(translated(c0, {0.2f, 0.0f, 0.0f}), 4.0f);
  const PassBuffer in = ramp_colour(kW, kH);
  PassBuffer a, b;
  const PredictStats sa = make("depth_warp")->predict({in, cameras_only(c0), cameras_only(c1)}, a);
  const PredictStats sb = make("rotation_warp")->predict({in, cameras_only(c0), cameras_only(c1)}, b);
  EXPECT_TRUE(a.bytes == b.bytes);
  EXPECT_EQ(sa.disoccluded, sb.disoccluded);
  EXPECT_GT(sa.disoccluded, 0u) << "the yaw uncovers a strip: the comparison covers the fill too";
}

// Turned around, nothing of the source lies in front of the new camera: every pixel is a hole
// (counted), and every row is filled from the rotation alone (clamped into the source).
TEST(DepthWarp, TurnedAroundEveryPixelIsAHoleFilledFromTheRotation) {
  const Camera c0 = oblique();
  const GBuffer g = render(Scene{}, c0);
  GBuffer src = cameras_only(c0);
  src.depth = g.depth;
  PassBuffer out;
  const PassBuffer in = paint_colour(g);
  const PredictStats st = make("depth_warp")->predict({in, src, cameras_only(yawed(c0, 180.0f))}, out);
  EXPECT_EQ(st.pixels, uint64_t(kW * kH));
  EXPECT_EQ(st.disoccluded, st.pixels);
  ASSERT_EQ(out.bytes.size(), in.bytes.size());
  const std::set<uint8_t> source(in.bytes.begin(), in.bytes.end());
  for (uint8_t b : out.bytes) EXPECT_TRUE(source.count(b)) << "every value is a source pixel's";
}

TEST(DepthWarp, RefusesMismatchedDepthBitmasksAndDepthPasses) {
  const Camera c0 = oblique();
  const GBuffer g = render(Scene{}, c0);
  GBuffer src = cameras_only(c0);
  src.depth = ImageF(kW / 2, kH, 1.0f);
  PassBuffer out;
  auto p = make("depth_warp");
  try {
    p->predict({paint_colour(g), src, cameras_only(c0)}, out);
    ADD_FAILURE() << "a depth of another size was used";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("32x48"), std::string::npos) << m;
    EXPECT_NE(m.find("64x48"), std::string::npos) << m;
  }
  EXPECT_THROW(p->predict({make_random(g, PassKind::Visibility, 4, 255, 1), g, g}, out), Error);
  // A depth pass's two byte planes are one code: no predictor may resample them as images.
  for (const char* name : {"depth_warp", "rotation_warp", "reprojection"}) {
    SCOPED_TRACE(name);
    EXPECT_THROW(make(name)->predict({pack_depth(g.depth, c0, 12), g, g}, out), Error);
  }
  EXPECT_EQ(p->depth_bits(), 12);
  EXPECT_EQ(make("depth_warp", {{"depth_bits", 16}})->depth_bits(), 16);
  EXPECT_EQ(make("rotation_warp")->depth_bits(), 0);
}

// ---------------------------------------------------------------- every predictor
//
// Value-parameterised over the registry: every registered predictor runs these by name
// (PredictorConformance.<test>/<predictor>), so a new one is tested without editing this file.

struct ConformanceCase {
  PassKind kind;
  int channels, full_scale;
};
constexpr ConformanceCase kConformanceCases[] = {
    {PassKind::Visibility, 4, 255}, {PassKind::Visibility, 12, 255}, {PassKind::SoftVisibility, 3, 255},
    {PassKind::Ao, 1, 8},           {PassKind::Ao, 1, 255},          {PassKind::Colour, 3, 255}};

std::string case_label(const ConformanceCase& c) {
  return std::string(pass_kind_name(c.kind)) + " " + std::to_string(c.channels) + "/" + std::to_string(c.full_scale);
}

std::vector<std::string> predictor_names() {
  std::vector<std::string> names;
  for (const auto& e : registries().predictors.entries()) names.push_back(e.name);
  return names;
}

class PredictorConformance : public ::testing::TestWithParam<std::string> {};

// Identity cameras (dst = an equal copy of src) must return the input, at dst's size, for
// every pass kind the predictor accepts; each predictor must accept at least one kind and
// refuse others only with a dhr::Error.
TEST_P(PredictorConformance, IdentityReturnsInputForAcceptedKinds) {
  const GBuffer src = render(Scene{}, oblique());
  const GBuffer dst = src;
  auto p = make(GetParam());
  int accepted = 0;
  for (const ConformanceCase& c : kConformanceCases) {
    const PassBuffer in = make_random(src, c.kind, c.channels, c.full_scale, 31);
    PassBuffer out;
    PredictStats st;
    try {
      st = p->predict({in, src, dst}, out);
    } catch (const Error& err) {
      EXPECT_FALSE(std::string(err.what()).empty());
      continue;
    }
    ++accepted;
    SCOPED_TRACE(GetParam() + " " + case_label(c));
    EXPECT_EQ(out.desc.width, dst.width());
    EXPECT_EQ(out.desc.height, dst.height());
    EXPECT_EQ(out.desc, in.desc);
    EXPECT_TRUE(out.bytes == in.bytes);
    EXPECT_EQ(st.disoccluded, 0u);
    p->reset();
  }
  EXPECT_GE(accepted, 1) << GetParam() << " accepts no pass kind";
  std::printf("%-16s accepts %d of %zu pass layouts\n", GetParam().c_str(), accepted, std::size(kConformanceCases));
}

// A moved camera: for every accepted kind the output has dst's size and the input's layout,
// counts no more disoccluded than predicted pixels, and is the same at one and two threads
// and from a second, fresh predictor.
TEST_P(PredictorConformance, MovedCameraIsDeterministicAndWellFormed) {
  const Scene scene;
  const GBuffer src = render(scene, oblique());
  const GBuffer dst = render(scene, translated(oblique(), {0.6f, -0.1f, 0.3f}));
  auto a = make(GetParam());
  auto b = make(GetParam());
  for (const ConformanceCase& c : kConformanceCases) {
    const PassBuffer in = make_random(src, c.kind, c.channels, c.full_scale, 41);
    PassBuffer out1, out2;
    PredictStats s1, s2;
    try {
      with_threads(1, [&] { s1 = a->predict({in, src, dst}, out1); });
    } catch (const Error&) {
      continue;  // refused (IdentityReturnsInputForAcceptedKinds checks that something is accepted)
    }
    with_threads(2, [&] { s2 = b->predict({in, src, dst}, out2); });
    SCOPED_TRACE(GetParam() + " " + case_label(c));
    EXPECT_EQ(out1.desc.width, dst.width());
    EXPECT_EQ(out1.desc.height, dst.height());
    EXPECT_EQ(out1.desc.kind, in.desc.kind);
    EXPECT_EQ(out1.desc.channels, in.desc.channels);
    EXPECT_EQ(out1.bytes.size(), out1.desc.byte_size());
    EXPECT_LE(s1.disoccluded, s1.pixels);
    EXPECT_LE(s1.pixels, uint64_t(dst.width()) * uint64_t(dst.height()));
    EXPECT_TRUE(out1.bytes == out2.bytes) << "differs between one and two threads";
    EXPECT_EQ(s1.pixels, s2.pixels);
    EXPECT_EQ(s1.disoccluded, s2.disoccluded);
  }
}

// The test name is the predictor's name (characters GoogleTest does not allow become '_').
std::string predictor_test_name(const ::testing::TestParamInfo<std::string>& info) {
  std::string s = info.param;
  for (char& c : s)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return s;
}

INSTANTIATE_TEST_SUITE_P(Registered, PredictorConformance, ::testing::ValuesIn(predictor_names()), predictor_test_name);

// An empty registry would instantiate no conformance test at all, silently.
TEST(PredictorRegistry, ConformanceSuiteIsNotEmpty) { EXPECT_GE(registries().predictors.entries().size(), 3u); }

}  // namespace
}  // namespace dhr
