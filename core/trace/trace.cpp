// Shadow visibility (paper section 3.1) and ray-traced AO (section 3.2, Eq. 1-3) with Embree
// packets. See core/trace/trace.h for the rules (which rays are traced, offsets, validation).
//
// The tracer in files, by layer:
// - core/trace/trace.cpp (this file): the public entry points: planning (plan_passes), validation of
//   the plan, settings and G-buffer, the passes run over blocks of rows in the thread arena,
//   packing counts into pass buffers.
// - core/trace/trace_kernels.h: what the layers below share: surfaces rebuilt from the G-buffer,
//   light constants, Embree packets (Batch), the row kernels' declarations.
// - core/trace/trace_rows.cpp: the row kernels of the visibility pass and the baseline AO pass, with
//   core/trace/trace_directions.h's scalar/SSE2 direction kernels.
// - core/trace/trace_avx512.cpp: the AVX-512 kernels (the AO pass's ray generator, the visibility
//   pass's stages), and core/trace/trace_avx2.cpp: the AVX2 ones (the AO pass's ray generator, the
//   visibility pass's surfaces, packets and cone loops); chosen at run time
//   (TraceSettings::wide_kernels).
#include "core/trace/trace.h"
#include "core/trace/trace_rays.h"

#include "core/base/error.h"
#include "core/buffers/upsample.h"
#include "core/trace/trace_kernels.h"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <cmath>

namespace dhr {

using namespace trace_detail;

namespace {

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
    orthonormal_basis(li.dir, li.t, li.b);
    out.push_back(li);
  }
  return out;
}

// Native 16-wide packets (Embree's AVX-512 kernels) when the device has them.
bool wide_packets(const RtScene& rt) {
  return rtcGetDeviceProperty(rt.device(), RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED) != 0;
}

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

// Sums per-chunk statistics (integer sums: the totals do not depend on the partition).
struct AtomicStats {
  std::atomic<uint64_t> shadow_rays{0}, ao_rays{0}, invalid{0}, unres{0}, facing{0}, range{0}, inside{0}, cov{0};
  void add(const TraceStats& s) {
    shadow_rays += s.shadow_rays;
    ao_rays += s.ao_rays;
    invalid += s.invalid_rays;
    unres += s.unresolved_pixels;
    facing += s.shadow_skipped_facing;
    range += s.shadow_skipped_range;
    inside += s.shadow_inside_light;
    cov += s.covered_pixels;
  }
};

// Runs rows(y0, y1, stats) over blocks of the image's rows in the pass's thread arena and
// returns the counts of every block summed (times are the caller's).
template <class Rows>
TraceStats trace_rows(RtScene& rt, const TraceSettings& settings, int w, int h, Rows&& rows) {
  AtomicStats acc;
  run_in_arena(rt, settings, [&] {
    const auto block = [&](const tbb::blocked_range<int>& r) {
      TraceStats st;
      rows(r.begin(), r.end(), st);
      acc.add(st);
    };
    if (settings.rows_per_block > 0)
      tbb::parallel_for(tbb::blocked_range<int>(0, h, size_t(settings.rows_per_block)), block,
                        tbb::simple_partitioner());
    else
      tbb::parallel_for(tbb::blocked_range<int>(0, h), block);
  });
  TraceStats st;
  st.pixels = size_t(w) * size_t(h);
  st.covered_pixels = acc.cov;
  st.shadow_rays = acc.shadow_rays;
  st.ao_rays = acc.ao_rays;
  st.invalid_rays = acc.invalid;
  st.unresolved_pixels = acc.unres;
  st.shadow_skipped_facing = acc.facing;
  st.shadow_skipped_range = acc.range;
  st.shadow_inside_light = acc.inside;
  return st;
}

VisibilityCounts visibility_impl(RtScene& rt, const GBuffer& g, const PassPlan& plan, const TraceSettings& settings,
                                 TraceStats& stats, std::vector<std::vector<RTCRay>>* rows_out) {
  if (!plan.visibility()) fail("trace_visibility: the plan has no visibility pass ({})", plan.describe());
  if (plan.lights != int(rt.scene().lights.size()))
    fail("trace_visibility: plan for {} lights, scene has {}", plan.lights, rt.scene().lights.size());
  if (plan.samples_per_light < 1 || plan.samples_per_light > 65535)
    fail("trace_visibility: samples_per_light {} out of range 1..65535", plan.samples_per_light);
  check_gbuffer(g);
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
  const bool wide = wide_packets(rt);
  const uint64_t pass = new_pass_id();
  TraceStats st = trace_rows(rt, settings, w, h, [&](int y0, int y1, TraceStats& rs) {
    if (wide)
      visibility_rows<16>(rt, g, settings, lights, pass, out, rows_out, y0, y1, rs);
    else
      visibility_rows<8>(rt, g, settings, lights, pass, out, rows_out, y0, y1, rs);
  });
  stats.add(st);
  return out;
}

AoCounts ao_impl(RtScene& rt, const GBuffer& g, int ao_rays, float radius_m, const TraceSettings& settings,
                 TraceStats& stats, std::vector<std::vector<RTCRay>>* rows_out) {
  if (ao_rays < 1 || ao_rays > 65535) fail("trace_ao: ao_rays {} out of range 1..65535", ao_rays);
  if (!(radius_m > 0.0f) || !std::isfinite(radius_m)) fail("trace_ao: radius_m {} must be finite and > 0", radius_m);
  check_gbuffer(g);
  rt.set_time(g.time_s);
  const int w = g.width(), h = g.height();
  const size_t npx = size_t(w) * size_t(h);
  AoCounts out;
  out.width = w;
  out.height = h;
  out.rays = ao_rays;
  // Background pixels read as unoccluded.
  out.unoccluded.assign(npx, uint16_t(ao_rays));
  const bool wide = wide_packets(rt);
#if DHR_TRACE_X86_KERNELS
  const bool x16 = wide && settings.wide_kernels && cpu_has_avx512dq();
  const bool x8 = !wide && settings.wide_kernels && cpu_has_avx2();
#endif
  TraceStats st = trace_rows(rt, settings, w, h, [&](int y0, int y1, TraceStats& rs) {
#if DHR_TRACE_X86_KERNELS
    if (x16) return ao_rows_compacted<16>(rt, g, ao_rays, radius_m, settings, out, rows_out, y0, y1, rs, ao_rays_x16);
    if (x8) return ao_rows_compacted<8>(rt, g, ao_rays, radius_m, settings, out, rows_out, y0, y1, rs, ao_rays_x8);
#endif
    if (wide)
      ao_rows_compacted<16>(rt, g, ao_rays, radius_m, settings, out, rows_out, y0, y1, rs, ao_rays_baseline<16>);
    else
      ao_rows_compacted<8>(rt, g, ao_rays, radius_m, settings, out, rows_out, y0, y1, rs, ao_rays_baseline<8>);
  });
  stats.add(st);
  return out;
}

}  // namespace

bool wide_kernels_available(const RtScene& rt) {
#if DHR_TRACE_X86_KERNELS
  return wide_packets(rt) ? cpu_has_avx512dq() : cpu_has_avx2();
#else
  (void)rt;
  return false;
#endif
}

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

std::vector<float> converged_visibility(RtScene& rt, const GBuffer& g, const PassPlan& scene_plan,
                                        const TraceSettings& settings, const ReferenceRays& reference,
                                        TraceStats& stats) {
  PassPlan plan = scene_plan;
  if (plan.shadow != ShadowMode::Hard) {  // S rays per area light; point lights keep their one ray
    plan.shadow = ShadowMode::SoftFraction;
    plan.samples_per_light = reference.samples_per_light;
  }
  TraceSettings ts = settings;
  ts.lattice = reference.lattice;
  const VisibilityCounts vc = trace_visibility_counts(rt, g, plan, ts, stats);
  const size_t npx = size_t(g.width()) * size_t(g.height());
  std::vector<float> vis(npx * size_t(vc.lights));
  for (int l = 0; l < vc.lights; ++l)
    for (size_t i = 0; i < npx; ++i) vis[size_t(l) * npx + i] = vc.fraction(l, i);
  return vis;
}

std::vector<float> converged_ao(RtScene& rt, const GBuffer& g, const PassPlan& plan, const TraceSettings& settings,
                                const ReferenceRays& reference, TraceStats& stats) {
  TraceSettings ts = settings;
  ts.lattice = reference.lattice;
  const AoCounts ac = trace_ao_counts(rt, g, reference.ao_rays, plan.ao_radius_m, ts, stats);
  std::vector<float> ao(ac.unoccluded.size());
  for (size_t i = 0; i < ao.size(); ++i) ao[i] = float(ac.unoccluded[i]) / float(ac.rays);
  return ao;
}

}  // namespace dhr
