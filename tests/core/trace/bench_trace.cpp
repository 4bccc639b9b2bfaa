// Speed of the server's passes (core/trace/trace.h) against a raw Embree ceiling measured in the same
// run on the SAME rays: for each scene and pass, the rays the pass traces are collected into an
// array first (collect_*_rays), then traced by the simplest loops -- rtcOccluded1 per ray,
// rtcOccluded8 and rtcOccluded16 packets, rtcOccluded1M streams of 256 with the incoherent
// (default) and the coherent context flag -- each over the array split between the threads,
// on the pass's own scene (same flags, build quality, masks, tnear/tfar). The fastest is the
// ceiling; the pass reports Mrays/s (rays it
// traced / wall time of the whole pass: surface rebuild, ray generation, tracing, counting)
// and its ratio to the ceiling. Goal: >= 0.9.
// A floor beside it (floor/<scene>/<pass>): the least any pass must do besides tracing --
// read the G-buffer layers a surface needs (object id everywhere; prim id, barycentrics and
// normal where covered) and write its output (one 16-bit count per pixel and light, or per
// pixel for AO) -- and nothing else. The pass's `bound` counter is ceiling time / (ceiling time
// + floor time): the ratio a pass with free ray generation would reach. Where the bound is
// below 0.9 (few rays per pixel: one light, most surfaces facing away) the goal cannot be
// met by any implementation that reads its input.
//
// Scenes: the built-in scenes (scenes/*.json) and the real scenes (scenes/real/*.json, skipped
// when ../shared/scenes is missing), at 1280x720, camera at t = 0, G-buffer from Embree
// primary rays. Set DHR_BENCH_SCENES=room,temple to restrict the scenes, DHR_BENCH_THREADS=N
// for the thread count (default: all cores), DHR_BENCH_WIDE_KERNELS=0 for the baseline
// (non-AVX-512) kernels. Mrays_per_s is per wall second, Mrays_per_cpu_s
// per process CPU second; the ratio uses CPU seconds, which a busy shared machine disturbs
// least.
//
// Run: build-x/tests/bench_trace --benchmark_counters_tabular=true
#include "core/base/error.h"
#include "core/scene/scene_load.h"
#include "core/trace/rt_scene.h"
#include "core/trace/trace.h"
#include "core/trace/trace_rays.h"

#include <benchmark/benchmark.h>
#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace dhr {
namespace {

constexpr int kWidth = 1280, kHeight = 720;

// Process CPU seconds (all threads). This machine is shared (2 cores, often many processes):
// wall time then measures the neighbours, so rates and ratios are also given per CPU second.
double cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

struct BenchScene {
  std::string name;
  Scene scene;
  std::unique_ptr<RtScene> rt;
  GBuffer gbuf;
};

struct PassCase {
  std::string name;  // hard, soft, soft16, ao8
  TraceSettings settings;
  PassPlan plan;
  std::vector<RTCRay> rays;    // exactly what the pass traces
  uint64_t expected_rays = 0;  // where `rays` is not collected (scene_layout rows): their number
  double ceiling_mrays = 0.0;
  std::string ceiling_kind;
  // Per ceiling loop, the rate of its longest run: Google Benchmark calls a benchmark several
  // times with growing iteration counts and reports the last; the short calls before it are
  // noisy and must not set the ceiling.
  std::map<std::string, std::pair<int64_t, double>> loop_rates;  // kind -> (iterations, Mrays/s)
  double floor_cpu_s = 0.0;  // per pass: reading the G-buffer and writing the output
};

// The floor: read what a surface needs from the G-buffer and write `outputs` 16-bit counts
// per pixel, nothing else (rows split between the threads like the passes').
void floor_pass(const GBuffer& g, int outputs, std::vector<uint16_t>& out) {
  const int w = g.width(), h = g.height();
  const size_t npx = size_t(w) * size_t(h);
  out.resize(npx * size_t(outputs));
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      for (int x = 0; x < w; ++x) {
        uint16_t v = 0;
        if (g.object_id(x, y) != kBackgroundId) {
          const glm::vec2 b = g.bary(x, y);
          const glm::vec3 n = g.geo_normal(x, y);
          v = uint16_t(g.prim_id(x, y) + uint32_t(b.x + b.y + n.x + n.y + n.z > 0.5f));
        }
        const size_t pixel = size_t(y) * size_t(w) + size_t(x);
        for (int k = 0; k < outputs; ++k) out[size_t(k) * npx + pixel] = v;
      }
    }
  });
}

std::map<std::string, PassCase>& cases() {
  static std::map<std::string, PassCase> m;
  return m;
}

std::map<std::string, std::unique_ptr<BenchScene>>& scenes() {
  static std::map<std::string, std::unique_ptr<BenchScene>> m;
  return m;
}

// layout: "default", or a scene_layout row's "robust" (RTC_SCENE_FLAG_ROBUST) or "static_child"
// (RtSceneOptions::static_child, the layout before the two-level one).
BenchScene& load(const std::string& file, const std::string& name, const std::string& layout = "default") {
  const std::string key = name + "#" + layout;
  auto& m = scenes();
  auto it = m.find(key);
  if (it != m.end()) return *it->second;
  // Only one large scene in memory at a time, and only its passes' rays (soft16 holds 16 rays
  // per light and pixel: about 2 GB on room at 1280x720).
  m.clear();
  std::erase_if(cases(), [&](const auto& kv) { return !kv.first.starts_with(name + "/"); });
  auto b = std::make_unique<BenchScene>();
  b->name = name;
  b->scene = load_scene(file, SceneSearchPath::standard());
  RtSceneOptions opt;
  opt.robust = layout == "robust";
  opt.static_child = layout == "static_child";
  if (const char* t = std::getenv("DHR_BENCH_THREADS")) opt.threads = std::atoi(t);
  b->rt = std::make_unique<RtScene>(b->scene, opt);
  const Camera cam = b->scene.camera.at(0.0, kWidth, kHeight);
  b->gbuf = b->rt->primary_gbuffer(cam, 0.0);
  return *m.emplace(key, std::move(b)).first->second;
}

// load(), or the benchmark skipped with the error (a real scene whose files are missing).
BenchScene* load_or_skip(benchmark::State& state, const std::string& file, const std::string& name,
                         const std::string& layout = "default") {
  try {
    return &load(file, name, layout);
  } catch (const Error& e) {
    state.SkipWithError(e.what());
    for (auto _ : state) {}
    return nullptr;
  }
}

// Fresh copies every iteration: Embree overwrites tfar of occluded rays.
void trace_1m(RTCScene scene, const std::vector<RTCRay>& rays) {
  tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    alignas(64) RTCRay buf[256];
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    for (size_t i = r.begin(); i < r.end(); i += 256) {
      const unsigned n = unsigned(std::min<size_t>(256, r.end() - i));
      std::memcpy(buf, &rays[i], n * sizeof(RTCRay));
      rtcOccluded1M(scene, &ctx, buf, n, sizeof(RTCRay));
      benchmark::DoNotOptimize(buf[0].tfar);
    }
  });
}

void trace_1(RTCScene scene, const std::vector<RTCRay>& rays) {
  tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    for (size_t i = r.begin(); i < r.end(); ++i) {
      RTCRay ray = rays[i];
      rtcOccluded1(scene, &ctx, &ray);
      benchmark::DoNotOptimize(ray.tfar);
    }
  });
}

void trace_8(RTCScene scene, const std::vector<RTCRay>& rays) {
  tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRay8 p;
    alignas(32) int valid[8];
    for (size_t i = r.begin(); i < r.end(); i += 8) {
      const size_t n = std::min<size_t>(8, r.end() - i);
      for (size_t k = 0; k < 8; ++k) {
        valid[k] = k < n ? -1 : 0;
        const RTCRay& s = rays[i + std::min(k, n - 1)];
        p.org_x[k] = s.org_x, p.org_y[k] = s.org_y, p.org_z[k] = s.org_z, p.tnear[k] = s.tnear;
        p.dir_x[k] = s.dir_x, p.dir_y[k] = s.dir_y, p.dir_z[k] = s.dir_z, p.time[k] = s.time;
        p.tfar[k] = s.tfar, p.mask[k] = s.mask, p.id[k] = s.id, p.flags[k] = s.flags;
      }
      rtcOccluded8(valid, scene, &ctx, &p);
      benchmark::DoNotOptimize(p.tfar[0]);
    }
  });
}

// 16-wide packets: native with Embree's AVX-512 kernels (emulated with 2x8 on AVX2 machines).
void trace_16(RTCScene scene, const std::vector<RTCRay>& rays) {
  tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRay16 p;
    alignas(64) int valid[16];
    for (size_t i = r.begin(); i < r.end(); i += 16) {
      const size_t n = std::min<size_t>(16, r.end() - i);
      for (size_t k = 0; k < 16; ++k) {
        valid[k] = k < n ? -1 : 0;
        const RTCRay& s = rays[i + std::min(k, n - 1)];
        p.org_x[k] = s.org_x, p.org_y[k] = s.org_y, p.org_z[k] = s.org_z, p.tnear[k] = s.tnear;
        p.dir_x[k] = s.dir_x, p.dir_y[k] = s.dir_y, p.dir_z[k] = s.dir_z, p.time[k] = s.time;
        p.tfar[k] = s.tfar, p.mask[k] = s.mask, p.id[k] = s.id, p.flags[k] = s.flags;
      }
      rtcOccluded16(valid, scene, &ctx, &p);
      benchmark::DoNotOptimize(p.tfar[0]);
    }
  });
}

// Streams with the coherent context flag (Embree then sorts the stream into packets).
void trace_1m_coherent(RTCScene scene, const std::vector<RTCRay>& rays) {
  tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    alignas(64) RTCRay buf[256];
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    for (size_t i = r.begin(); i < r.end(); i += 256) {
      const unsigned n = unsigned(std::min<size_t>(256, r.end() - i));
      std::memcpy(buf, &rays[i], n * sizeof(RTCRay));
      rtcOccluded1M(scene, &ctx, buf, n, sizeof(RTCRay));
      benchmark::DoNotOptimize(buf[0].tfar);
    }
  });
}

// A pass's name, settings and plan, without its rays.
PassCase case_settings(const BenchScene& b, const std::string& pass) {
  PassCase c;
  c.name = pass;
  if (pass == "hard") c.settings.soft_shadows = false;
  if (pass == "soft") c.settings.soft_shadows = true;
  if (pass == "soft16") {  // the cone loop of S > 1 rays per light, as the ground truth traces
    c.settings.soft_shadows = true;
    c.settings.samples_per_light = 16;
  }
  if (pass == "ao8") c.settings.ao_rays = 8;
  // DHR_BENCH_WIDE_KERNELS=0: the baseline kernels (TraceSettings::wide_kernels = false), to
  // compare with the AVX-512 ones in the same build (same rays, same bits).
  if (const char* v = std::getenv("DHR_BENCH_WIDE_KERNELS")) c.settings.wide_kernels = std::strcmp(v, "0") != 0;
  c.plan = plan_passes(b.scene, c.settings);
  return c;
}

// The AO pass's radius: the scene's, or 1 m for a scene without an AO block.
float ao_radius(const BenchScene& b, const PassCase& c) { return b.scene.ao ? c.plan.ao_radius_m : 1.0f; }

PassCase make_case(BenchScene& b, const std::string& pass) {
  PassCase c = case_settings(b, pass);
  if (pass == "ao8") {
    c.rays = collect_ao_rays(*b.rt, b.gbuf, 8, ao_radius(b, c), c.settings);
  } else if (c.plan.visibility()) {
    c.rays = collect_visibility_rays(*b.rt, b.gbuf, c.plan, c.settings);
  }
  return c;
}

// Returns the pass's Mrays/s (rays traced / wall time of the whole pass).
double run_pass(BenchScene& b, PassCase& c, benchmark::State& state) {
  uint64_t rays = 0;
  const auto t0 = std::chrono::steady_clock::now();
  const double c0 = cpu_seconds();
  for (auto _ : state) {
    TraceStats st;
    if (c.name == "ao8") {
      benchmark::DoNotOptimize(trace_ao_counts(*b.rt, b.gbuf, 8, ao_radius(b, c), c.settings, st));
      rays = st.ao_rays;
    } else {
      benchmark::DoNotOptimize(trace_visibility_counts(*b.rt, b.gbuf, c.plan, c.settings, st));
      rays = st.shadow_rays;
    }
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const uint64_t want = c.rays.empty() ? c.expected_rays : c.rays.size();
  if (rays != want) state.SkipWithError(fmt::format("pass traced {} rays, expected {}", rays, want).c_str());
  state.counters["Mrays_per_s"] =
      benchmark::Counter(double(rays) * 1e-6 * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["rays"] = double(rays);
  const double cpu = cpu_seconds() - c0;
  (void)s;
  const double rate = double(rays) * 1e-6 * double(state.iterations()) / cpu;
  state.counters["Mrays_per_cpu_s"] = rate;
  return rate;
}

void register_scene(const std::string& file) {
  const std::string name = std::filesystem::path(file).stem().string();
  if (const char* only = std::getenv("DHR_BENCH_SCENES")) {
    const std::string list = std::string(",") + only + ",";
    if (list.find("," + name + ",") == std::string::npos) return;
  }
  for (const std::string pass : {"hard", "soft", "soft16", "ao8"}) {
    const std::string key = name + "/" + pass;
    // Ceilings first (registration order is run order), then the pass itself.
    for (const std::string kind : {"occluded1", "occluded8", "occluded16", "occluded1M", "occluded1M_coherent"}) {
      benchmark::RegisterBenchmark(
          ("ceiling/" + key + "/" + kind).c_str(),
          [=](benchmark::State& state) {
            BenchScene* b = load_or_skip(state, file, name);
            if (!b) return;
            auto& cs = cases();
            if (!cs.count(key)) cs[key] = make_case(*b, pass);
            PassCase& c = cs[key];
            if (c.rays.empty()) {
              state.SkipWithError("no rays (the scene has no such pass)");
              for (auto _ : state) {}
              return;
            }
            const RTCScene scene = b->rt->handle();
            const auto t0 = std::chrono::steady_clock::now();
            const double c0 = cpu_seconds();
            b->rt->arena().execute([&] {
              for (auto _ : state) {
                if (kind == "occluded1") trace_1(scene, c.rays);
                if (kind == "occluded8") trace_8(scene, c.rays);
                if (kind == "occluded16") trace_16(scene, c.rays);
                if (kind == "occluded1M") trace_1m(scene, c.rays);
                if (kind == "occluded1M_coherent") trace_1m_coherent(scene, c.rays);
              }
            });
            const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            const double mrays = double(c.rays.size()) * 1e-6 * double(state.iterations());
            state.counters["Mrays_per_s"] = benchmark::Counter(mrays, benchmark::Counter::kIsRate);
            state.counters["rays"] = double(c.rays.size());
            const double cpu = cpu_seconds() - c0;
            state.counters["Mrays_per_cpu_s"] = mrays / cpu;
            (void)s;
            const double rate = mrays / cpu;  // kept for the pass's ratio (per CPU second)
            auto& [iterations, kind_rate] = c.loop_rates[kind];
            if (int64_t(state.iterations()) >= iterations) {
              iterations = int64_t(state.iterations());
              kind_rate = rate;
            }
            c.ceiling_mrays = 0.0;
            for (const auto& [k, r] : c.loop_rates) {
              if (r.second > c.ceiling_mrays) {
                c.ceiling_mrays = r.second;
                c.ceiling_kind = k;
              }
            }
          })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(1.0);
    }
    benchmark::RegisterBenchmark(("floor/" + key).c_str(),
                                 [=](benchmark::State& state) {
                                   BenchScene* b = load_or_skip(state, file, name);
                                   if (!b) return;
                                   auto& cs = cases();
                                   if (!cs.count(key)) cs[key] = make_case(*b, pass);
                                   PassCase& c = cs[key];
                                   const int outputs = pass == "ao8" ? 1 : std::max(1, c.plan.lights);
                                   std::vector<uint16_t> out;
                                   const double c0 = cpu_seconds();
                                   b->rt->arena().execute([&] {
                                     for (auto _ : state) {
                                       floor_pass(b->gbuf, outputs, out);
                                       benchmark::DoNotOptimize(out.data());
                                     }
                                   });
                                   c.floor_cpu_s = (cpu_seconds() - c0) / double(state.iterations());
                                   state.counters["cpu_ms"] = c.floor_cpu_s * 1e3;
                                 })
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime()
        ->MinTime(0.5);
    benchmark::RegisterBenchmark(("pass/" + key).c_str(),
                                 [=](benchmark::State& state) {
                                   auto& cs = cases();
                                   BenchScene* bp = load_or_skip(state, file, name);
                                   if (!bp) return;
                                   BenchScene& b = *bp;
                                   if (!cs.count(key))
                                     cs[key] = make_case(b, pass);  // filtered run without the ceilings
                                   PassCase& c = cs[key];
                                   if (c.rays.empty()) {
                                     state.SkipWithError("no rays (the scene has no such pass)");
                                     for (auto _ : state) {}
                                     return;
                                   }
                                   const double rate = run_pass(b, c, state);
                                   state.counters["ceiling_Mrays_per_s"] = c.ceiling_mrays;
                                   state.counters["ratio"] = rate / c.ceiling_mrays;
                                   if (c.floor_cpu_s > 0.0 && c.ceiling_mrays > 0.0) {
                                     const double ceiling_s = double(c.rays.size()) * 1e-6 / c.ceiling_mrays;
                                     state.counters["bound"] = ceiling_s / (ceiling_s + c.floor_cpu_s);
                                   }
                                   state.SetLabel("ceiling: " + c.ceiling_kind);
                                 })
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime()
        ->MinTime(1.0);
  }
}

// The scene's layout against its cost, measured on the passes themselves: RTC_SCENE_FLAG_ROBUST
// and the older static-child layout (RtSceneOptions::static_child; a scene with moving objects
// only) beside the default two-level one, on AO (8 rays),
// hard shadows and 16 rays per area light (the ground truth's cone loop). Every layout traces
// from the default layout's G-buffer (primary rays can differ too). `counts_differ`: the counts
// (per pixel, and light) that differ from the default layout's, whose row runs first;
// `kernels_differ`: the counts where the baseline kernels differ from the vector kernels on
// this layout (tests/core/trace/test_trace_bits.cpp checks the default layout on its pinned images).
struct LayoutDefault {
  GBuffer gbuf;
  std::map<std::string, std::vector<uint16_t>> counts;  // by pass
};
std::map<std::string, LayoutDefault>& layout_defaults() {  // by scene
  static std::map<std::string, LayoutDefault> m;
  return m;
}

std::vector<uint16_t> layout_counts(BenchScene& b, const PassCase& c, bool wide, TraceStats& st) {
  TraceSettings s = c.settings;
  s.wide_kernels = wide;
  if (c.name == "ao8") return trace_ao_counts(*b.rt, b.gbuf, 8, ao_radius(b, c), s, st).unoccluded;
  return trace_visibility_counts(*b.rt, b.gbuf, c.plan, s, st).visible;
}

size_t count_differ(const std::vector<uint16_t>& a, const std::vector<uint16_t>& b) {
  if (a.size() != b.size()) return std::max(a.size(), b.size());
  size_t n = 0;
  for (size_t i = 0; i < a.size(); ++i) n += a[i] != b[i];
  return n;
}

void register_layouts(const std::string& file) {
  const std::string name = std::filesystem::path(file).stem().string();
  if (const char* only = std::getenv("DHR_BENCH_SCENES")) {
    const std::string list = std::string(",") + only + ",";
    if (list.find("," + name + ",") == std::string::npos) return;
  }
  for (const std::string pass : {"ao8", "hard", "soft16"}) {
    for (const std::string layout : {"default", "robust", "static_child"}) {
      benchmark::RegisterBenchmark(
          fmt::format("scene_layout/{}/{}/{}", name, pass, layout).c_str(),
          [=](benchmark::State& state) {
            BenchScene* b = load_or_skip(state, file, name, layout);
            if (!b) return;
            LayoutDefault& d = layout_defaults()[name];
            if (layout == "default")
              d.gbuf = b->gbuf;
            else if (d.gbuf.width() == b->gbuf.width())
              b->gbuf = d.gbuf;
            PassCase c = case_settings(*b, pass);
            if (pass != "ao8" && !c.plan.visibility()) {
              state.SkipWithError("the scene has no lights");
              for (auto _ : state) {}
              return;
            }
            TraceStats st;
            const std::vector<uint16_t> counts = layout_counts(*b, c, c.settings.wide_kernels, st);
            c.expected_rays = pass == "ao8" ? st.ao_rays : st.shadow_rays;
            run_pass(*b, c, state);
            TraceStats other;
            state.counters["kernels_differ"] =
                double(count_differ(counts, layout_counts(*b, c, !c.settings.wide_kernels, other)));
            if (layout == "default") d.counts[pass] = counts;
            const auto it = d.counts.find(pass);
            if (it != d.counts.end()) state.counters["counts_differ"] = double(count_differ(counts, it->second));
          })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(1.0);
    }
  }
}

}  // namespace
}  // namespace dhr

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  std::vector<std::string> files = dhr::builtin_scene_files();
  for (const auto& f : files) dhr::register_scene(f);
  for (const auto& f : dhr::real_scene_files()) dhr::register_scene(f);
  for (const auto& f : files) dhr::register_layouts(f);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
