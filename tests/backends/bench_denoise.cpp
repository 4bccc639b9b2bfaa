// Denoiser cost at 1280x720 against the cost of tracing ONE more AO ray per pixel on the same
// scene, measured in the same run (the project's ceiling rule: docs/architecture.md, "What is
// measured"). Goal: svgf_ao costs less than one extra AO ray per pixel.
//
// Scene: scenes/room.json (the built-in PINK ROOM stand-in), G-buffer by the rasterizer
// (core/raster/raster.h) at t = 1 s of its camera path, AO traced by core/trace/trace.h with the scene's
// radius. Denoiser input: 8-ray AO counts (full_scale 8), four noise realisations (frames
// 0..3) cycled so every frame brings new noise.
//   BM_TraceAoOneRay            : trace_ao with 1 ray per pixel (the ceiling)
//   BM_Denoise/<name>/steady    : static camera, history full (temporal denoisers at
//                                 steady state; the spatial ones have no history anyway)
//   BM_Denoise/<name>/reset     : every frame with history_valid = false (a camera cut: the
//                                 temporal denoisers take their spatial-variance path
//                                 everywhere: the worst case, what disoccluded pixels cost)
// The interleaved table also times svgf_ao with a 3x3 kernel, with 3x3 and 3 iterations, with
// one 5x5 iteration (what its default accuracy costs in time), with the exact weights of
// fast_weights = false, and with light_history 4, 8, 16 (DHR-S 3.3's lightweight path for pixels
// with a long history).
// After the runs two tables print ms per frame and the ratio to one AO ray: the Google
// Benchmark figures, and the fastest frame of --rounds=N (default 9) interleaved rounds of
// every configuration (the fair comparison on a shared, fluctuating machine).
//
// With --fast_weights_diff=N (run by hand; instead of the benchmarks; --scenes=a,b to choose):
// svgf_ao with its default fast weights against fast_weights = false on N frames of each
// scene's camera path at 1280x720: the share of output pixels equal, 1 level apart, 2 or more.
//
// With --accuracy (run by hand; instead of the benchmarks; about 5 minutes for all eight
// scenes on 2 cores): the accuracy-versus-time table at 640x360, for each scene: AO rays
// {1, 2, 4, 8, 16, 32, 64} x denoiser {none, single_iteration, atrous, svgf_ao} x frame of
// history {1, 8}: SSIM and MAE (8-bit levels) of the denoised AO against
// converged AO (1024 rays; --reference_rays=N), with trace and denoise wall time. The camera is
// static at t = 1 s of the scene's path; frame f traces a fresh noise realisation (frame
// index f of core/base/rng.h) and the denoiser keeps its history, so "frame 8" is the best case of
// the temporal denoisers (a still camera) and "frame 1" their worst (no history; a camera
// cut). The spatial denoisers (none, atrous) have no history: their frame-8 row is just
// another noise realisation. Times are the fastest of several runs on the shared machine:
// trace_ms per ray count = the fastest of its 8 frames' traces and of 5 more interleaved
// timing rounds (same work, other noise); denoise_ms per denoiser (its work does not depend on
// the ray count) = for frame 1 the fastest first-frame path (history_valid = false) of the 5
// rounds, for frame 8 the fastest steady frame (history >= 4 everywhere) of frames 5..8 of
// every ray count and of the 5 rounds. Progress goes to stderr, the table to stdout and, with
// --csv=PATH, to a CSV file (one row per scene, rays, denoiser, frame of history).
//   --frames=N        score frame 1 and frame N of history instead of frame 8 (N frames are
//                     traced per ray count; "steady" timing then takes frames 5..N)
//   --scenes=a,b,...  the scenes (default: every built-in scene, scenes/*.json, then every
//                     real one, scenes/real/*.json). A real scene whose files are missing
//                     (../shared/scenes absent) is skipped with a message on stderr.
//
// Run: build-*/tests/bench_denoise [--rounds=9] [--benchmark_filter=...]
//      build-*/tests/bench_denoise --accuracy [--scenes=room,temple] [--csv=PATH] [--reference_rays=1024]
//          [--frames=8] [--denoisers='svgf_ao svgf_ao{"light_history":8}']
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "core/base/error.h"
#include "core/buffers/gbuffer.h"
#include "core/metrics/metrics.h"
#include "core/raster/raster.h"
#include "core/scene/scene.h"
#include "core/scene/scene_load.h"
#include "core/trace/rt_scene.h"
#include "core/trace/trace.h"

#include <benchmark/benchmark.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

namespace dhr {
namespace {

struct Setup {
  Scene scene;
  std::unique_ptr<RtScene> rt;
  GBuffer gbuf;
  PassPlan plan;
  std::vector<ImageU8> noisy;  // 8-ray AO counts, frames 0..3
  int rays = 8;
};

// AO counts of `rays` rays for frame `frame` as an 8-bit image (full_scale = rays).
ImageU8 trace_ao_image(const Scene& scene, RtScene& rt, const GBuffer& gbuf, int rays, uint32_t frame,
                       double* ms = nullptr) {
  TraceSettings ts;
  ts.seed = 1;
  ts.frame = frame;
  ts.ao_rays = rays;
  TraceStats stats;
  PassPlan plan = plan_passes(scene, ts);
  const auto t0 = std::chrono::steady_clock::now();
  PassBuffer ao = trace_ao(rt, gbuf, plan, ts, stats);
  const auto t1 = std::chrono::steady_clock::now();
  if (ms) *ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
  ImageU8 img(gbuf.width(), gbuf.height());
  std::memcpy(img.data(), ao.bytes.data(), img.size());
  return img;
}

// The G-buffer at time t, its motion vectors from the previous frame at prev_t (default: t, no motion).
GBuffer raster_gbuffer(const Scene& scene, int w, int h, double t, double prev_t = -1.0) {
  if (prev_t < 0.0) prev_t = t;
  RasterFrame rf;
  rf.scene = &scene;
  rf.camera = scene.camera.at(t, w, h);
  rf.prev_camera = scene.camera.at(prev_t, w, h);
  rf.time_s = t;
  rf.prev_time_s = prev_t;
  GBuffer g;
  rasterize(rf, g);
  return g;
}

Setup& setup() {
  static Setup s = [] {
    Setup r;
    r.scene = load_scene_or_model("room", SceneSearchPath::standard());
    r.rt = std::make_unique<RtScene>(r.scene);
    r.gbuf = raster_gbuffer(r.scene, 1280, 720, 1.0);
    r.rt->set_time(r.gbuf.time_s);
    for (uint32_t f = 0; f < 4; ++f) r.noisy.push_back(trace_ao_image(r.scene, *r.rt, r.gbuf, r.rays, f));
    return r;
  }();
  return s;
}

void BM_TraceAoOneRay(benchmark::State& state) {
  Setup& s = setup();
  TraceSettings ts;
  ts.ao_rays = 1;
  const PassPlan plan = plan_passes(s.scene, ts);
  uint32_t frame = 0;
  for (auto _ : state) {
    ts.frame = frame++;
    TraceStats stats;
    PassBuffer ao = trace_ao(*s.rt, s.gbuf, plan, ts, stats);
    benchmark::DoNotOptimize(ao.bytes.data());
  }
}
BENCHMARK(BM_TraceAoOneRay)->Unit(benchmark::kMillisecond)->UseRealTime();

// ---- The arithmetic floor of svgf_ao's a-trous iterations (docs/performance.md). With the
// exact weights (fast_weights = false) each of the 24 off-centre taps of a 16-pixel AVX-512
// block is 45 vector instructions in the compiled kernel (atrous_block16_unrolled in
// backends/denoise/filters_kernels.cpp, counted in its disassembly: 23 multiplies, 14
// adds/subtracts, 2 abs (and), max, compare, vrndscaleps, vscalefps, and 2 broadcasts of the
// tap's constants) and 43 without the broadcasts, the fewest known with the same bits (dot 5,
// clamp 1, 7 squarings, depth term 4, AO term 3, their sum 1, exponential 14 -- scale 1,
// rounding 3, polynomial 8, exponent 1, underflow mask 1 --, weight 2, sums 6: the operations
// the bits depend on, in order). With the fast weights (the default) a tap is 33 instructions
// on average in the compiled kernel (29-38 between two vscalefps in the disassembly of
// atrous_blocks16<7, 2, true>, which atrous_row16_all runs for its unmasked blocks: the
// operations, broadcasts of constants and register copies for the FMAs) and 31 operations
// without those (dot 3 with two FMAs, clamp 1, 7 squarings, |dz| and |dl| 4, their weighted sum
// 2, rounding 1, fraction 1, polynomial 3, exponent 1, cut mask 1, weight 2, sums 4). The
// machine's rate of independent 16-lane float multiplies and adds (no loads, no dependencies
// between the chains, all threads; an FMA is one instruction like a multiply) turns those
// counts into CPU milliseconds per frame: the least the five iterations can cost at 1280x720 on
// this machine.
constexpr int kTapOpsCompiled = 33, kTapOpsMinimal = 31;            // fast weights, the default
constexpr int kTapOpsCompiledExact = 45, kTapOpsMinimalExact = 43;  // fast_weights = false

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
using Vec16 = float __attribute__((vector_size(64)));
// 2 * kChains * n 16-lane operations (a multiply and an add per chain and step).
__attribute__((target("avx512f"), optimize("fp-contract=off"), noinline)) float vector_ops(int64_t n, float seed) {
  constexpr int kChains = 12;
  Vec16 x[kChains];
  for (int c = 0; c < kChains; ++c) x[c] = Vec16{} + (seed + float(c));
  const Vec16 a = Vec16{} + 0.999999f, b = Vec16{} + 1e-7f;
  for (int64_t i = 0; i < n; ++i)
    for (int c = 0; c < kChains; ++c) x[c] = x[c] * a + b;  // fp-contract=off: two instructions
  float s = 0.0f;
  for (int c = 0; c < kChains; ++c) s += x[c][0];
  return s;
}
bool have_avx512() { return __builtin_cpu_supports("avx512f"); }
#else
float vector_ops(int64_t, float) { return 0.0f; }
bool have_avx512() { return false; }
#endif

// 16-lane operations per process CPU second, on all threads.
double vector_op_rate() {
  constexpr int64_t kSteps = 20'000'000;
  constexpr int kChainsOps = 24;  // 2 * kChains
  const int threads = int(tbb::this_task_arena::max_concurrency());
  timespec t0{}, t1{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t0);
  std::vector<float> sink(size_t(threads), 0.0f);
  tbb::parallel_for(0, threads, [&](int t) { sink[size_t(t)] = vector_ops(kSteps, float(t)); });
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t1);
  benchmark::DoNotOptimize(sink.data());
  const double cpu = double(t1.tv_sec - t0.tv_sec) + 1e-9 * double(t1.tv_nsec - t0.tv_nsec);
  return double(kSteps) * kChainsOps * threads / cpu;
}

void BM_Denoise(benchmark::State& state, const std::string& name, bool reset_every_frame) {
  Setup& s = setup();
  auto d = registries().denoisers.create(name, nlohmann::json::object());
  ImageU8 out;
  uint32_t frame = 0;
  // Warm up to a full history (history cap 32).
  for (; frame < 40; ++frame) d->denoise(DenoiseInput{s.gbuf, s.noisy[frame % 4], s.rays, frame, true}, out);
  for (auto _ : state) {
    d->denoise(DenoiseInput{s.gbuf, s.noisy[frame % 4], s.rays, frame, !reset_every_frame}, out);
    ++frame;
    benchmark::DoNotOptimize(out.data());
  }
}

// ---- the summary table: ms per frame and the ratio to one AO ray, from the same run.
class Collector : public benchmark::ConsoleReporter {
 public:
  std::map<std::string, double> ms;
  void ReportRuns(const std::vector<Run>& runs) override {
    // The fastest repetition: on a shared machine the minimum is the least disturbed figure.
    for (const auto& r : runs)
      if (r.run_type == Run::RT_Iteration && r.iterations > 0) {
        const double v = r.real_accumulated_time / double(r.iterations) * 1e3;
        auto [it, fresh] = ms.emplace(r.benchmark_name(), v);
        if (!fresh) it->second = std::min(it->second, v);
      }
    ConsoleReporter::ReportRuns(runs);
  }
};

// ---- Interleaved minima: on a shared machine the load changes from second to second, so the
// summary times one frame of every configuration per round, round after round, and keeps
// each configuration's fastest frame: every configuration sees the same conditions.
struct Config {
  std::string label;
  std::string denoiser;  // empty: trace one AO ray per pixel
  bool reset_every_frame = false;
  nlohmann::json params = nlohmann::json::object();
};

struct Minima {
  std::string label;
  double wall_ms, cpu_ms;
};

double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) * 1e3 + double(ts.tv_nsec) * 1e-6;
}

std::vector<Minima> interleaved_minima(int rounds) {
  Setup& s = setup();
  std::vector<Config> configs = {{"trace 1 AO ray/px", "", false}};
  for (const std::string name : {"none", "temporal", "single_iteration", "atrous", "svgf_ao"}) {
    configs.push_back({name + " (steady)", name, false});
    if (name != "none" && name != "atrous") configs.push_back({name + " (reset)", name, true});
  }
  // What svgf_ao's accuracy costs: its default (five 5x5 iterations, as SVGF) against a 3x3
  // kernel and fewer iterations (the paper's section 3.3 suggests both once history is long).
  configs.push_back({"svgf_ao 3x3 kernel (steady)", "svgf_ao", false, {{"kernel_radius", 1}}});
  configs.push_back(
      {"svgf_ao 3x3 kernel, 3 iterations (steady)", "svgf_ao", false, {{"kernel_radius", 1}, {"iterations", 3}}});
  configs.push_back({"svgf_ao 5x5 kernel, 1 iteration (steady)", "svgf_ao", false, {{"iterations", 1}}});
  // The same filter with its a-trous weights by separate products and sums and a degree-4
  // exponential (fast_weights false), the filter without the default fast weights.
  configs.push_back({"svgf_ao exact weights (steady)", "svgf_ao", false, {{"fast_weights", false}}});
  configs.push_back({"svgf_ao exact weights (reset)", "svgf_ao", true, {{"fast_weights", false}}});
  // The paper's lightweight path for long history (light_history = L: one 3x3 iteration where
  // the history has L frames or more). Steady: every pixel is at history_cap (32) >= L, so the
  // whole image takes it; reset: no pixel does (history 1), the full path everywhere.
  for (int l : {4, 8, 16}) {
    const std::string label = "svgf_ao light_history " + std::to_string(l);
    configs.push_back({label + " (steady)", "svgf_ao", false, {{"light_history", l}}});
    configs.push_back({label + " (reset)", "svgf_ao", true, {{"light_history", l}}});
  }
  std::vector<std::unique_ptr<Denoiser>> dens;
  std::vector<uint32_t> frames(configs.size(), 0);
  ImageU8 out;
  for (const auto& c : configs) {
    dens.push_back(c.denoiser.empty() ? nullptr : registries().denoisers.create(c.denoiser, c.params));
    if (dens.back())
      for (uint32_t f = 0; f < 40; ++f)
        dens.back()->denoise(DenoiseInput{s.gbuf, s.noisy[f % 4], s.rays, f, true}, out);
  }
  TraceSettings ts;
  ts.ao_rays = 1;
  const PassPlan plan = plan_passes(s.scene, ts);
  std::vector<double> best(configs.size(), 1e30), best_cpu(configs.size(), 1e30);
  for (int r = 0; r < rounds; ++r)
    for (size_t i = 0; i < configs.size(); ++i) {
      const auto t0 = std::chrono::steady_clock::now();
      const double c0 = process_cpu_ms();
      if (!dens[i]) {
        ts.frame = uint32_t(r);
        TraceStats stats;
        PassBuffer ao = trace_ao(*s.rt, s.gbuf, plan, ts, stats);
        benchmark::DoNotOptimize(ao.bytes.data());
      } else {
        const uint32_t f = 40 + frames[i]++;
        dens[i]->denoise(DenoiseInput{s.gbuf, s.noisy[f % 4], s.rays, f, !configs[i].reset_every_frame}, out);
      }
      const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      best[i] = std::min(best[i], ms);
      best_cpu[i] = std::min(best_cpu[i], process_cpu_ms() - c0);
    }
  std::vector<Minima> res;
  for (size_t i = 0; i < configs.size(); ++i) res.push_back({configs[i].label, best[i], best_cpu[i]});
  return res;
}

// ---- --accuracy: the accuracy-versus-time table.
struct AccuracyOptions {
  std::vector<std::string> scenes;  // empty: every built-in and real scene
  // empty: none, single_iteration, atrous, svgf_ao with defaults; an entry is a name, or a name
  // followed by its parameters as JSON: svgf_ao{"kernel_radius":1}
  std::vector<std::string> denoisers;
  std::string csv_path;  // empty: no CSV
  int reference_rays = 1024;
  int frames = 8;  // the frames of history scored: the first and this one
};

double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

std::string file_stem(const std::string& path) { return std::filesystem::path(path).stem().string(); }

// The scenes a by-hand mode runs: --scenes (each a built-in or real scene's name; an unknown one
// fails, naming the valid ones), or all of them. The real ones need ../shared/scenes: the modes
// skip one that does not load.
struct SceneList {
  std::vector<std::string> names, real;
  bool is_real(const std::string& n) const { return std::find(real.begin(), real.end(), n) != real.end(); }
};
SceneList scene_list(const AccuracyOptions& opt) {
  SceneList l;
  std::vector<std::string> builtin;
  for (const auto& f : builtin_scene_files()) builtin.push_back(file_stem(f));
  for (const auto& f : real_scene_files()) l.real.push_back(file_stem(f));
  l.names = opt.scenes;
  if (l.names.empty()) {
    l.names = builtin;
    l.names.insert(l.names.end(), l.real.begin(), l.real.end());
  }
  std::string valid;
  for (const auto& n : builtin) valid += " " + n;
  for (const auto& n : l.real) valid += " " + n;
  for (const auto& n : l.names)
    if (std::find(builtin.begin(), builtin.end(), n) == builtin.end() && !l.is_real(n))
      fail("bench_denoise --scenes: unknown scene '{}' (valid:{})", n, valid);
  return l;
}

// Scene `name` of the list with an AO block, or nothing when it is skipped (a real scene that does
// not load, a scene without AO), said on stderr under `tag`; a built-in that does not load fails.
std::optional<Scene> load_listed(const SceneList& list, const std::string& name, const char* tag) {
  Scene scene;
  try {
    scene = load_scene_or_model(name, SceneSearchPath::standard());
  } catch (const Error& e) {
    if (!list.is_real(name)) throw;
    std::fprintf(stderr, "[%s] skipping real scene %s: it does not load (is ../shared/scenes there?):\n%s\n", tag,
                 name.c_str(), e.what());
    return std::nullopt;
  }
  if (!scene.ao) {
    std::fprintf(stderr, "[%s] skipping %s: the scene has no AO block\n", tag, name.c_str());
    return std::nullopt;
  }
  return scene;
}

void accuracy_table(const AccuracyOptions& opt) {
  const int w = 640, h = 360, kFrames = opt.frames, kTimingRounds = 5;
  const std::vector<int> kRays = {1, 2, 4, 8, 16, 32, 64};
  const double time_s = 1.0;
  const SceneList list = scene_list(opt);
  const std::vector<std::string>& scenes = list.names;
  std::ofstream csv;
  if (!opt.csv_path.empty()) {
    csv.open(opt.csv_path);
    if (!csv) fail("bench_denoise --csv={}: cannot open the file for writing", opt.csv_path);
    csv << "scene,width,height,reference_rays,rays,denoiser,frame_of_history,ssim,mae_levels,trace_ms,denoise_ms,"
           "total_ms,threads\n";
  }
  const int threads = int(tbb::this_task_arena::max_concurrency());
  const std::vector<std::string> denoisers =
      opt.denoisers.empty() ? std::vector<std::string>{"none", "single_iteration", "atrous", "svgf_ao"} : opt.denoisers;
  // "name" or "name{params}"; the CSV label replaces commas by semicolons.
  auto create = [](const std::string& spec) {
    const size_t brace = spec.find('{');
    const nlohmann::json params =
        brace == std::string::npos ? nlohmann::json::object() : nlohmann::json::parse(spec.substr(brace));
    return registries().denoisers.create(spec.substr(0, brace), params);
  };
  std::vector<std::string> labels;
  for (std::string d : denoisers) {
    std::replace(d.begin(), d.end(), ',', ';');
    labels.push_back(d);
  }
  for (const auto& d : denoisers) create(d);  // unknown names and parameters fail before any work
  for (const auto& name : scenes) {
    const auto t_load = std::chrono::steady_clock::now();
    std::optional<Scene> loaded = load_listed(list, name, "accuracy");
    if (!loaded) continue;
    Scene& scene = *loaded;
    RtScene rt(scene);
    const GBuffer g = raster_gbuffer(scene, w, h, time_s);
    rt.set_time(g.time_s);
    std::fprintf(stderr, "[accuracy] %s: loaded in %.1f s (%zu triangles)\n", name.c_str(), ms_since(t_load) / 1e3,
                 scene.triangle_count());
    // The converged reference: counts need more than 8 bits, hence trace_ao_counts.
    double ref_ms = 0.0;
    const ImageU8 ref = [&] {
      TraceSettings ts;
      ts.seed = 99;  // independent of the noisy frames (seed 1)
      ts.frame = 1000;
      TraceStats stats;
      const auto t0 = std::chrono::steady_clock::now();
      AoCounts c = trace_ao_counts(rt, g, opt.reference_rays, scene.ao->radius_m, ts, stats);
      ref_ms = ms_since(t0);
      ImageU8 img(w, h);
      for (size_t i = 0; i < img.size(); ++i)
        img[i] = uint8_t(std::lround(double(c.unoccluded[i]) * 255.0 / double(c.rays)));
      return img;
    }();
    std::fprintf(stderr, "[accuracy] %s: reference %d rays in %.1f s\n", name.c_str(), opt.reference_rays,
                 ref_ms / 1e3);
    std::printf("\nAccuracy vs time, %s at %dx%d, reference %d rays (%.0f ms to trace), %d threads\n", name.c_str(), w,
                h, opt.reference_rays, ref_ms, threads);
    std::printf("| rays | denoiser | frame | SSIM | MAE (levels) | trace ms | denoise ms | total ms |\n");
    std::printf("| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |\n");
    // Quality: 8 frames per ray count, each denoiser keeps its history across them.
    struct Row {
      int rays;
      size_t dn;
      int frame;
      double ssim, mae;
    };
    std::vector<Row> rows;
    std::vector<double> trace_ms(kRays.size(), 1e30);
    std::vector<double> first_ms(denoisers.size(), 1e30), steady_ms(denoisers.size(), 1e30);
    std::vector<ImageU8> last_noisy;  // the frames of the largest ray count (timing below)
    for (size_t ri = 0; ri < kRays.size(); ++ri) {
      const int rays = kRays[ri];
      const auto t_rays = std::chrono::steady_clock::now();
      std::vector<ImageU8> noisy;
      for (uint32_t f = 0; f < uint32_t(kFrames); ++f) {
        double ms = 0.0;
        noisy.push_back(trace_ao_image(scene, rt, g, rays, f, &ms));
        trace_ms[ri] = std::min(trace_ms[ri], ms);
      }
      for (size_t di = 0; di < denoisers.size(); ++di) {
        auto d = create(denoisers[di]);
        ImageU8 out;
        for (int f = 0; f < kFrames; ++f) {
          const auto t0 = std::chrono::steady_clock::now();
          d->denoise(DenoiseInput{g, noisy[size_t(f)], rays, uint32_t(f), true}, out);
          if (f >= 4) steady_ms[di] = std::min(steady_ms[di], ms_since(t0));
          if (f != 0 && f != kFrames - 1) continue;
          // Scored on 0..255: a denoiser that keeps its input's scale (none) is rescaled.
          if (const int scale = d->output_full_scale(rays); scale != 255)
            for (size_t i = 0; i < out.size(); ++i) out[i] = uint8_t((out[i] * 255 + scale / 2) / scale);
          double mae = 0.0;
          for (size_t i = 0; i < out.size(); ++i) mae += std::abs(int(out[i]) - int(ref[i]));
          mae /= double(out.size());
          rows.push_back({rays, di, f + 1, ssim_u8(out, ref), mae});
        }
      }
      std::fprintf(stderr, "[accuracy] %s: %d rays scored (%.1f s)\n", name.c_str(), rays, ms_since(t_rays) / 1e3);
      if (ri + 1 == kRays.size()) last_noisy = std::move(noisy);
    }
    // Time: kTimingRounds interleaved rounds of every configuration on top of the samples above
    // (a shared machine's load changes from second to second: each configuration sees the same
    // conditions), keeping the fastest. The denoisers' work does not depend on the ray count
    // (the same passes and taps on every pixel), so their time is taken per denoiser: the
    // first-frame path (history_valid = false) and the steady path (history of 8+ frames).
    {
      const auto t_timing = std::chrono::steady_clock::now();
      const int top = kRays.back();
      std::vector<std::unique_ptr<Denoiser>> steady, probe;
      ImageU8 out;
      for (const auto& dn : denoisers) {
        steady.push_back(create(dn));
        probe.push_back(create(dn));
        for (int f = 0; f < kFrames; ++f)
          steady.back()->denoise(DenoiseInput{g, last_noisy[size_t(f)], top, uint32_t(f), true}, out);
        probe.back()->denoise(DenoiseInput{g, last_noisy[0], top, 0, false}, out);  // allocates
      }
      for (int round = 0; round < kTimingRounds; ++round) {
        for (size_t ri = 0; ri < kRays.size(); ++ri) {
          double ms = 0.0;
          trace_ao_image(scene, rt, g, kRays[ri], uint32_t(100 + round), &ms);
          trace_ms[ri] = std::min(trace_ms[ri], ms);
        }
        for (size_t di = 0; di < denoisers.size(); ++di) {
          const ImageU8& n = last_noisy[size_t(round) % last_noisy.size()];
          auto t0 = std::chrono::steady_clock::now();
          probe[di]->denoise(DenoiseInput{g, n, top, uint32_t(round), false}, out);
          first_ms[di] = std::min(first_ms[di], ms_since(t0));
          t0 = std::chrono::steady_clock::now();
          steady[di]->denoise(DenoiseInput{g, n, top, uint32_t(kFrames + round), true}, out);
          steady_ms[di] = std::min(steady_ms[di], ms_since(t0));
        }
      }
      std::fprintf(stderr, "[accuracy] %s: %d timing rounds (%.1f s)\n", name.c_str(), kTimingRounds,
                   ms_since(t_timing) / 1e3);
    }
    for (const Row& r : rows) {
      const size_t ri = size_t(std::find(kRays.begin(), kRays.end(), r.rays) - kRays.begin());
      const double dms = r.frame == 1 ? first_ms[r.dn] : steady_ms[r.dn];
      const double tms = trace_ms[ri];
      std::printf("| %d | %s | %d | %.4f | %.2f | %.2f | %.2f | %.2f |\n", r.rays, labels[r.dn].c_str(), r.frame,
                  r.ssim, r.mae, tms, dms, tms + dms);
      if (csv)
        csv << name << ',' << w << ',' << h << ',' << opt.reference_rays << ',' << r.rays << ',' << labels[r.dn] << ','
            << r.frame << ',' << std::to_string(r.ssim) << ',' << std::to_string(r.mae) << ',' << std::to_string(tms)
            << ',' << std::to_string(dms) << ',' << std::to_string(tms + dms) << ',' << threads << '\n';
    }
    std::fflush(stdout);
  }
  if (csv) {
    csv.close();
    if (!csv) fail("bench_denoise --csv={}: writing the file failed", opt.csv_path);
    std::fprintf(stderr, "[accuracy] wrote %s\n", opt.csv_path.c_str());
  }
}

// ---- --fast_weights_diff: svgf_ao (fast_weights, the default) against fast_weights = false, frame by frame on
// each scene's camera path (60 fps from t = 1 s, 1280x720, 8 AO rays, history kept): how many
// output pixels differ, by how many 8-bit levels.
void fast_weights_diff(const AccuracyOptions& opt, int frames) {
  const int w = 1280, h = 720, rays = 8;
  const SceneList list = scene_list(opt);
  std::printf(
      "svgf_ao (fast_weights) against fast_weights = false: %dx%d, %d AO rays, %d frames at 60 fps from t = 1 s\n", w,
      h, rays, frames);
  std::printf("| scene | pixels | equal | 1 level | 2 or more | most levels | mean levels |\n");
  std::printf("| --- | ---: | ---: | ---: | ---: | ---: | ---: |\n");
  for (const auto& name : list.names) {
    std::optional<Scene> loaded = load_listed(list, name, "fast_weights_diff");
    if (!loaded) continue;
    Scene& scene = *loaded;
    RtScene rt(scene);
    auto exact = registries().denoisers.create("svgf_ao", {{"fast_weights", false}});
    auto fast = registries().denoisers.create("svgf_ao", nlohmann::json::object());
    uint64_t counts[3] = {0, 0, 0}, sum = 0;
    int most = 0;
    ImageU8 out_exact, out_fast;
    for (int f = 0; f < frames; ++f) {
      const double t = 1.0 + f / 60.0;
      const GBuffer g = raster_gbuffer(scene, w, h, t, f == 0 ? t : t - 1.0 / 60.0);
      rt.set_time(g.time_s);
      const ImageU8 noisy = trace_ao_image(scene, rt, g, rays, uint32_t(f));
      exact->denoise(DenoiseInput{g, noisy, rays, uint32_t(f), f > 0}, out_exact);
      fast->denoise(DenoiseInput{g, noisy, rays, uint32_t(f), f > 0}, out_fast);
      for (size_t i = 0; i < out_exact.size(); ++i) {
        const int d = std::abs(int(out_exact[i]) - int(out_fast[i]));
        ++counts[std::min(d, 2)];
        sum += uint64_t(d);
        most = std::max(most, d);
      }
    }
    const double n = double(counts[0] + counts[1] + counts[2]);
    std::printf("| %s | %.0f | %.4f %% | %.4f %% | %.6f %% | %d | %.6f |\n", name.c_str(), n,
                100.0 * double(counts[0]) / n, 100.0 * double(counts[1]) / n, 100.0 * double(counts[2]) / n, most,
                double(sum) / n);
    std::fflush(stdout);
  }
}

}  // namespace
}  // namespace dhr

int main(int argc, char** argv) {
  bool accuracy = false;
  int rounds = 9, diff_frames = 0;
  dhr::AccuracyOptions acc;
  std::vector<char*> args;
  for (int i = 0; i < argc; ++i) {
    if (std::strcmp(argv[i], "--accuracy") == 0)
      accuracy = true;
    else if (std::strncmp(argv[i], "--fast_weights_diff=", 20) == 0) {
      diff_frames = std::atoi(argv[i] + 20);
      if (diff_frames < 1 || diff_frames > 10000) {
        std::fprintf(stderr, "bench_denoise: --fast_weights_diff=%s must be a frame count, 1..10000\n", argv[i] + 20);
        return 2;
      }
    } else if (std::strncmp(argv[i], "--rounds=", 9) == 0)
      rounds = std::max(1, std::atoi(argv[i] + 9));
    else if (std::strncmp(argv[i], "--scenes=", 9) == 0) {
      std::string list = argv[i] + 9;
      for (size_t pos = 0; pos <= list.size();) {
        const size_t comma = std::min(list.find(',', pos), list.size());
        if (comma > pos) acc.scenes.push_back(list.substr(pos, comma - pos));
        pos = comma + 1;
      }
    } else if (std::strncmp(argv[i], "--denoisers=", 12) == 0) {
      // Entries separated by spaces (JSON parameters contain commas).
      std::stringstream list(argv[i] + 12);
      for (std::string d; list >> d;) acc.denoisers.push_back(d);
    } else if (std::strncmp(argv[i], "--csv=", 6) == 0)
      acc.csv_path = argv[i] + 6;
    else if (std::strncmp(argv[i], "--frames=", 9) == 0) {
      acc.frames = std::atoi(argv[i] + 9);
      if (acc.frames < 2 || acc.frames > 1000) {
        std::fprintf(stderr, "bench_denoise: --frames=%s must be 2..1000\n", argv[i] + 9);
        return 2;
      }
    } else if (std::strncmp(argv[i], "--reference_rays=", 17) == 0) {
      acc.reference_rays = std::atoi(argv[i] + 17);
      if (acc.reference_rays < 1 || acc.reference_rays > 65535) {
        std::fprintf(stderr, "bench_denoise: --reference_rays=%s must be 1..65535\n", argv[i] + 17);
        return 2;
      }
    } else
      args.push_back(argv[i]);
  }
  if (diff_frames > 0) {
    try {
      dhr::fast_weights_diff(acc, diff_frames);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_denoise --fast_weights_diff: %s\n", e.what());
      return 1;
    }
    return 0;
  }
  if (accuracy) {
    try {
      dhr::accuracy_table(acc);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_denoise --accuracy: %s\n", e.what());
      return 1;
    }
    return 0;
  }
  int n = int(args.size());
  for (const std::string name : {"none", "temporal", "single_iteration", "atrous", "svgf_ao"}) {
    benchmark::RegisterBenchmark(("BM_Denoise/" + name + "/steady").c_str(), dhr::BM_Denoise, name, false)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
    if (name != "none" && name != "atrous")
      benchmark::RegisterBenchmark(("BM_Denoise/" + name + "/reset").c_str(), dhr::BM_Denoise, name, true)
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime();
  }
  benchmark::Initialize(&n, args.data());
  dhr::Collector collector;
  benchmark::RunSpecifiedBenchmarks(&collector);
  const auto minima = dhr::interleaved_minima(rounds);
  std::printf("\n1280x720, room, 8-ray AO input, %d threads; fastest of %d interleaved rounds\n",
              int(tbb::this_task_arena::max_concurrency()), rounds);
  std::printf(
      "(wall: elapsed ms; CPU: process CPU ms over all threads, the work done, which the\n"
      "load of other processes disturbs less)\n");
  std::printf(
      "| configuration | wall ms | wall ratio to one AO ray | CPU ms | CPU ratio |\n"
      "| --- | ---: | ---: | ---: | ---: |\n");
  for (const auto& m : minima)
    std::printf("| %s | %.2f | %.2f | %.2f | %.2f |\n", m.label.c_str(), m.wall_ms, m.wall_ms / minima.front().wall_ms,
                m.cpu_ms, m.cpu_ms / minima.front().cpu_ms);
  if (dhr::have_avx512()) {
    // The fastest of three measurements (a shared machine only ever slows it down).
    double rate = 0.0;
    for (int k = 0; k < 3; ++k) rate = std::max(rate, dhr::vector_op_rate());
    const double blocks = 1280.0 * 720.0 / 16.0, taps = 24.0, iterations = 5.0;
    const double ray_cpu = minima.front().cpu_ms;
    std::printf(
        "\nArithmetic floor of svgf_ao's five 5x5 a-trous iterations (1280x720, 16-lane blocks):\n"
        "measured rate %.3g 16-lane ops per CPU second (independent multiplies and adds)\n",
        rate);
    std::printf(
        "| taps as | ops per tap | CPU ms per frame | ratio to one AO ray (CPU) |\n| --- | ---: | ---: | ---: |\n");
    for (const auto& [label, ops] :
         {std::pair<const char*, int>{"compiled kernel (fast weights)", dhr::kTapOpsCompiled},
          std::pair<const char*, int>{"fewest with the same bits (fast weights)", dhr::kTapOpsMinimal},
          std::pair<const char*, int>{"compiled kernel (exact weights)", dhr::kTapOpsCompiledExact},
          std::pair<const char*, int>{"fewest with the same bits (exact weights)", dhr::kTapOpsMinimalExact}}) {
      const double ms = iterations * taps * blocks * double(ops) / rate * 1e3;
      std::printf("| %s | %d | %.2f | %.2f |\n", label, ops, ms, ms / ray_cpu);
    }
  }
  const auto it = collector.ms.find("BM_TraceAoOneRay/real_time");
  if (it != collector.ms.end()) {
    const double ray_ms = it->second;
    std::printf("\nGoogle Benchmark runs (sequential; noisier on a shared machine). One AO ray: %.2f ms\n", ray_ms);
    std::printf("| benchmark | ms per frame | ratio to one AO ray |\n| --- | ---: | ---: |\n");
    std::printf("| (threads: %d) | | |\n", int(tbb::this_task_arena::max_concurrency()));
    for (const auto& [name, ms] : collector.ms)
      if (name != it->first) std::printf("| %s | %.2f | %.2f |\n", name.c_str(), ms, ms / ray_ms);
  }
  benchmark::Shutdown();
  return 0;
}
