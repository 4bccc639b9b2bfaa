// Image metrics at 1280x720, each beside a ceiling or floor timed in the same run:
//  - SSIM (luma) in both conventions, SsimBorder::Mirrored (core/metrics/metrics.h's default) and
//    SsimBorder::Valid (the reference convention), against OpenCV's quality module
//    (cv::quality::QualitySSIM) on the same plane;
//  - FLIP against a memory-bandwidth floor of the same image size: one pass that reads both
//    8-bit RGB inputs and writes a float per pixel, the least any full-image error map costs;
//    whole (both images) and its test half (the reference's features computed once, as the
//    runner scores every frame of a run against one reference);
//  - FLIP's powers (core/base/pow_row.h) against the library's powf called per element, and FLIP's
//    test half with each;
//  - the temporal stability scores of one frame step against their previous sequential loop;
//  - the metrics' filter taps alone at this CPU's peak rate (BM_Metrics_taps_floor): the least
//    time any implementation of SSIM's and FLIP's filters as specified needs per frame.
// After the runs a table prints the fastest repetition of each and the ratios, twice: wall ms
// (the metrics use all cores through TBB) and process CPU ms per iteration summed over all
// threads (on a shared, loaded machine the wall time mostly measures the neighbours; the CPU
// time a metric consumes varies much less).
#include "core/base/avx512.h"
#include "core/base/pow_row.h"
#include "core/base/rng.h"
#include "core/metrics/flip.h"
#include "core/metrics/metrics.h"
#include "core/metrics/temporal.h"
#include "tests/support.h"

#include <benchmark/benchmark.h>
#include <opencv2/quality/qualityssim.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <map>
#include <string>
#include <vector>

namespace {

dhr::ImageRGB8 frame(uint64_t seed) {
  dhr::ImageRGB8 img(1280, 720);
  for (int y = 0; y < 720; ++y)
    for (int x = 0; x < 1280; ++x) {
      const float n = dhr::rng_uniform({seed, uint32_t(y * 1280 + x), 0, 0, 3});
      const uint8_t v = uint8_t(std::clamp(128 + 90 * std::sin(x * 0.01f + y * 0.02f) + 30 * (n - 0.5f), 0.0f, 255.0f));
      img(x, y) = {v, uint8_t(v / 2), uint8_t(255 - v)};
    }
  return img;
}

double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) * 1e3 + double(ts.tv_nsec) * 1e-6;
}

// Process CPU time (all threads) per iteration of the timed loop, as a counter.
struct CpuCounter {
  benchmark::State& state;
  double start = process_cpu_ms();
  ~CpuCounter() {
    state.counters["proc_cpu_ms"] =
        (process_cpu_ms() - start) / double(std::max<benchmark::IterationCount>(state.iterations(), 1));
  }
};

const dhr::ImageRGB8& frame_a() {
  static const dhr::ImageRGB8 a = frame(1);
  return a;
}
const dhr::ImageRGB8& frame_b() {
  static const dhr::ImageRGB8 b = frame(2);
  return b;
}

void BM_SsimLuma_dhrbench(benchmark::State& state) {
  const auto &a = frame_a(), &b = frame_b();
  CpuCounter cpu{state};
  for (auto _ : state) benchmark::DoNotOptimize(dhr::compare_images(a, b).ssim);
  state.counters["Mpix/s"] = benchmark::Counter(1280.0 * 720, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_SsimLuma_dhrbench)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_SsimLuma_valid(benchmark::State& state) {
  const auto &a = frame_a(), &b = frame_b();
  CpuCounter cpu{state};
  for (auto _ : state)
    benchmark::DoNotOptimize(dhr::compare_images(a, b, dhr::SsimChannel::Luma, nullptr, dhr::SsimBorder::Valid).ssim);
  state.counters["Mpix/s"] = benchmark::Counter(1280.0 * 720, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_SsimLuma_valid)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_SsimLuma_OpenCvQuality(benchmark::State& state) {
  const auto la = dhr::luma(frame_a()), lb = dhr::luma(frame_b());
  cv::Mat ma(720, 1280, CV_8UC1, const_cast<uint8_t*>(la.data()));
  cv::Mat mb(720, 1280, CV_8UC1, const_cast<uint8_t*>(lb.data()));
  CpuCounter cpu{state};
  for (auto _ : state) benchmark::DoNotOptimize(cv::quality::QualitySSIM::compute(ma, mb, cv::noArray())[0]);
  state.counters["Mpix/s"] = benchmark::Counter(1280.0 * 720, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_SsimLuma_OpenCvQuality)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_Flip(benchmark::State& state) {
  const auto &a = frame_a(), &b = frame_b();
  CpuCounter cpu{state};
  for (auto _ : state) benchmark::DoNotOptimize(dhr::flip(a, b).mean);
  state.counters["Mpix/s"] = benchmark::Counter(1280.0 * 720, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Flip)->Unit(benchmark::kMillisecond)->UseRealTime();

// FLIP's half that a run pays for each scored frame: the test image against a reference whose
// features the runner computed once (flip_features, kept in its cache).
void BM_Flip_test_half(benchmark::State& state) {
  static const dhr::FlipFeatures features = dhr::flip_features(frame_a());
  const auto& b = frame_b();
  CpuCounter cpu{state};
  for (auto _ : state) benchmark::DoNotOptimize(dhr::flip(features, b).mean);
  state.counters["Mpix/s"] = benchmark::Counter(1280.0 * 720, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Flip_test_half)->Unit(benchmark::kMillisecond)->UseRealTime();

// The same with pow through libm one pixel at a time (pow_row_portable_only: the path of CPUs
// without AVX-512): the same bits.
void BM_Flip_test_half_libm_pow(benchmark::State& state) {
  static const dhr::FlipFeatures features = dhr::flip_features(frame_a());
  const auto& b = frame_b();
  dhr::pow_row_portable_only(true);
  {
    CpuCounter cpu{state};
    for (auto _ : state) benchmark::DoNotOptimize(dhr::flip(features, b).mean);
  }
  dhr::pow_row_portable_only(false);
}
BENCHMARK(BM_Flip_test_half_libm_pow)->Unit(benchmark::kMillisecond)->UseRealTime();

// pow_row against the library's own call on the same 1280x720 values: FLIP's second power,
// errors in (0, 1] to powers in (0.16, 1]; one thread. `fallback_pct`: the lanes the kernel
// left to std::pow.
struct PowInputs {
  std::vector<float> x, y;
  PowInputs() : x(1280 * 720), y(1280 * 720) {
    for (size_t i = 0; i < x.size(); ++i) {
      x[i] = dhr::rng_uniform({9, uint32_t(i), 0, 0, 1});
      y[i] = 0.16f + 0.84f * dhr::rng_uniform({9, uint32_t(i), 0, 0, 2});
    }
  }
};
const PowInputs& pow_inputs() {
  static const PowInputs p;
  return p;
}
void BM_PowRow(benchmark::State& state) {
  const PowInputs& p = pow_inputs();
  std::vector<float> out(p.x.size());
  const dhr::PowRowCounts before = dhr::pow_row_counts();
  {
    CpuCounter cpu{state};
    for (auto _ : state) {
      dhr::pow_row(p.x.data(), p.y.data(), out.data(), out.size());
      benchmark::DoNotOptimize(out.data());
    }
  }
  const dhr::PowRowCounts after = dhr::pow_row_counts();
  state.counters["fallback_pct"] = after.lanes > before.lanes ? 100.0 * double(after.fallbacks - before.fallbacks) /
                                                                    double(after.lanes - before.lanes)
                                                              : 100.0;
}
BENCHMARK(BM_PowRow)->Unit(benchmark::kMillisecond)->UseRealTime();
void BM_PowLibm(benchmark::State& state) {
  const PowInputs& p = pow_inputs();
  std::vector<float> out(p.x.size());
  CpuCounter cpu{state};
  for (auto _ : state) {
    for (size_t i = 0; i < out.size(); ++i) out[i] = std::pow(p.x[i], p.y[i]);
    benchmark::DoNotOptimize(out.data());
  }
}
BENCHMARK(BM_PowLibm)->Unit(benchmark::kMillisecond)->UseRealTime();

// The floor: read both inputs once, write one float per pixel (a fresh map, as flip() returns).
void BM_Flip_floor(benchmark::State& state) {
  const auto &a = frame_a(), &b = frame_b();
  CpuCounter cpu{state};
  for (auto _ : state) {
    dhr::ImageF map(a.width(), a.height());
    for (size_t i = 0; i < a.size(); ++i)
      map[i] = float(std::abs(int(a[i].r) - int(b[i].r)) + std::abs(int(a[i].g) - int(b[i].g)) +
                     std::abs(int(a[i].b) - int(b[i].b)));
    benchmark::DoNotOptimize(map.data());
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(int64_t(state.iterations()) * int64_t(a.size()) * (3 + 3 + 4));
}
BENCHMARK(BM_Flip_floor)->Unit(benchmark::kMillisecond)->UseRealTime();

// The metrics' filter taps alone, per 1280x720 frame, at this CPU's peak rate: the taps of SSIM
// (luma; five moments x 11 taps across, in float, and down, in double, as core/metrics/metrics.cpp sums
// them) and of FLIP's test half (flip_detail::test_half_taps: 301 at the default 67 pixels per
// degree). Every kernel is symmetric or antisymmetric, so two taps can share one product: each
// pair of taps is taken as one sum (or difference) of the two inputs and one fused multiply-add
// into the output (the metrics themselves take a product and a sum per tap, each rounded on its
// own: four operations a pair, not two), on inputs held in L1, eight independent 16-lane sums in
// registers; on a CPU whose adders and multipliers are separate units (Zen 4) the pair costs
// one slot of each. Nothing else is counted: not the colour conversions, powers, square roots
// and quotients, nor the reads and writes of the planes. The loop runs at 0.91-0.97 of the
// peak rate of these instructions on the AVX-512 EPYC, so no implementation of these filters as
// specified (direct, separable, in these precisions) takes much less; docs/performance.md
// compares it with a client frame.
constexpr int kFloorW = 1280, kFloorH = 720;

int64_t ssim_taps_per_pixel() { return 5 * int64_t(dhr::kSsimWindow); }  // each direction

#if DHR_AVX512_KERNELS
// 16 floats or 8 doubles: one 512-bit register's loads, sums and fused multiply-adds.
DHR_AVX512_TARGET inline __m512 load_lanes(const float* p) { return _mm512_loadu_ps(p); }
DHR_AVX512_TARGET inline __m512d load_lanes(const double* p) { return _mm512_loadu_pd(p); }
DHR_AVX512_TARGET inline __m512 add_lanes(__m512 a, __m512 b) { return _mm512_add_ps(a, b); }
DHR_AVX512_TARGET inline __m512d add_lanes(__m512d a, __m512d b) { return _mm512_add_pd(a, b); }
DHR_AVX512_TARGET inline __m512 fmadd_lanes(__m512 w, __m512 x, __m512 a) { return _mm512_fmadd_ps(w, x, a); }
DHR_AVX512_TARGET inline __m512d fmadd_lanes(__m512d w, __m512d x, __m512d a) { return _mm512_fmadd_pd(w, x, a); }
DHR_AVX512_TARGET inline __m512 splat_lanes(float v) { return _mm512_set1_ps(v); }
DHR_AVX512_TARGET inline __m512d splat_lanes(double v) { return _mm512_set1_pd(v); }
DHR_AVX512_TARGET inline float reduce_lanes(__m512 v) { return _mm512_reduce_add_ps(v); }
DHR_AVX512_TARGET inline double reduce_lanes(__m512d v) { return _mm512_reduce_add_pd(v); }

// `blocks` x 8 register-wide tap pairs (a sum of two of five inputs, then a multiply-add) into
// eight sums; returns their total (kept live). T is float or double.
template <class T>
DHR_AVX512_TARGET T tap_pairs(const T* in, int64_t blocks) {
  constexpr int kLanes = 64 / int(sizeof(T));
  using V = decltype(load_lanes(in));
  V acc[8];
  for (auto& a : acc) a = splat_lanes(T(0));
  const V w0 = splat_lanes(T(0.25)), w1 = splat_lanes(T(-0.125));
  for (int64_t b = 0; b < blocks; ++b) {
    const T* p = in + 2 * kLanes * (b & 7);  // within the first 19 registers' worth: in L1
    const V x0 = load_lanes(p), x1 = load_lanes(p + kLanes), x2 = load_lanes(p + 2 * kLanes);
    const V x3 = load_lanes(p + 3 * kLanes), x4 = load_lanes(p + 4 * kLanes);
    acc[0] = fmadd_lanes(w0, add_lanes(x0, x1), acc[0]);
    acc[1] = fmadd_lanes(w1, add_lanes(x0, x2), acc[1]);
    acc[2] = fmadd_lanes(w0, add_lanes(x0, x3), acc[2]);
    acc[3] = fmadd_lanes(w1, add_lanes(x0, x4), acc[3]);
    acc[4] = fmadd_lanes(w1, add_lanes(x1, x2), acc[4]);
    acc[5] = fmadd_lanes(w0, add_lanes(x1, x3), acc[5]);
    acc[6] = fmadd_lanes(w1, add_lanes(x2, x4), acc[6]);
    acc[7] = fmadd_lanes(w0, add_lanes(x3, x4), acc[7]);
  }
  V sum = acc[0];
  for (int j = 1; j < 8; ++j) sum = add_lanes(sum, acc[j]);
  return reduce_lanes(sum);
}
#endif

// One thread, as the CPU ms of the metrics above count all threads' time.
void BM_Metrics_taps_floor(benchmark::State& state) {
#if DHR_AVX512_KERNELS
  if (!dhr::cpu_has_avx512dq()) {
    state.SkipWithError("the taps floor is written for AVX-512 (this CPU has none, or DHR_MAX_ISA forbids it)");
    return;
  }
  const int64_t pixels = int64_t(kFloorW) * kFloorH;
  const int64_t flip_taps = dhr::flip_detail::test_half_taps(dhr::kFlipDefaultPpd);
  // SSIM over the valid interior (SsimBorder::Valid, no map): its columns on every row across,
  // its pixels down.
  const int64_t r = dhr::kSsimWindow / 2, ssim_cols = kFloorW - 2 * r, ssim_rows = kFloorH - 2 * r;
  const int64_t float_taps = pixels * flip_taps + ssim_cols * kFloorH * ssim_taps_per_pixel();
  const int64_t double_taps = ssim_cols * ssim_rows * ssim_taps_per_pixel();
  // Two taps a pair (an odd kernel's middle tap counted as half a pair: a little under the count).
  const int64_t float_blocks = float_taps / 2 / (8 * 16), double_blocks = double_taps / 2 / (8 * 8);
  std::vector<float> in_f(512);
  std::vector<double> in_d(256);
  for (size_t i = 0; i < in_f.size(); ++i) in_f[i] = float(i % 7) * 0.01f;
  for (size_t i = 0; i < in_d.size(); ++i) in_d[i] = double(i % 5) * 0.01;
  CpuCounter cpu{state};
  for (auto _ : state) {
    benchmark::DoNotOptimize(tap_pairs(in_f.data(), float_blocks));
    benchmark::DoNotOptimize(tap_pairs(in_d.data(), double_blocks));
  }
  state.counters["flip_taps_per_px"] = double(flip_taps);
  state.counters["ssim_taps_per_px"] = double(2 * ssim_taps_per_pixel());
#else
  state.SkipWithError("the taps floor is written for AVX-512 (not built for this compiler or CPU)");
#endif
}
BENCHMARK(BM_Metrics_taps_floor)->Unit(benchmark::kMillisecond)->UseRealTime();

// Temporal stability of one frame step (core/metrics/temporal.h) against the sequential loop it was
// until its per-pixel terms ran in vectorized chunks (tests/support.h; the same bits:
// Temporal.SameBitsAsOneSequentialLoop).
void BM_Temporal(benchmark::State& state) {
  const auto &a = frame_a(), &b = frame_b();
  CpuCounter cpu{state};
  for (auto _ : state) benchmark::DoNotOptimize(dhr::temporal_scores(a, b, b, a).temporal_error);
}
BENCHMARK(BM_Temporal)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_Temporal_one_loop(benchmark::State& state) {
  const auto &a = frame_a(), &b = frame_b();
  CpuCounter cpu{state};
  for (auto _ : state) benchmark::DoNotOptimize(dhr::test::temporal_scores_one_loop(a, b, b, a, 0.0).temporal_error);
}
BENCHMARK(BM_Temporal_one_loop)->Unit(benchmark::kMillisecond)->UseRealTime();

// Keeps the fastest repetition of every benchmark (wall ms per iteration) and prints the table.
class Summary : public benchmark::ConsoleReporter {
 public:
  void ReportRuns(const std::vector<Run>& runs) override {
    for (const auto& r : runs)
      if (r.run_type == Run::RT_Iteration && r.iterations > 0 && !r.error_occurred) {
        keep_min(ms_, r.run_name.function_name, r.real_accumulated_time / double(r.iterations) * 1e3);
        const auto c = r.counters.find("proc_cpu_ms");
        if (c != r.counters.end()) keep_min(cpu_ms_, r.run_name.function_name, c->second.value);
      }
    ConsoleReporter::ReportRuns(runs);
  }
  void Finalize() override {
    ConsoleReporter::Finalize();
    for (const auto* table : {&ms_, &cpu_ms_}) {
      auto row = [&](const char* label, const std::string& ours, const std::string& base) {
        const auto o = table->find(ours), b = table->find(base);
        if (o == table->end() || b == table->end()) return;
        std::printf("%-48s %10.2f %10.2f %9.2fx\n", label, o->second, b->second, o->second / b->second);
      };
      std::printf(
          "\n%-48s %10s %10s %10s\n",
          table == &ms_ ? "1280x720, fastest repetition: wall ms" : "1280x720, fastest repetition: process CPU ms",
          "ours", "base", "ours/base");
      row("SSIM valid / SSIM mirrored (today's)", "BM_SsimLuma_valid", "BM_SsimLuma_dhrbench");
      row("SSIM mirrored / OpenCV QualitySSIM", "BM_SsimLuma_dhrbench", "BM_SsimLuma_OpenCvQuality");
      row("SSIM valid / OpenCV QualitySSIM", "BM_SsimLuma_valid", "BM_SsimLuma_OpenCvQuality");
      row("FLIP / memory floor (read 2 RGB8, write float)", "BM_Flip", "BM_Flip_floor");
      row("FLIP test half / memory floor", "BM_Flip_test_half", "BM_Flip_floor");
      row("FLIP test half / with libm's pow per pixel", "BM_Flip_test_half", "BM_Flip_test_half_libm_pow");
      row("pow_row / libm's powf per element", "BM_PowRow", "BM_PowLibm");
      row("temporal scores / the sequential loop before", "BM_Temporal", "BM_Temporal_one_loop");
      const auto ssim = table->find("BM_SsimLuma_valid"), flip = table->find("BM_Flip_test_half"),
                 floor = table->find("BM_Metrics_taps_floor");
      // CPU time only: the floor runs on one thread, the metrics on all.
      if (table == &cpu_ms_ && ssim != table->end() && flip != table->end() && floor != table->end())
        std::printf("%-48s %10.2f %10.2f %9.2fx\n", "SSIM valid + FLIP test half / their taps floor",
                    ssim->second + flip->second, floor->second, (ssim->second + flip->second) / floor->second);
    }
  }

 private:
  static void keep_min(std::map<std::string, double>& m, const std::string& key, double v) {
    auto [it, fresh] = m.emplace(key, v);
    if (!fresh) it->second = std::min(it->second, v);
  }
  std::map<std::string, double> ms_, cpu_ms_;
};

}  // namespace

int main(int argc, char** argv) {
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  Summary summary;
  benchmark::RunSpecifiedBenchmarks(&summary);
  benchmark::Shutdown();
  return 0;
}
