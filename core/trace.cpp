// Shadow visibility (paper section 3.1) and ray-traced AO (section 3.2, Eq. 1-3) with Embree
// ray streams. See core/trace.h for the rules (which rays are traced, offsets, validation).
//
// Rays are generated straight into 8-wide SoA packets (Batch) and traced with rtcOccluded8;
// Embree marks an occluded ray by setting tfar to -inf.
#include "core/trace.h"

#include "core/error.h"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>

namespace dhr {

namespace {


double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// A surface point rebuilt from the G-buffer (core/trace.h: "Surface points").
struct Surface {
  glm::vec3 p{0.0f};       // on the triangle
  glm::vec3 n{0.0f};       // unit geometric normal, oriented like the G-buffer's (camera side)
  glm::vec3 origin{0.0f};  // p offset along n (Waechter-Binder)
  glm::vec3 t{0.0f}, b{0.0f};  // orthonormal basis around n (AO only)
};

// False for background pixels. Unresolvable ids fall back to the G-buffer's position and
// geometric normal (counted); a non-finite result then fails ray validation downstream.
bool surface_at(const RtScene& rt, const GBuffer& g, int x, int y, Surface& s, uint64_t& unresolved) {
  const uint32_t id = g.object_id(x, y);
  if (id == kBackgroundId) return false;
  const glm::vec3 gn = g.geo_normal(x, y);
  glm::dvec3 v[3];
  const int oi = rt.object_index(id);
  if (oi >= 0 && rt.triangle_world(oi, g.prim_id(x, y), v)) {
    const glm::dvec2 bc(g.bary(x, y));
    const glm::dvec3 p = (1.0 - bc.x - bc.y) * v[0] + bc.x * v[1] + bc.y * v[2];
    glm::dvec3 n = glm::cross(v[1] - v[0], v[2] - v[0]);
    n /= glm::length(n);  // non-degenerate: degenerate triangles were skipped at build
    // Orient towards the camera side, as the G-buffer's geometric normal is; without a usable
    // G-buffer normal, towards the camera itself.
    double side = glm::dot(n, glm::dvec3(gn));
    if (!(std::abs(side) > 0.0)) side = glm::dot(n, glm::dvec3(g.camera.position) - p);
    if (side < 0.0) n = -n;
    s.p = glm::vec3(p);
    s.n = glm::vec3(n);
  } else {
    ++unresolved;
    s.p = g.position(x, y);
    const float len = glm::length(gn);
    s.n = gn / len;  // NaN for a zero normal: the rays then fail validation (counted)
  }
  s.origin = offset_ray_origin(s.p, s.n);
  return true;
}

struct LightInfo {
  bool sphere = true;
  bool soft = false;
  int samples = 1;
  glm::vec3 centre{0.0f};     // sphere
  glm::dvec3 centre_d{0.0};
  float radius = 0.0f;
  float range = 0.0f;
  glm::vec3 dir{0.0f, 1.0f, 0.0f};  // distant: unit, towards the light
  float one_minus_cos = 0.0f;       // distant: 1 - cos(angular radius)
  float sin_alpha = 0.0f;           // distant: sin(angular radius)
};

std::vector<LightInfo> light_infos(const Scene& scene, const PassPlan& plan) {
  std::vector<LightInfo> out;
  for (size_t l = 0; l < scene.lights.size(); ++l) {
    const Light& L = scene.lights[l];
    LightInfo li;
    li.sphere = L.type == LightType::Sphere;
    li.soft = plan.light_soft[l] != 0;
    li.samples = li.soft ? plan.samples_per_light : 1;
    li.centre = L.position;
    li.centre_d = glm::dvec3(L.position);
    li.radius = std::max(0.0f, L.radius_m);
    li.range = L.range_m;
    const float dl = glm::length(L.direction);
    li.dir = dl > 0.0f ? L.direction / dl : glm::vec3(0.0f, 1.0f, 0.0f);
    const double alpha = glm::radians(double(std::max(0.0f, L.angular_radius_deg)));
    li.one_minus_cos = float(2.0 * std::sin(alpha / 2) * std::sin(alpha / 2));  // exact near 0
    li.sin_alpha = float(std::sin(alpha));
    out.push_back(li);
  }
  return out;
}

// (cos 2 pi u, sin 2 pi u) for u in [0, 1) without libm: the quadrant from 4u, then
// polynomials on [0, pi/2] (Taylor to degree 8/9: |error| < 4e-6, far below what a ray
// direction needs; the results keep c^2 + s^2 = 1 within 1e-5). Deterministic: no
// library or ISA dependence.
inline void sincos_2pi(float u, float& c, float& s) {
  const float x = 4.0f * u;
  const int q = std::min(3, int(x));
  const float a = (x - float(q)) * (std::numbers::pi_v<float> / 2.0f);  // [0, pi/2)
  const float a2 = a * a;
  const float sa = a * (1.0f + a2 * (-1.0f / 6 + a2 * (1.0f / 120 + a2 * (-1.0f / 5040 + a2 * (1.0f / 362880)))));
  const float ca = 1.0f + a2 * (-0.5f + a2 * (1.0f / 24 + a2 * (-1.0f / 720 + a2 * (1.0f / 40320))));
  // Rotate by q quarter turns.
  const float cs[4] = {ca, -sa, -ca, sa};
  const float sn[4] = {sa, ca, -sa, -ca};
  c = cs[q];
  s = sn[q];
}

// A direction in the cone around unit w with 1 - cos(half angle) = omc_max, uniform in solid
// angle (paper 3.1: "a circular cone distribution that covers the entire light").
inline glm::vec3 sample_cone(const glm::vec3& w, float omc_max, float u0, float u1) {
  glm::vec3 t, b;
  orthonormal_basis(w, t, b);
  const float omc = u0 * omc_max;  // 1 - cos(theta), precise for small cones
  const float cos_t = 1.0f - omc;
  const float sin_t = std::sqrt(std::max(0.0f, omc * (2.0f - omc)));
  float c, s;
  sincos_2pi(u1, c, s);
  return glm::normalize(t * (c * sin_t) + b * (s * sin_t) + w * cos_t);
}

// A packet of up to 8 occlusion rays and, per ray, the counter it increments when unoccluded.
// Rays are written straight into Embree's SoA layout and traced with rtcOccluded8: on this
// machine 8-wide packets of consecutive rays (the N AO rays of one pixel, or neighbouring
// pixels' shadow rays) beat rtcOccluded1M streams and rtcOccluded1 (see bench_trace).
struct Batch {
  RTCRay8 packet;
  std::array<uint16_t*, 8> counter{};
  unsigned n = 0;
  RTCScene scene = nullptr;
  uint64_t traced = 0;
  std::vector<RTCRay>* record = nullptr;  // collect_*_rays: keep the rays, trace nothing

  void flush() {
    if (n == 0) return;
    alignas(32) int valid[8];
    for (unsigned k = 0; k < 8; ++k) valid[k] = k < n ? -1 : 0;
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    rtcOccluded8(valid, scene, &ctx, &packet);
    for (unsigned k = 0; k < n; ++k)
      if (!(packet.tfar[k] < 0.0f)) ++*counter[k];
    traced += n;
    n = 0;
  }
  void push(const glm::vec3& o, const glm::vec3& d, float tfar, unsigned mask, uint16_t* count) {
    if (record) {
      RTCRay& r = record->emplace_back();
      r.org_x = o.x, r.org_y = o.y, r.org_z = o.z, r.tnear = 0.0f;
      r.dir_x = d.x, r.dir_y = d.y, r.dir_z = d.z, r.time = 0.0f;
      r.tfar = tfar, r.mask = mask, r.id = 0, r.flags = 0;
      return;
    }
    packet.org_x[n] = o.x;
    packet.org_y[n] = o.y;
    packet.org_z[n] = o.z;
    packet.tnear[n] = 0.0f;
    packet.dir_x[n] = d.x;
    packet.dir_y[n] = d.y;
    packet.dir_z[n] = d.z;
    packet.time[n] = 0.0f;
    packet.tfar[n] = tfar;
    packet.mask[n] = mask;
    packet.id[n] = n;
    packet.flags[n] = 0;
    counter[n] = count;
    if (++n == 8) flush();
  }
};

template <class F>
void run_in_arena(RtScene& rt, const TraceSettings& settings, F&& f) {
  if (settings.threads > 0 && settings.threads != rt.threads()) {
    tbb::task_arena arena(settings.threads);
    arena.execute(f);
  } else {
    rt.arena().execute(f);
  }
}

void check_gbuffer(const GBuffer& g) {
  const int w = g.width(), h = g.height();
  if (!g.object_id.same_size(w, h) || !g.prim_id.same_size(w, h) || !g.bary.same_size(w, h) ||
      !g.position.same_size(w, h) || !g.geo_normal.same_size(w, h))
    fail("trace: G-buffer layers differ in size from its depth layer ({}x{})", w, h);
}

}  // namespace

const char* shadow_mode_name(ShadowMode mode) {
  switch (mode) {
    case ShadowMode::None: return "none";
    case ShadowMode::Hard: return "hard";
    case ShadowMode::SoftBit: return "soft_bit";
    case ShadowMode::SoftFraction: return "soft_fraction";
  }
  return "unknown";
}

int PassPlan::visibility_full_scale() const {
  return shadow == ShadowMode::SoftFraction ? std::min(samples_per_light, 255) : 1;
}

PassDesc PassPlan::visibility_desc(int width, int height) const {
  PassDesc d;
  d.kind = visibility_kind();
  d.width = width;
  d.height = height;
  d.channels = lights;
  d.full_scale = shadow == ShadowMode::SoftFraction ? visibility_full_scale() : 255;
  return d;
}

PassDesc PassPlan::ao_desc(int width, int height) const {
  PassDesc d;
  d.kind = PassKind::Ao;
  d.width = width;
  d.height = height;
  d.channels = 1;
  d.full_scale = ao_rays;
  return d;
}

std::string PassPlan::describe() const {
  std::string s;
  for (const auto& r : reasons) {
    if (!s.empty()) s += "; ";
    s += r;
  }
  return s;
}

void TraceStats::add(const TraceStats& o) {
  pixels += o.pixels;
  covered_pixels += o.covered_pixels;
  shadow_rays += o.shadow_rays;
  ao_rays += o.ao_rays;
  invalid_rays += o.invalid_rays;
  unresolved_pixels += o.unresolved_pixels;
  shadow_skipped_facing += o.shadow_skipped_facing;
  shadow_skipped_range += o.shadow_skipped_range;
  shadow_inside_light += o.shadow_inside_light;
  shadow_ms += o.shadow_ms;
  ao_ms += o.ao_ms;
}

PassPlan plan_passes(const Scene& scene, const TraceSettings& s) {
  if (s.ao_rays < 0 || s.ao_rays > 255) fail("trace settings: ao_rays {} out of range 1..255 (0 = the scene's)", s.ao_rays);
  if (!(s.ao_radius_m >= 0.0f) || !std::isfinite(s.ao_radius_m))
    fail("trace settings: ao_radius_m {} must be finite and > 0 (0 = the scene's)", s.ao_radius_m);
  if (s.samples_per_light < 1 || s.samples_per_light > 1024)
    fail("trace settings: samples_per_light {} out of range 1..1024", s.samples_per_light);
  if (s.threads < 0) fail("trace settings: threads {} must be >= 0 (0 = the scene's arena)", s.threads);
  if (scene.lights.size() > 64) fail("scene '{}': {} lights, at most 64 are supported", scene.name, scene.lights.size());

  PassPlan plan;
  plan.lights = int(scene.lights.size());
  if (scene.lights.empty()) {
    plan.reasons.push_back("no lights: no visibility pass");
  } else if (!s.visibility_pass) {
    plan.reasons.push_back("visibility pass switched off by the run's settings");
  } else {
    bool any_area = false;
    for (const Light& l : scene.lights) {
      const bool soft = s.soft_shadows && !l.is_point();
      plan.light_soft.push_back(soft ? 1 : 0);
      any_area = any_area || !l.is_point();
    }
    if (!any_area) {
      plan.shadow = ShadowMode::Hard;
      plan.samples_per_light = 1;
      plan.reasons.push_back(fmt::format("{} point light(s) only: hard shadows, one ray per light", plan.lights));
    } else if (!s.soft_shadows) {
      plan.shadow = ShadowMode::Hard;
      plan.samples_per_light = 1;
      plan.reasons.push_back("soft shadows off: hard shadows, one ray to each light's centre");
    } else if (s.samples_per_light == 1) {
      plan.shadow = ShadowMode::SoftBit;
      plan.samples_per_light = 1;
      plan.reasons.push_back("area light(s): soft shadows, one jittered ray per light (bitmask)");
    } else {
      plan.shadow = ShadowMode::SoftFraction;
      plan.samples_per_light = s.samples_per_light;
      plan.reasons.push_back(fmt::format("area light(s): soft shadows, {} rays per light (8-bit fraction)",
                                         s.samples_per_light));
    }
  }
  if (!scene.ao) {
    plan.reasons.push_back("no ao block: no AO pass");
  } else if (!s.ao_pass) {
    plan.reasons.push_back("AO pass switched off by the run's settings");
  } else {
    plan.ao = true;
    plan.ao_rays = s.ao_rays > 0 ? s.ao_rays : scene.ao->rays;
    plan.ao_radius_m = s.ao_radius_m > 0.0f ? s.ao_radius_m : scene.ao->radius_m;
    if (plan.ao_rays < 1 || plan.ao_rays > 255)
      fail("scene '{}': ao.rays {} out of range 1..255", scene.name, plan.ao_rays);
    if (!(plan.ao_radius_m > 0.0f) || !std::isfinite(plan.ao_radius_m))
      fail("scene '{}': ao.radius_m {} must be finite and > 0", scene.name, plan.ao_radius_m);
    plan.reasons.push_back(fmt::format("ao: {} rays, radius {} m", plan.ao_rays, plan.ao_radius_m));
  }
  return plan;
}

namespace {

VisibilityCounts visibility_impl(RtScene& rt, const GBuffer& g, const PassPlan& plan, const TraceSettings& settings,
                                 TraceStats& stats, std::vector<std::vector<RTCRay>>* rows_out) {
  if (!plan.visibility()) fail("trace_visibility: the plan has no visibility pass ({})", plan.describe());
  if (plan.lights != int(rt.scene().lights.size()))
    fail("trace_visibility: plan for {} lights, scene has {}", plan.lights, rt.scene().lights.size());
  if (plan.samples_per_light < 1 || plan.samples_per_light > 65535)
    fail("trace_visibility: samples_per_light {} out of range 1..65535", plan.samples_per_light);
  check_gbuffer(g);
  const auto t0 = std::chrono::steady_clock::now();
  rt.set_time(g.time_s);
  const int w = g.width(), h = g.height();
  const size_t npx = size_t(w) * size_t(h);
  const auto lights = light_infos(rt.scene(), plan);
  const int nl = int(lights.size());
  VisibilityCounts out;
  out.width = w;
  out.height = h;
  out.lights = nl;
  for (const auto& li : lights) out.samples.push_back(li.samples);
  out.visible.assign(npx * size_t(nl), 0);
  std::atomic<uint64_t> a_rays{0}, a_invalid{0}, a_unres{0}, a_facing{0}, a_range{0}, a_inside{0}, a_cov{0};
  const RTCScene scene = rt.handle();

  run_in_arena(rt, settings, [&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
      Batch batch;
      batch.scene = scene;
      uint64_t invalid = 0, unres = 0, facing = 0, range = 0, inside = 0, cov = 0;
      for (int y = rows.begin(); y < rows.end(); ++y) {
        if (rows_out) batch.record = &(*rows_out)[size_t(y)];
        for (int x = 0; x < w; ++x) {
          Surface s;
          if (!surface_at(rt, g, x, y, s, unres)) continue;
          ++cov;
          const size_t pixel = size_t(y) * size_t(w) + size_t(x);
          const PixelRng rng(settings.seed, uint32_t(pixel), settings.frame);
          for (int l = 0; l < nl; ++l) {
            const LightInfo& li = lights[size_t(l)];
            uint16_t* count = &out.visible[size_t(l) * npx + pixel];
            if (li.sphere) {
              const glm::dvec3 to_c = li.centre_d - glm::dvec3(s.p);
              const double d = glm::length(to_c);
              if (li.range > 0.0f && d > double(li.range)) {
                ++range;
                continue;
              }
              if (!(d > double(li.radius)) && d == d) {  // inside the light: visible, no ray
                *count = uint16_t(li.samples);
                ++inside;
                continue;
              }
              const double n_dot = glm::dot(glm::dvec3(s.n), to_c);
              // Hard: facing away from the centre. Soft: the whole sphere below the horizon.
              if (li.soft ? n_dot <= -double(li.radius) : n_dot <= 0.0) {
                ++facing;
                continue;
              }
              const glm::vec3 oc = li.centre - s.origin;
              const float dist_o = glm::length(oc);
              if (!li.soft) {
                const glm::vec3 dir = oc / dist_o;
                const float tfar = std::max(0.0f, (dist_o - li.radius) * kShadowTfarScale);
                if (!ray_is_valid(s.origin, dir, 0.0f, tfar)) {
                  ++invalid;
                  ++*count;
                  continue;
                }
                batch.push(s.origin, dir, tfar, kMaskShadow, count);
                continue;
              }
              // Cone subtended by the sphere from p: sin^2 = R^2 / d^2.
              const double s2 = double(li.radius) * li.radius / (d * d);
              const float omc_max = float(s2 / (1.0 + std::sqrt(1.0 - s2)));
              const glm::vec3 w_dir = glm::vec3(to_c / d);
              for (int k = 0; k < li.samples; ++k) {
                float u0, u1;
                rng.uniform2(uint32_t(k), kStreamLightBase + uint32_t(l), u0, u1);
                const glm::vec3 dir = sample_cone(w_dir, omc_max, u0, u1);
                // Distance from the origin to the sphere along dir (nearest root); rounding
                // at the cone's rim can leave no root: then the closest approach.
                const float b = glm::dot(dir, oc);
                const glm::vec3 perp = oc - b * dir;
                const float disc = li.radius * li.radius - glm::dot(perp, perp);
                const float t_hit = disc > 0.0f ? b - std::sqrt(disc) : b;
                const float tfar = std::max(0.0f, t_hit * kShadowTfarScale);
                if (!ray_is_valid(s.origin, dir, 0.0f, tfar)) {
                  ++invalid;
                  ++*count;
                  continue;
                }
                batch.push(s.origin, dir, tfar, kMaskShadow, count);
              }
            } else {
              const float n_dot = glm::dot(s.n, li.dir);
              if (li.soft ? n_dot <= -li.sin_alpha : n_dot <= 0.0f) {
                ++facing;
                continue;
              }
              constexpr float kInf = std::numeric_limits<float>::infinity();
              for (int k = 0; k < li.samples; ++k) {
                glm::vec3 dir = li.dir;
                if (li.soft) {
                  float u0, u1;
                  rng.uniform2(uint32_t(k), kStreamLightBase + uint32_t(l), u0, u1);
                  dir = sample_cone(li.dir, li.one_minus_cos, u0, u1);
                }
                if (!ray_is_valid(s.origin, dir, 0.0f, kInf)) {
                  ++invalid;
                  ++*count;
                  continue;
                }
                batch.push(s.origin, dir, kInf, kMaskShadow, count);
              }
            }
          }
        }
      }
      batch.flush();
      if (rows_out)
        for (int y = rows.begin(); y < rows.end(); ++y) batch.traced += (*rows_out)[size_t(y)].size();
      a_rays += batch.traced;
      a_invalid += invalid;
      a_unres += unres;
      a_facing += facing;
      a_range += range;
      a_inside += inside;
      a_cov += cov;
    });
  });
  TraceStats st;
  st.pixels = npx;
  st.covered_pixels = a_cov;
  st.shadow_rays = a_rays;
  st.invalid_rays = a_invalid;
  st.unresolved_pixels = a_unres;
  st.shadow_skipped_facing = a_facing;
  st.shadow_skipped_range = a_range;
  st.shadow_inside_light = a_inside;
  st.shadow_ms = ms_since(t0);
  stats.add(st);
  return out;
}

AoCounts ao_impl(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m, const TraceSettings& settings,
                 TraceStats& stats, std::vector<std::vector<RTCRay>>* rows_out) {
  if (ao_rays < 1 || ao_rays > 65535) fail("trace_ao: ao_rays {} out of range 1..65535", ao_rays);
  if (!(radius_m > 0.0f) || !std::isfinite(radius_m)) fail("trace_ao: radius_m {} must be finite and > 0", radius_m);
  check_gbuffer(g);
  const auto t0 = std::chrono::steady_clock::now();
  rt.set_time(g.time_s);
  const int w = g.width(), h = g.height();
  const size_t npx = size_t(w) * size_t(h);
  AoCounts out;
  out.width = w;
  out.height = h;
  out.rays = ao_rays;
  // Background pixels read as unoccluded.
  out.unoccluded.assign(npx, uint16_t(ao_rays));
  std::atomic<uint64_t> a_rays{0}, a_invalid{0}, a_unres{0}, a_cov{0};
  const RTCScene scene = rt.handle();

  run_in_arena(rt, settings, [&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
      Batch batch;
      batch.scene = scene;
      uint64_t invalid = 0, unres = 0, cov = 0;
      for (int y = rows.begin(); y < rows.end(); ++y) {
        if (rows_out) batch.record = &(*rows_out)[size_t(y)];
        for (int x = 0; x < w; ++x) {
          Surface s;
          if (!surface_at(rt, g, x, y, s, unres)) continue;
          ++cov;
          const size_t pixel = size_t(y) * size_t(w) + size_t(x);
          uint16_t* count = &out.unoccluded[pixel];
          *count = 0;
          orthonormal_basis(s.n, s.t, s.b);
          // Validation once per pixel: with a valid origin, a finite unit basis and
          // 0 <= tfar = r, every direction below is a finite unit-length combination of the
          // basis, so every ray of the pixel is valid (ray_is_valid would pass each one).
          const bool valid = ray_is_valid(s.origin, s.n, 0.0f, radius_m) && std::isfinite(s.t.x + s.t.y + s.t.z) &&
                             std::isfinite(s.b.x + s.b.y + s.b.z);
          if (!valid) {
            invalid += uint64_t(ao_rays);
            *count = uint16_t(ao_rays);
            continue;
          }
          const PixelRng rng(settings.seed, uint32_t(pixel), settings.frame);
          for (int k = 0; k < ao_rays; ++k) {
            // Cosine-weighted hemisphere sample (Malley's method): the cosine of Eq. 1 is in
            // the density, so O = N_unoccluded / N (Eq. 2-3).
            float u0, u1, c, sn;
            rng.uniform2(uint32_t(k), kStreamAo, u0, u1);
            const float r = std::sqrt(u0);
            const float z = std::sqrt(1.0f - u0);  // u0 < 1
            sincos_2pi(u1, c, sn);
            const glm::vec3 dir = s.t * (r * c) + s.b * (r * sn) + s.n * z;
            // tfar = r: "occluded if anything is hit within r", never trace further.
            batch.push(s.origin, dir, radius_m, kMaskAll, count);
          }
        }
      }
      batch.flush();
      if (rows_out)
        for (int y = rows.begin(); y < rows.end(); ++y) batch.traced += (*rows_out)[size_t(y)].size();
      a_rays += batch.traced;
      a_invalid += invalid;
      a_unres += unres;
      a_cov += cov;
    });
  });
  TraceStats st;
  st.pixels = npx;
  st.covered_pixels = a_cov;
  st.ao_rays = a_rays;
  st.invalid_rays = a_invalid;
  st.unresolved_pixels = a_unres;
  st.ao_ms = ms_since(t0);
  stats.add(st);
  return out;
}

}  // namespace

VisibilityCounts trace_visibility_counts(RtScene& rt, const GBuffer& g, const PassPlan& plan,
                                         const TraceSettings& settings, TraceStats& stats) {
  return visibility_impl(rt, g, plan, settings, stats, nullptr);
}

AoCounts trace_ao_counts(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m, const TraceSettings& settings,
                         TraceStats& stats) {
  return ao_impl(rt, g, ao_rays, radius_m, settings, stats, nullptr);
}

std::vector<RTCRay> collect_visibility_rays(RtScene& rt, const GBuffer& g, const PassPlan& plan,
                                            const TraceSettings& settings) {
  std::vector<std::vector<RTCRay>> rows(size_t(g.height()));
  TraceStats st;
  visibility_impl(rt, g, plan, settings, st, &rows);
  std::vector<RTCRay> out;
  out.reserve(st.shadow_rays);
  for (auto& r : rows) out.insert(out.end(), r.begin(), r.end());
  return out;
}

std::vector<RTCRay> collect_ao_rays(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m,
                                    const TraceSettings& settings) {
  std::vector<std::vector<RTCRay>> rows(size_t(g.height()));
  TraceStats st;
  ao_impl(rt, g, ao_rays, radius_m, settings, st, &rows);
  std::vector<RTCRay> out;
  out.reserve(st.ao_rays);
  for (auto& r : rows) out.insert(out.end(), r.begin(), r.end());
  return out;
}

PassBuffer pack_visibility(const VisibilityCounts& c, const PassPlan& plan) {
  PassBuffer pb;
  pb.desc = plan.visibility_desc(c.width, c.height);
  const std::string problem = pb.desc.validate();
  if (!problem.empty()) fail("pack_visibility: {}", problem);
  const size_t npx = size_t(c.width) * size_t(c.height);
  pb.bytes.assign(pb.desc.byte_size(), 0);
  if (pb.desc.kind == PassKind::Visibility) {
    const size_t bpp = size_t((c.lights + 7) / 8);
    for (int l = 0; l < c.lights; ++l) {
      const uint16_t* v = &c.visible[size_t(l) * npx];
      const uint8_t bit = uint8_t(1u << (l & 7));
      uint8_t* dst = pb.bytes.data() + size_t(l >> 3);
      for (size_t i = 0; i < npx; ++i)
        if (v[i] * 2 >= c.samples[size_t(l)]) dst[i * bpp] |= bit;  // samples are 1 here
    }
  } else {
    const int fs = pb.desc.full_scale;
    for (int l = 0; l < c.lights; ++l) {
      const uint16_t* v = &c.visible[size_t(l) * npx];
      uint8_t* dst = pb.bytes.data() + size_t(l) * npx;
      const uint32_t sl = uint32_t(c.samples[size_t(l)]);
      for (size_t i = 0; i < npx; ++i)
        dst[i] = sl == uint32_t(fs) ? uint8_t(v[i]) : uint8_t((uint32_t(v[i]) * uint32_t(fs) + sl / 2) / sl);
    }
  }
  return pb;
}

PassBuffer pack_ao(const AoCounts& c) {
  if (c.rays < 1 || c.rays > 255) fail("pack_ao: {} rays do not fit the 8-bit AO pass (1..255)", c.rays);
  PassBuffer pb;
  pb.desc.kind = PassKind::Ao;
  pb.desc.width = c.width;
  pb.desc.height = c.height;
  pb.desc.channels = 1;
  pb.desc.full_scale = c.rays;
  pb.bytes.resize(c.unoccluded.size());
  for (size_t i = 0; i < c.unoccluded.size(); ++i) pb.bytes[i] = uint8_t(c.unoccluded[i]);
  return pb;
}

PassBuffer trace_visibility(RtScene& rt, const GBuffer& g, const PassPlan& plan, const TraceSettings& settings,
                            TraceStats& stats) {
  return pack_visibility(trace_visibility_counts(rt, g, plan, settings, stats), plan);
}

PassBuffer trace_ao(RtScene& rt, const GBuffer& g, const PassPlan& plan, const TraceSettings& settings,
                    TraceStats& stats) {
  if (!plan.ao) fail("trace_ao: the plan has no AO pass ({})", plan.describe());
  return pack_ao(trace_ao_counts(rt, g, plan.ao_rays, plan.ao_radius_m, settings, stats));
}

TraceResult trace_passes(RtScene& rt, const GBuffer& g, const TraceSettings& settings) {
  TraceResult r;
  r.plan = plan_passes(rt.scene(), settings);
  r.stats.pixels = uint64_t(g.width()) * uint64_t(g.height());
  TraceStats vs, as;
  if (r.plan.visibility()) r.visibility = trace_visibility(rt, g, r.plan, settings, vs);
  if (r.plan.ao) r.ao = trace_ao(rt, g, r.plan, settings, as);
  // pixels/covered are per G-buffer, not per pass: take them once.
  r.stats.covered_pixels = std::max(vs.covered_pixels, as.covered_pixels);
  vs.pixels = as.pixels = vs.covered_pixels = as.covered_pixels = 0;
  if (r.plan.visibility() && r.plan.ao) as.unresolved_pixels = 0;  // same pixels counted twice
  r.stats.add(vs);
  r.stats.add(as);
  return r;
}

}  // namespace dhr
