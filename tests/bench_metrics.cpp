// SSIM at 1280x720 against OpenCV's quality module (cv::quality::QualitySSIM) on the same
// plane in the same run: the ceiling the benchmark's own SSIM is compared with.
#include "core/metrics.h"
#include "core/rng.h"

#include <benchmark/benchmark.h>
#include <opencv2/quality/qualityssim.hpp>

#include <cmath>

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

void BM_SsimLuma_dhrbench(benchmark::State& state) {
  const auto a = frame(1), b = frame(2);
  for (auto _ : state) benchmark::DoNotOptimize(dhr::compare_images(a, b).ssim);
  state.counters["Mpix/s"] = benchmark::Counter(1280.0 * 720, benchmark::Counter::kIsIterationInvariantRate) ;
}
BENCHMARK(BM_SsimLuma_dhrbench)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_SsimLuma_OpenCvQuality(benchmark::State& state) {
  const auto a = dhr::luma(frame(1)), b = dhr::luma(frame(2));
  cv::Mat ma(720, 1280, CV_8UC1, const_cast<uint8_t*>(a.data()));
  cv::Mat mb(720, 1280, CV_8UC1, const_cast<uint8_t*>(b.data()));
  for (auto _ : state) benchmark::DoNotOptimize(cv::quality::QualitySSIM::compute(ma, mb, cv::noArray())[0]);
  state.counters["Mpix/s"] = benchmark::Counter(1280.0 * 720, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_SsimLuma_OpenCvQuality)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
