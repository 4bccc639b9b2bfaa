// Reprojection at 1280x720 (an Ao buffer and a 4-light Visibility bitmask) on synthetic
// G-buffers of an analytic scene (a ground plane and a row of boxes; the camera moved by
// 0.15 m and turned by 1 degree between the two frames), beside a memory-bound ceiling
// measured in the same run: a plain gather, out[i] = in[idx[i]], with the source indices
// precomputed (the nearest source pixel of each dst pixel), on the same TBB row split.
// Each reprojection benchmark reports ms per frame and, as counters, the gather's ms and
// the ratio (reprojection / gather).
//
// The memory floor of a stage (docs/performance.md, "Each stage against its floor"): one
// streaming pass over exactly the bytes the stage reads (every plane it reads, once) and writes
// (its output), on the same TBB row split, timed in process CPU time beside the stage's own
// process CPU time per frame (`cpu_ms`, `floor_cpu_ms`, `x_floor`), both on one thread (TBB
// limited to 1: no worker spinning in the CPU time, the same basis as bench_raster's ratio).
// Reprojection reads the dst G-buffer's object_id, position and normal, the src G-buffer's
// object_id, position, normal and geo_normal and the received bytes, and writes the predicted
// bytes (70 B/px for 1-byte passes); BM_Composite (room, rasterized at 1280x720, three lights,
// a synthetic visibility bitmask and AO) reads object_id, normal, albedo, position and both
// passes and writes the RGB8 image (45 B/px; geo_normal only where the normal is zero, not
// counted).
#include "core/base/avx512.h"
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "core/base/cpu_isa.h"
#include "core/base/rng.h"
#include "core/buffers/depth_pass.h"
#include "core/buffers/upsample.h"
#include "core/pass/composite.h"
#include "core/raster/raster.h"
#include "core/scene/scene_load.h"

#include <benchmark/benchmark.h>
#include <tbb/global_control.h>
#include <glm/gtc/matrix_transform.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <span>
#include <vector>

namespace {

using namespace dhr;

constexpr int kW = 1280, kH = 720;

struct Box {
  glm::vec3 lo, hi;
};

const std::vector<Box>& boxes() {
  static const std::vector<Box> b = [] {
    std::vector<Box> v;
    for (int i = 0; i < 6; ++i) {
      const float x = -6.0f + 2.2f * float(i), z = -2.0f - 1.5f * float(i % 3);
      v.push_back({{x, 0.0f, z}, {x + 1.2f, 0.8f + 0.4f * float(i % 4), z + 1.0f}});
    }
    return v;
  }();
  return b;
}

// Ground y = 0 (|x|, |z| <= 30, id 1) and the boxes (ids 2..), as test_predictors does.
GBuffer render(const Camera& cam) {
  GBuffer g;
  g.camera = cam;
  g.resize(cam.width, cam.height);
  tbb::parallel_for(0, cam.height, [&](int y) {
    for (int x = 0; x < cam.width; ++x) {
      const Ray r = cam.primary_ray(float(x) + 0.5f, float(y) + 0.5f);
      float best = INFINITY;
      glm::vec3 n(0.0f);
      uint32_t id = kBackgroundId;
      if (r.direction.y < 0.0f) {
        const float t = -r.origin.y / r.direction.y;
        const glm::vec3 p = r.origin + t * r.direction;
        if (std::fabs(p.x) <= 30.0f && std::fabs(p.z) <= 30.0f) best = t, n = {0, 1, 0}, id = 1;
      }
      for (size_t b = 0; b < boxes().size(); ++b) {
        float t0 = -INFINITY, t1 = INFINITY;
        int axis = -1;
        for (int a = 0; a < 3; ++a) {
          if (r.direction[a] == 0.0f) continue;
          float ta = (boxes()[b].lo[a] - r.origin[a]) / r.direction[a];
          float tb = (boxes()[b].hi[a] - r.origin[a]) / r.direction[a];
          if (ta > tb) std::swap(ta, tb);
          if (ta > t0) t0 = ta, axis = a;
          t1 = std::min(t1, tb);
        }
        if (axis >= 0 && t0 <= t1 && t0 > 0.0f && t0 < best) {
          best = t0;
          n = glm::vec3(0.0f);
          n[axis] = r.direction[axis] > 0.0f ? -1.0f : 1.0f;
          id = uint32_t(2 + b);
        }
      }
      if (id == kBackgroundId) continue;
      const glm::vec3 p = r.origin + best * r.direction;
      g.position(x, y) = p;
      g.depth(x, y) = cam.view_depth(p);
      g.normal(x, y) = n;
      g.geo_normal(x, y) = n;
      g.object_id(x, y) = id;
    }
  });
  return g;
}

struct Frames {
  GBuffer src, dst;
  PassBuffer ao, vis4, soft3;          // soft3: soft visibility of three lights (room's), 8-bit planes
  std::vector<uint32_t> gather_index;  // nearest source pixel of each dst pixel (itself if none)
};

const Frames& frames() {
  static const Frames f = [] {
    Frames r;
    const Camera c0 = Camera::look_at({0.0f, 3.0f, 8.0f}, {0.0f, 0.5f, -2.0f}, {0, 1, 0}, 60.0f, kW, kH, 0.05f, 200.0f);
    Camera c1 = c0;
    c1.position += glm::vec3(0.15f, 0.0f, -0.05f);
    const glm::mat3 yaw(glm::rotate(glm::mat4(1.0f), glm::radians(1.0f), glm::vec3(0, 1, 0)));
    c1.forward = glm::normalize(yaw * c0.forward);
    c1.up = glm::normalize(yaw * c0.up);
    r.src = render(c0);
    r.dst = render(c1);
    const size_t n = size_t(kW) * kH;
    r.ao.desc = {PassKind::Ao, kW, kH, 1, 255};
    r.vis4.desc = {PassKind::Visibility, kW, kH, 4, 255};
    r.soft3.desc = {PassKind::SoftVisibility, kW, kH, 3, 255};
    r.ao.bytes.resize(n);
    r.vis4.bytes.resize(n);
    r.soft3.bytes.resize(3 * n);
    for (size_t i = 0; i < n; ++i) {
      const bool bg = r.src.object_id[i] == kBackgroundId;
      const uint64_t h = rng_bits({1, uint32_t(i), 0, 0, 9});
      r.ao.bytes[i] = bg ? 255 : uint8_t(128 + (h & 63));
      r.vis4.bytes[i] = bg ? 15 : uint8_t(h >> 8 & 15);
      for (size_t c = 0; c < 3; ++c) r.soft3.bytes[c * n + i] = bg ? 255 : uint8_t(h >> (16 + 8 * c));
    }
    r.gather_index.resize(n);
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x) {
        const size_t i = size_t(y) * kW + x;
        const glm::vec3 q = c0.project(r.dst.position[i]);
        const bool in =
            r.dst.object_id[i] != kBackgroundId && q.z > 0.0f && q.x >= 0.0f && q.x < kW && q.y >= 0.0f && q.y < kH;
        r.gather_index[i] = in ? uint32_t(int(q.y) * kW + int(q.x)) : uint32_t(i);
      }
    return r;
  }();
  return f;
}

void gather(const std::vector<uint32_t>& idx, const std::vector<uint8_t>& in, std::vector<uint8_t>& out) {
  tbb::parallel_for(tbb::blocked_range<int>(0, kH, 2), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) {
      const size_t o = size_t(y) * kW;
      for (size_t i = o; i < o + kW; ++i) out[i] = in[idx[i]];
    }
  });
}

// Mean ms of the gather ceiling, measured now (same run, same machine state), over at least
// 0.5 s like the benchmark loop itself: a short median would dodge the preemptions a loaded
// machine inflicts on the longer reprojection loop and bias the ratio.
double gather_ms() {
  const Frames& f = frames();
  std::vector<uint8_t> out(f.ao.bytes.size());
  const auto start = std::chrono::steady_clock::now();
  int runs = 0;
  double elapsed_ms = 0.0;
  while (elapsed_ms < 500.0 || runs < 10) {
    gather(f.gather_index, f.ao.bytes, out);
    benchmark::DoNotOptimize(out.data());
    ++runs;
    elapsed_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  }
  return elapsed_ms / runs;
}

double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) * 1e3 + double(ts.tv_nsec) * 1e-6;
}

// A plane the floor streams: `bytes_per_pixel` bytes per pixel, row-major.
struct Plane {
  const void* data;
  size_t bytes_per_pixel;
};

// One streaming pass: every read plane summed as 64-bit words row by row, the output rows
// written (filled with a byte of that sum, so nothing is optimised away).
void stream_floor(std::span<const Plane> reads, uint8_t* out, size_t out_bpp, std::vector<uint64_t>& sums) {
  tbb::parallel_for(tbb::blocked_range<int>(0, kH, 2), [&](const tbb::blocked_range<int>& r) {
    uint64_t acc = 0;
    for (int y = r.begin(); y < r.end(); ++y) {
      for (const Plane& p : reads) {
        const size_t row = size_t(kW) * p.bytes_per_pixel;
        const auto* bytes = static_cast<const uint8_t*>(p.data) + size_t(y) * row;
        for (size_t i = 0; i + 8 <= row; i += 8) {
          uint64_t v;
          std::memcpy(&v, bytes + i, 8);
          acc += v;
        }
      }
      const size_t orow = size_t(kW) * out_bpp;
      std::memset(out + size_t(y) * orow, int(acc & 255), orow);
    }
    sums[size_t(r.begin())] = acc;
  });
}

// Process CPU ms per floor pass, over at least 0.5 s (as gather_ms).
double floor_cpu_ms(std::span<const Plane> reads, size_t out_bpp) {
  std::vector<uint8_t> out(size_t(kW) * kH * out_bpp);
  std::vector<uint64_t> sums(size_t(kH), 0);
  const auto start = std::chrono::steady_clock::now();
  const double cpu0 = process_cpu_ms();
  int runs = 0;
  while (std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count() < 500.0 ||
         runs < 10) {
    stream_floor(reads, out.data(), out_bpp, sums);
    benchmark::DoNotOptimize(out.data());
    benchmark::DoNotOptimize(sums.data());
    ++runs;
  }
  return (process_cpu_ms() - cpu0) / runs;
}

void run_reprojection(benchmark::State& state, const PassBuffer& in, const nlohmann::json& params) {
  const Frames& f = frames();
  auto p = registries().predictors.create("reprojection", params);
  PassBuffer out;
  PredictStats st = p->predict({in, f.src, f.dst}, out);  // warm: sizes the output once
  double total_ms = 0.0;
  const tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
  const double cpu0 = process_cpu_ms();
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    st = p->predict({in, f.src, f.dst}, out);
    benchmark::DoNotOptimize(out.bytes.data());
    total_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
  const double cpu_ms = (process_cpu_ms() - cpu0) / double(state.iterations());
  const double ceiling = gather_ms();
  const double per_frame = total_ms / double(state.iterations());
  const Plane reads[] = {{in.bytes.data(), 1},      {f.dst.object_id.data(), 4},  {f.dst.position.data(), 12},
                         {f.dst.normal.data(), 12}, {f.src.object_id.data(), 4},  {f.src.position.data(), 12},
                         {f.src.normal.data(), 12}, {f.src.geo_normal.data(), 12}};
  const double floor_ms = floor_cpu_ms(reads, 1);
  state.counters["cpu_ms"] = cpu_ms;
  state.counters["floor_cpu_ms"] = floor_ms;
  state.counters["x_floor"] = cpu_ms / floor_ms;
  state.counters["gather_ms"] = ceiling;
  state.counters["x_gather"] = per_frame / ceiling;
  state.counters["disoccluded_%"] = 100.0 * double(st.disoccluded) / double(std::max<uint64_t>(st.pixels, 1));
  state.counters["Mpix/s"] = benchmark::Counter(double(kW) * kH, benchmark::Counter::kIsIterationInvariantRate);
}

void BM_Reprojection_Ao_Bilinear(benchmark::State& state) {
  run_reprojection(state, frames().ao, {{"filter", "bilinear"}});
}
BENCHMARK(BM_Reprojection_Ao_Bilinear)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_Reprojection_Ao_Nearest(benchmark::State& state) {
  run_reprojection(state, frames().ao, {{"filter", "nearest"}});
}
BENCHMARK(BM_Reprojection_Ao_Nearest)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_Reprojection_Visibility4(benchmark::State& state) {
  run_reprojection(state, frames().vis4, nlohmann::json::object());
}
BENCHMARK(BM_Reprojection_Visibility4)->Unit(benchmark::kMillisecond)->UseRealTime();

// The hybrid client's frame on room: soft visibility (three lights) and AO received for the same
// frame, predicted apart (two calls, the taps found twice) and together (one predict_passes call,
// what the client does), one thread, process CPU ms per frame against the floor of streaming
// everything the two read and write once.
void run_soft_and_ao(benchmark::State& state, bool together) {
  const Frames& f = frames();
  auto p = registries().predictors.create("reprojection", nlohmann::json::object());
  PassBuffer soft, ao;
  const PassBuffer* received[2] = {&f.soft3, &f.ao};
  PassBuffer* out[2] = {&soft, &ao};
  auto once = [&] {
    if (together) {
      p->predict_passes(f.src, f.dst, received, out);
    } else {
      p->predict({f.soft3, f.src, f.dst}, soft);
      p->predict({f.ao, f.src, f.dst}, ao);
    }
  };
  once();  // warm: sizes the outputs
  const tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
  const double cpu0 = process_cpu_ms();
  for (auto _ : state) {
    once();
    benchmark::DoNotOptimize(soft.bytes.data());
    benchmark::DoNotOptimize(ao.bytes.data());
  }
  const double cpu_ms = (process_cpu_ms() - cpu0) / double(state.iterations());
  const Plane reads[] = {{f.soft3.bytes.data(), 3},   {f.ao.bytes.data(), 1},    {f.dst.object_id.data(), 4},
                         {f.dst.position.data(), 12}, {f.dst.normal.data(), 12}, {f.src.object_id.data(), 4},
                         {f.src.position.data(), 12}, {f.src.normal.data(), 12}, {f.src.geo_normal.data(), 12}};
  const double floor_ms = floor_cpu_ms(reads, 4);
  state.counters["cpu_ms"] = cpu_ms;
  state.counters["floor_cpu_ms"] = floor_ms;
  state.counters["x_floor"] = cpu_ms / floor_ms;
}

void BM_Reprojection_SoftAndAo_Apart(benchmark::State& state) { run_soft_and_ao(state, false); }
BENCHMARK(BM_Reprojection_SoftAndAo_Apart)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_Reprojection_SoftAndAo_Together(benchmark::State& state) { run_soft_and_ao(state, true); }
BENCHMARK(BM_Reprojection_SoftAndAo_Together)->Unit(benchmark::kMillisecond)->UseRealTime();

// The remote client's warps of an RGB8 colour frame at 1280x720, between the same two cameras:
// rotation_warp (cameras only) and depth_warp (with the src frame's depth as the client receives
// it: 12-bit inverse depth, unpacked inside the timed loop as the client does for every frame).
// Memory floor: reading the colour (3 B/px) and, for depth_warp, the received depth pass (2 B/px),
// and writing the warped colour (3 B/px). One thread, process CPU time, as above. (The frames
// above were rendered for the reprojection benchmarks; the colour is random bytes.)
void run_warp(benchmark::State& state, bool with_depth) {
  const Frames& f = frames();
  const size_t n = size_t(kW) * kH;
  PassBuffer colour;
  colour.desc = {PassKind::Colour, kW, kH, 3, 255};
  colour.bytes.resize(3 * n);
  for (size_t i = 0; i < 3 * n; ++i) colour.bytes[i] = uint8_t(rng_bits({3, uint32_t(i), 0, 0, 9}));
  const PassBuffer depth = pack_depth(f.src.depth, f.src.camera, 12);
  GBuffer src, dst;
  src.camera = f.src.camera;
  dst.camera = f.dst.camera;
  auto p = registries().predictors.create(with_depth ? "depth_warp" : "rotation_warp", nlohmann::json::object());
  PassBuffer out;
  auto once = [&] {
    if (with_depth) src.depth = unpack_depth(depth, src.camera);
    return p->predict({colour, src, dst}, out);
  };
  PredictStats st = once();  // warm: sizes the buffers once
  const tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
  const double cpu0 = process_cpu_ms();
  for (auto _ : state) {
    st = once();
    benchmark::DoNotOptimize(out.bytes.data());
  }
  const double cpu_ms = (process_cpu_ms() - cpu0) / double(state.iterations());
  std::vector<Plane> reads = {{colour.bytes.data(), 3}};
  if (with_depth) reads.push_back({depth.bytes.data(), 2});
  const double floor_ms = floor_cpu_ms(reads, 3);
  state.counters["cpu_ms"] = cpu_ms;
  state.counters["floor_cpu_ms"] = floor_ms;
  state.counters["x_floor"] = cpu_ms / floor_ms;
  state.counters["disoccluded_%"] = 100.0 * double(st.disoccluded) / double(std::max<uint64_t>(st.pixels, 1));
}

void BM_RotationWarp_Colour(benchmark::State& state) { run_warp(state, false); }
BENCHMARK(BM_RotationWarp_Colour)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_DepthWarp_Colour(benchmark::State& state) { run_warp(state, true); }
BENCHMARK(BM_DepthWarp_Colour)->Unit(benchmark::kMillisecond)->UseRealTime();

// The client's upsampling of an AO pass traced at 1/scale (core/buffers/upsample.h) to 1280x720, guided
// by the dst frame's G-buffer (joint_bilateral) or not (bilinear). Memory floor: the full-res
// G-buffer planes it reads (joint_bilateral: object_id, position, normal, depth, 32 B/px;
// bilinear: object_id, 4 B/px) and the 1 B/px it writes; the low-res pass it reads (1/scale^2
// B/px) is left out. One thread, process CPU time, as above.
void run_upsample(benchmark::State& state, UpsampleFilter filter) {
  const int scale = int(state.range(0));
  const Frames& f = frames();
  PassBuffer low;
  low.desc = {PassKind::Ao, reduced_size(kW, scale), reduced_size(kH, scale), 1, 255};
  low.bytes.resize(low.desc.byte_size());
  for (size_t i = 0; i < low.bytes.size(); ++i) low.bytes[i] = uint8_t(rng_bits({5, uint32_t(i), 0, 0, 9}));
  PassBuffer out = upsample_pass(low, f.dst, scale, filter);  // warm
  const tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
  const double cpu0 = process_cpu_ms();
  for (auto _ : state) {
    out = upsample_pass(low, f.dst, scale, filter);
    benchmark::DoNotOptimize(out.bytes.data());
  }
  const double cpu_ms = (process_cpu_ms() - cpu0) / double(state.iterations());
  std::vector<Plane> reads = {{f.dst.object_id.data(), 4}};
  if (filter == UpsampleFilter::JointBilateral) {
    reads.push_back({f.dst.position.data(), 12});
    reads.push_back({f.dst.normal.data(), 12});
    reads.push_back({f.dst.depth.data(), 4});
  }
  const double floor_ms = floor_cpu_ms(reads, 1);
  state.counters["cpu_ms"] = cpu_ms;
  state.counters["floor_cpu_ms"] = floor_ms;
  state.counters["x_floor"] = cpu_ms / floor_ms;
}

void BM_Upsample_Ao_JointBilateral(benchmark::State& state) { run_upsample(state, UpsampleFilter::JointBilateral); }
BENCHMARK(BM_Upsample_Ao_JointBilateral)->Arg(2)->Arg(4)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_Upsample_Ao_Bilinear(benchmark::State& state) { run_upsample(state, UpsampleFilter::Bilinear); }
BENCHMARK(BM_Upsample_Ao_Bilinear)->Arg(2)->Arg(4)->Unit(benchmark::kMillisecond)->UseRealTime();

// The composite's inputs: room (three lights) rasterized at 1280x720, `rows` rows of it from
// the middle (all of it for 720), and a visibility bitmask and an AO pass of synthetic bytes.
struct CompositeBench {
  Scene scene;
  GBuffer g;
  PassBuffer vis, ao;
};
CompositeBench composite_bench(int rows) {
  CompositeBench b;
  for (const std::string& f : builtin_scene_files())
    if (f.ends_with("/room.json")) b.scene = load_scene(f, SceneSearchPath::standard());
  const Camera cam = b.scene.camera.at(0.0, kW, kH);
  rasterize({&b.scene, cam, 0.0, cam, 0.0}, b.g);
  if (rows < kH) {
    const GBuffer full = std::move(b.g);
    const int y0 = (kH - rows) / 2;
    b.g = GBuffer{};
    b.g.camera = full.camera;
    b.g.resize(kW, rows);
    for (int y = 0; y < rows; ++y)
      for (int x = 0; x < kW; ++x) {
        b.g.position(x, y) = full.position(x, y0 + y);
        b.g.normal(x, y) = full.normal(x, y0 + y);
        b.g.geo_normal(x, y) = full.geo_normal(x, y0 + y);
        b.g.albedo(x, y) = full.albedo(x, y0 + y);
        b.g.object_id(x, y) = full.object_id(x, y0 + y);
        b.g.depth(x, y) = full.depth(x, y0 + y);
      }
  }
  const size_t n = size_t(kW) * size_t(rows);
  const int lights = int(b.scene.lights.size());
  b.vis.desc = {PassKind::Visibility, kW, rows, lights, 255};
  b.ao.desc = {PassKind::Ao, kW, rows, 1, 255};
  b.vis.bytes.resize(b.vis.desc.byte_size());
  b.ao.bytes.resize(n);
  const size_t bpp = b.vis.bytes.size() / n;
  for (size_t i = 0; i < n; ++i) {
    const uint64_t h = rng_bits({2, uint32_t(i), 0, 0, 9});
    b.ao.bytes[i] = uint8_t(128 + (h & 127));
    for (size_t k = 0; k < bpp; ++k) b.vis.bytes[i * bpp + k] = uint8_t(h >> (8 + 8 * k));
  }
  return b;
}

// The composite of room (three lights) at 1280x720: a visibility bitmask and an AO pass of
// synthetic bytes over the rasterized G-buffer.
// state.range(0): 1 = the 8-lane row path only (composite_row_path_only), 0 = the default (the
// 16-lane kernel where the CPU has AVX-512).
void BM_Composite(benchmark::State& state) {
  CompositeBench b;
  try {
    b = composite_bench(kH);
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
    return;
  }
  composite_row_path_only(state.range(0) != 0);
  const GBuffer& g = b.g;
  const size_t n = size_t(kW) * kH;
  const CompositeSettings settings;
  ImageRGB8 img = composite(g, b.scene, &b.vis, &b.ao, settings);
  const tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
  const double cpu0 = process_cpu_ms();
  for (auto _ : state) {
    img = composite(g, b.scene, &b.vis, &b.ao, settings);
    benchmark::DoNotOptimize(img.data());
  }
  const double cpu_ms = (process_cpu_ms() - cpu0) / double(state.iterations());
  const Plane reads[] = {{g.object_id.data(), 4},
                         {g.normal.data(), 12},
                         {g.albedo.data(), 12},
                         {g.position.data(), 12},
                         {b.vis.bytes.data(), b.vis.bytes.size() / n},
                         {b.ao.bytes.data(), 1}};
  const double floor_ms = floor_cpu_ms(reads, 3);
  state.counters["lights"] = double(b.scene.lights.size());
  state.counters["cpu_ms"] = cpu_ms;
  state.counters["floor_cpu_ms"] = floor_ms;
  state.counters["x_floor"] = cpu_ms / floor_ms;
  composite_row_path_only(false);
}
BENCHMARK(BM_Composite)->ArgName("row_path_only")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

#if DHR_AVX512_KERNELS
// The inputs of composite_divisions_x16: d^2 and n . l for 1024 lanes (8 KB, in L1).
struct DivisionInputs {
  alignas(64) float d2[1024], dot[1024];
  DivisionInputs() {
    for (size_t i = 0; i < 1024; ++i) d2[i] = 1.0f + float(i) * 1e-3f, dot[i] = 0.5f + float(i) * 1e-4f;
  }
};

// `blocks` times a sphere light's square root and two divisions in 16 lanes, on `in`; no
// block's divisions wait on another's (only the sum that keeps them live does).
DHR_AVX512_TARGET void composite_divisions_x16(const DivisionInputs& in, size_t blocks) {
  const float* d2 = in.d2;
  const float* dot = in.dot;
  __m512 acc = _mm512_setzero_ps();
  for (size_t k = 0; k < blocks; ++k) {
    const size_t j = (k * 16) % 1024;
    const __m512 m = _mm512_load_ps(d2 + j);
    const __m512 q = _mm512_div_ps(_mm512_load_ps(dot + j), _mm512_maskz_sqrt_ps(0xffff, m));
    acc = _mm512_add_ps(acc, _mm512_mul_ps(q, _mm512_div_ps(_mm512_set1_ps(1.0f), m)));
  }
  benchmark::DoNotOptimize(acc);
}
#endif

// The same composite on data in cache: the middle 8 rows of that frame (about 0.4 MB read and
// written, within L2) composited 90 times, CPU ms per 720 rows: what the kernel's arithmetic
// takes without waiting on memory. Beside it, the arithmetic the same bits cannot do without:
// each sphere light's square root and two IEEE divisions (n . l / d and 1 / max(d^2, r^2, ...))
// for every 16 pixels of a 1280x720 frame and light (room's three lights are all spheres),
// independent of each other, on data in L1
// (`divisions_cpu_ms`; where the CPU has AVX-512, the composite's 16-lane kernel's case).
void BM_Composite_InCache(benchmark::State& state) {
  CompositeBench b;
  try {
    b = composite_bench(8);
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
    return;
  }
  const CompositeSettings settings;
  const tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
  const int reps = kH / b.g.height();
  ImageRGB8 img;
  const double cpu0 = process_cpu_ms();
  for (auto _ : state)
    for (int r = 0; r < reps; ++r) {
      img = composite(b.g, b.scene, &b.vis, &b.ao, settings);
      benchmark::DoNotOptimize(img.data());
    }
  const double cpu_ms = (process_cpu_ms() - cpu0) / double(state.iterations());
  state.counters["cpu_ms"] = cpu_ms;
#if DHR_AVX512_KERNELS
  if (cpu_has_avx512dq()) {
    const DivisionInputs inputs;
    double div_ms = 1e30;
    for (int round = 0; round < 5; ++round) {
      const double t0 = process_cpu_ms();
      composite_divisions_x16(inputs, size_t(kW) * kH / 16 * b.scene.lights.size());
      div_ms = std::min(div_ms, process_cpu_ms() - t0);
    }
    state.counters["divisions_cpu_ms"] = div_ms;
  }
#endif
}
BENCHMARK(BM_Composite_InCache)->Unit(benchmark::kMillisecond)->UseRealTime();

// The ceiling on its own, for reference (the counters above re-measure it beside each run).
void BM_GatherCeiling_U8(benchmark::State& state) {
  const Frames& f = frames();
  std::vector<uint8_t> out(f.ao.bytes.size());
  for (auto _ : state) {
    gather(f.gather_index, f.ao.bytes, out);
    benchmark::DoNotOptimize(out.data());
  }
  state.counters["Mpix/s"] = benchmark::Counter(double(kW) * kH, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_GatherCeiling_U8)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
