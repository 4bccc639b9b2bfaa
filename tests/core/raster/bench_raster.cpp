// The CPU rasterizer (core/raster/raster.h) at 1280x720 on every built-in scene (scenes/*.json) and
// every real scene (scenes/real/*.json; skipped when ../shared/scenes is missing), with all
// cores and with one thread. Counters: the scene's triangle count, triangles per second,
// fragments, and `x_fill`: the frame time over the ceiling measured in the same run -- the
// time to write the same G-buffer bytes (76 B/px) with std::fill (BM_GBufferFill), i.e. what
// a rasterizer that did nothing but write its output would cost. `cpu_ms` is the process CPU
// time per frame (all threads) and `x_fill_cpu` its ratio to the fill's process CPU time (one
// thread, best of 7): on a shared machine the wall times measure the neighbours, the CPU time
// a frame consumes much less (docs/performance.md).
//
//   build-*/tests/bench_raster --benchmark_min_time=0.5
#include "core/base/error.h"
#include "core/buffers/gbuffer.h"
#include "core/raster/raster.h"
#include "core/scene/scene.h"
#include "core/scene/scene_load.h"
#include "tests/support.h"

#include <benchmark/benchmark.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <filesystem>
#include <map>
#include <memory>
#include <string>

namespace {

constexpr int kWidth = 1280, kHeight = 720;

void fill_gbuffer(dhr::GBuffer& g, float v) {
  std::fill(g.depth.pixels().begin(), g.depth.pixels().end(), v);
  std::fill(g.position.pixels().begin(), g.position.pixels().end(), glm::vec3(v));
  std::fill(g.normal.pixels().begin(), g.normal.pixels().end(), glm::vec3(v));
  std::fill(g.geo_normal.pixels().begin(), g.geo_normal.pixels().end(), glm::vec3(v));
  std::fill(g.albedo.pixels().begin(), g.albedo.pixels().end(), glm::vec3(v));
  std::fill(g.object_id.pixels().begin(), g.object_id.pixels().end(), uint32_t(v));
  std::fill(g.prim_id.pixels().begin(), g.prim_id.pixels().end(), uint32_t(v));
  std::fill(g.bary.pixels().begin(), g.bary.pixels().end(), glm::vec2(v));
  std::fill(g.motion.pixels().begin(), g.motion.pixels().end(), glm::vec2(v));
}

double gbuffer_bytes() { return double(kWidth) * kHeight * (4 + 12 * 4 + 4 + 4 + 8 + 8); }

// The ceiling: one thread writing every G-buffer byte (the rasterizer's own output cost).
void BM_GBufferFill(benchmark::State& state) {
  dhr::GBuffer g;
  g.resize(kWidth, kHeight);
  float v = 0.0f;
  for (auto _ : state) {
    fill_gbuffer(g, v);
    v += 1.0f;
    benchmark::DoNotOptimize(g.depth.data());
    benchmark::ClobberMemory();
  }
  state.counters["GB/s"] = benchmark::Counter(gbuffer_bytes() * 1e-9, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_GBufferFill)->Unit(benchmark::kMillisecond)->UseRealTime();

// The same ceiling measured once inside this process for the ratio counters (best of 7).
double fill_ms() {
  static const double ms = [] {
    dhr::GBuffer g;
    g.resize(kWidth, kHeight);
    double best = 1e30;
    for (int i = 0; i < 7; ++i) {
      const auto t0 = std::chrono::steady_clock::now();
      fill_gbuffer(g, float(i));
      benchmark::DoNotOptimize(g.depth.data());
      benchmark::ClobberMemory();
      best = std::min(best, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
    return best;
  }();
  return ms;
}

double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) * 1e3 + double(ts.tv_nsec) * 1e-6;
}

// The same ceiling in process CPU time (one thread writes; best of 7).
double fill_cpu_ms() {
  static const double ms = [] {
    dhr::GBuffer g;
    g.resize(kWidth, kHeight);
    double best = 1e30;
    for (int i = 0; i < 7; ++i) {
      const double t0 = process_cpu_ms();
      fill_gbuffer(g, float(i));
      benchmark::DoNotOptimize(g.depth.data());
      benchmark::ClobberMemory();
      best = std::min(best, process_cpu_ms() - t0);
    }
    return best;
  }();
  return ms;
}

// Scenes are loaded once per process (real ones take seconds).
const dhr::Scene& cached_scene(const std::string& path) {
  static std::map<std::string, std::unique_ptr<dhr::Scene>> cache;
  auto it = cache.find(path);
  if (it == cache.end())
    it = cache.emplace(path, std::make_unique<dhr::Scene>(dhr::load_scene(path, dhr::SceneSearchPath::standard())))
             .first;
  return *it->second;
}

void BM_Raster(benchmark::State& state, const std::string& path, bool real) {
  if (real && !std::filesystem::is_directory(dhr::test::shared_scenes_dir())) {
    state.SkipWithError(("real scenes not found at " + dhr::test::shared_scenes_dir()).c_str());
    return;
  }
  const dhr::Scene* scene = nullptr;
  try {
    scene = &cached_scene(path);
  } catch (const dhr::Error& e) {
    state.SkipWithError(e.what());
    return;
  }
  const int threads = int(state.range(0));
  std::unique_ptr<tbb::global_control> limit;
  if (threads > 0) limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, threads);
  // The first frames of the scene's camera path, one frame apart (camera and object motion).
  const double t = 1.0 / 30.0;
  const dhr::RasterFrame frame{scene, scene->camera.at(t, kWidth, kHeight), t, scene->camera.at(0.0, kWidth, kHeight),
                               0.0};
  dhr::GBuffer g;
  dhr::RasterStats stats = dhr::rasterize(frame, g);  // warm-up, allocates the G-buffer
  double wall_ms = 0.0;
  const double cpu0 = process_cpu_ms();
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    stats = dhr::rasterize(frame, g);
    benchmark::DoNotOptimize(g.depth.data());
    wall_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
  // Rates from wall time (Google Benchmark's rate counters divide by the main thread's CPU
  // time, which misses TBB's worker threads).
  const double iterations = double(std::max<benchmark::IterationCount>(state.iterations(), 1));
  const double cpu_ms = (process_cpu_ms() - cpu0) / iterations;
  const double ms = wall_ms / iterations;
  const double tris = double(scene->triangle_count());
  state.counters["ms"] = ms;
  state.counters["triangles"] = tris;
  state.counters["Mtri/s"] = tris / ms * 1e-3;
  state.counters["fragments"] = double(stats.fragments);
  state.counters["covered"] = double(std::count_if(g.object_id.pixels().begin(), g.object_id.pixels().end(),
                                                   [](uint32_t id) { return id != dhr::kBackgroundId; }));
  state.counters["culled"] = double(stats.triangles_culled);
  state.counters["clipped"] = double(stats.triangles_clipped);
  state.counters["fill_ms"] = fill_ms();
  state.counters["x_fill"] = ms / fill_ms();  // frame time in units of the output-write ceiling
  state.counters["cpu_ms"] = cpu_ms;
  state.counters["fill_cpu_ms"] = fill_cpu_ms();
  state.counters["x_fill_cpu"] = cpu_ms / fill_cpu_ms();
}

std::string stem(const std::string& path) { return std::filesystem::path(path).stem().string(); }

}  // namespace

int main(int argc, char** argv) {
  for (const auto& [files, real] :
       {std::pair{dhr::builtin_scene_files(), false}, std::pair{dhr::real_scene_files(), true}}) {
    for (const std::string& f : files) {
      const std::string name = std::string("BM_Raster/") + (real ? "real/" : "") + stem(f);
      benchmark::RegisterBenchmark(name.c_str(), BM_Raster, f, real)
          ->ArgName("threads")
          ->Arg(0)
          ->Arg(1)
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime();
    }
  }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
