// Pass coding against what the client holds (backends/codec/delta.cpp, predictor
// reprojection) at 1280x720 on the room scene rasterized along its camera path (frames 0 and 4
// of the path at 60 Hz: 67 ms of camera motion, what a 50 ms round trip leaves between two
// coded frames), with passes fixed to the world (AO a smooth function of the world position,
// a one-light visibility checker), as tests/backends/test_pass_coding.cpp uses.
//
// Per pass, one thread (TBB limited to 1), process CPU time per frame (`cpu_ms`):
//   inner        zstd level 1 on the frame alone: the codec the delta wraps
//   delta_none   delta + zstd against the previous frame as it is
//   delta_reproj delta + zstd against the previous frame reprojected (encode; `decode`: the client)
//   predict      the reprojection alone (bilinear filter, what the delta uses by default)
//   floor        one streaming pass over the bytes prediction and residual touch: the G-buffer
//                planes the reprojection reads (dst object_id, position, normal; src object_id,
//                position, normal, geo_normal: 69 B/px), the reference, the frame and the
//                prediction (3 B/px read) and the prediction and residual written (2 B/px)
//   h264, h264_decode        (AO) h264 crf 23 on the frame alone: encode, decode
//   delta_video_reproj       (AO) delta_video: the residual against the reprojected
//                            reconstruction through h264 crf 23 (encode; `decode`: the client)
// Counters: `bytes` per coded frame, and for delta_reproj `x_inner` (its CPU time over the
// inner codec's) and `overhead_minus_predict_ms` (delta_reproj - inner - predict: what the
// wrapping costs beyond the prediction; the goal is that it stays <= 0 or near it);
// for delta_video also `overhead_minus_predict_mirror_ms` (less one h264 decode: its encoder
// decodes its own output to keep the client's reconstruction as the reference).
//
// Usage: build/tests/bench_pass_coding [--benchmark_repetitions=3]
//
// --regions [--frames N] [SCENE...]: instead of timing, where the residual's bits go on real
// passes (default scenes: room, classroom, living-room, the headline's; 320x180, frames 1..N
// of the camera path from 1.0 s at 60 Hz, 8 AO rays denoised with svgf_ao, one jittered shadow
// ray per light as the headline traces them). Each frame k is predicted from frame k-1 as the
// delta codec predicts it (reprojection; bilinear for AO, nearest for the bitmask), and every
// covered pixel is put in one region, first match wins:
//   disoccluded  the reprojection found no valid source sample (filled, not predicted)
//   moving       the surface belongs to an animated object
//   penumbra     some light's bit differs from a 4-neighbour's (shadow edges and the noise of
//                one jittered ray inside penumbrae)
//   static       everything else
// Per region: its share of covered pixels, its share of the residual's nonzero pixels, and the
// bytes zstd (level 3) spends on it: the residual coded with every other region zeroed, less
// the all-zero residual's size. The regions' bytes need not add up to the whole frame's.
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "core/config/run_config.h"
#include "core/pass/passes.h"
#include "core/raster/raster.h"
#include "core/scene/scene_load.h"
#include "core/trace/rt_scene.h"
#include "core/trace/trace.h"
#include "tests/support_buffers.h"

#include <benchmark/benchmark.h>
#include <tbb/global_control.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <map>
#include <set>
#include <string>
#include <vector>

namespace {

using namespace dhr;

constexpr int kW = 1280, kH = 720;
constexpr int kFrameGap = 4;

double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) * 1e3 + double(ts.tv_nsec) * 1e-6;
}

struct Frames {
  GBuffer g[2];
  PassBuffer pass[2][2];  // [AO, visibility][frame]
};

const Frames& frames() {
  static const Frames f = [] {
    Frames r;
    const Scene scene = load_scene(std::string(DHR_SOURCE_DIR) + "/scenes/room.json", SceneSearchPath::standard());
    for (int i = 0; i < 2; ++i) {
      const double t = 1.0 + i * kFrameGap / 60.0, t_prev = t - 1.0 / 60.0;
      rasterize({&scene, scene.camera.at(t, kW, kH), t, scene.camera.at(t_prev, kW, kH), t_prev}, r.g[i]);
      r.pass[0][i] = test::make_world_pass(r.g[i], PassKind::Ao);
      r.pass[1][i] = test::make_world_pass(r.g[i], PassKind::Visibility);
    }
    return r;
  }();
  return f;
}

std::map<std::string, double>& cpu_of() {  // "pass/what" -> CPU ms per frame, for the ratios
  static std::map<std::string, double> m;
  return m;
}

// Frame i of the benchmark alternates between the two G-buffers, so every coded frame is
// predicted across the same camera motion (forwards, then backwards).
FrameContext context_of(uint32_t i) {
  const Frames& f = frames();
  return {i, &f.g[i % 2], [&f](uint32_t k) { return &f.g[k % 2]; }};
}

// `key`: where its CPU ms per frame is kept in cpu_of() for the ratios.
void run_codec(benchmark::State& state, const std::string& key, int pass, const std::string& name,
               const nlohmann::json& params, bool decode) {
  tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
  const Frames& f = frames();
  auto enc = registries().codecs.create(name, params);
  auto dec = registries().codecs.create(name, params);
  std::vector<uint8_t> bytes;
  PassBuffer out;
  std::string error;
  uint32_t i = 0;
  auto step = [&](bool time_decode) {
    const PassBuffer& in = f.pass[pass][i % 2];
    EncodeOptions o;
    o.context = context_of(i);
    const double c0 = process_cpu_ms();
    enc->encode(in, o, bytes);
    const double c1 = process_cpu_ms();
    if (!dec->decode_in_context(bytes, in.desc, context_of(i), out, error) ||
        (enc->lossless() && out.bytes != in.bytes))
      state.SkipWithError(("decode failed: " + error).c_str());
    const double c2 = process_cpu_ms();
    ++i;
    return time_decode ? c2 - c1 : c1 - c0;
  };
  step(false);  // the keyframe
  double cpu = 0.0;
  size_t total = 0;
  for (auto _ : state) {
    cpu += step(decode);
    total += bytes.size();
  }
  const double n = double(state.iterations());
  cpu_of()[key] = cpu / n;
  state.counters["cpu_ms"] = cpu / n;
  state.counters["bytes"] = double(total) / n;
}

std::string key_of(int pass, const char* what) { return std::to_string(pass) + "/" + what; }

void BM_Inner(benchmark::State& s, int pass) {
  run_codec(s, key_of(pass, "inner"), pass, "zstd", {{"level", 1}}, false);
}
void BM_DeltaNone(benchmark::State& s, int pass) {
  run_codec(s, key_of(pass, "delta_none"), pass, "delta", {{"inner", "zstd"}, {"level", 1}, {"predictor", "none"}},
            false);
}
void BM_DeltaReproj(benchmark::State& s, int pass, bool decode) {
  const std::string self = key_of(pass, decode ? "delta_reproj_decode" : "delta_reproj");
  run_codec(s, self, pass, "delta", {{"inner", "zstd"}, {"level", 1}, {"predictor", "reprojection"}}, decode);
  auto& m = cpu_of();
  const std::string inner = key_of(pass, "inner"), predict = key_of(pass, "predict");
  if (!decode && m.count(inner) && m.count(predict)) {
    s.counters["x_inner"] = m[self] / m[inner];
    s.counters["overhead_minus_predict_ms"] = m[self] - m[inner] - m[predict];
  }
}

// delta_video (AO only): the residual through h264 crf 23, against h264 crf 23 on the frame
// alone. Its encoder also decodes what it made (the mirror: the reconstruction is the
// reference), so beyond the prediction it costs about one h264 decode.
const nlohmann::json kH264 = {{"rate_control", "crf"}, {"crf", 23}};
void BM_H264(benchmark::State& s, bool decode) {
  run_codec(s, key_of(0, decode ? "h264_decode" : "h264"), 0, "h264", kH264, decode);
}
void BM_DeltaVideo(benchmark::State& s, bool decode) {
  const std::string self = key_of(0, decode ? "delta_video_decode" : "delta_video");
  run_codec(s, self, 0, "delta_video", {{"inner", "h264"}, {"crf", 23}, {"predictor", "reprojection"}}, decode);
  auto& m = cpu_of();
  const std::string inner = key_of(0, "h264"), inner_decode = key_of(0, "h264_decode"), predict = key_of(0, "predict");
  if (!decode && m.count(inner) && m.count(inner_decode) && m.count(predict)) {
    s.counters["x_inner"] = m[self] / m[inner];
    s.counters["overhead_minus_predict_ms"] = m[self] - m[inner] - m[predict];
    s.counters["overhead_minus_predict_mirror_ms"] = m[self] - m[inner] - m[predict] - m[inner_decode];
  }
}

void BM_Predict(benchmark::State& state, int pass) {
  tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
  const Frames& f = frames();
  // The filter the delta uses by default: bilinear (a bitmask is always taken from the nearest tap).
  auto predictor = registries().predictors.create("reprojection", {{"filter", "bilinear"}});
  PassBuffer out;
  const double c0 = process_cpu_ms();
  for (auto _ : state) predictor->predict({f.pass[pass][0], f.g[0], f.g[1]}, out);
  const double cpu = (process_cpu_ms() - c0) / double(state.iterations());
  cpu_of()[key_of(pass, "predict")] = cpu;
  state.counters["cpu_ms"] = cpu;
}

// One streaming pass: read the planes prediction and residual read, write what they write.
void BM_Floor(benchmark::State& state, int pass) {
  const Frames& f = frames();
  const GBuffer &src = f.g[0], &dst = f.g[1];
  const size_t n = size_t(kW) * kH;
  std::vector<uint8_t> w1(n), w2(n);
  const double c0 = process_cpu_ms();
  for (auto _ : state) {
    const uint8_t* ref = f.pass[pass][0].bytes.data();
    const uint8_t* cur = f.pass[pass][1].bytes.data();
    for (size_t i = 0; i < n; ++i) {
      float s = dst.position[i].x + dst.normal[i].y + src.position[i].z + src.normal[i].x + src.geo_normal[i].y;
      const uint32_t id = dst.object_id[i] ^ src.object_id[i];
      const uint8_t p = uint8_t(ref[i] + uint8_t(id) + uint8_t(s > 0.0f));
      w1[i] = p;
      w2[i] = uint8_t(cur[i] - p + ref[i]);
    }
    benchmark::DoNotOptimize(w1.data());
    benchmark::DoNotOptimize(w2.data());
    benchmark::ClobberMemory();
  }
  state.counters["cpu_ms"] = (process_cpu_ms() - c0) / double(state.iterations());
  state.counters["bytes_per_px"] = 69 + 3 + 2;
}

void register_all() {
  for (int pass : {0, 1}) {
    const std::string p = pass == 0 ? "ao" : "visibility";
    auto reg = [&](const std::string& what, auto fn) {
      benchmark::RegisterBenchmark(("pass_coding/" + p + "/" + what).c_str(), fn)
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime();
    };
    reg("inner", [pass](benchmark::State& s) { BM_Inner(s, pass); });
    reg("predict", [pass](benchmark::State& s) { BM_Predict(s, pass); });
    reg("floor", [pass](benchmark::State& s) { BM_Floor(s, pass); });
    reg("delta_none", [pass](benchmark::State& s) { BM_DeltaNone(s, pass); });
    reg("delta_reproj", [pass](benchmark::State& s) { BM_DeltaReproj(s, pass, false); });
    reg("delta_reproj_decode", [pass](benchmark::State& s) { BM_DeltaReproj(s, pass, true); });
    if (pass == 0) {
      reg("h264", [](benchmark::State& s) { BM_H264(s, false); });
      reg("h264_decode", [](benchmark::State& s) { BM_H264(s, true); });
      reg("delta_video_reproj", [](benchmark::State& s) { BM_DeltaVideo(s, false); });
      reg("delta_video_reproj_decode", [](benchmark::State& s) { BM_DeltaVideo(s, true); });
    }
  }
}

// ---- --regions: where the residual's bits go

enum Region { kDisoccluded, kMoving, kPenumbra, kStatic, kRegions };
const char* const kRegionNames[kRegions] = {"disoccluded", "moving", "penumbra", "static"};

struct RegionTally {
  uint64_t pixels[kRegions] = {}, nonzero[kRegions] = {}, bytes[kRegions] = {};
  uint64_t frame_bytes = 0, frames = 0;
};

int run_regions(const std::vector<std::string>& scenes, int frames) {
  constexpr int w = 320, h = 180;
  auto zstd = registries().codecs.create("zstd", {{"level", 3}});
  auto bits_pred = registries().predictors.create("reprojection", {{"filter", "nearest"}});
  auto ao_pred = registries().predictors.create("reprojection", {{"filter", "bilinear"}});
  auto hole_pred = registries().predictors.create("reprojection", {{"filter", "nearest"}, {"fill", "local"}});
  SimConfig trace;  // the headline's tracing: seed 1, 8 AO rays, one jittered ray per light
  trace.seed = 1;
  trace.trace.ao_rays = 8;
  std::printf("320x180, frames 1..%d predicted from the frame before (60 Hz from 1.0 s), zstd level 3\n", frames);
  std::printf("%-12s %-10s %-12s %8s %9s %9s %9s\n", "scene", "pass", "region", "pixels", "nonzero", "bytes", "bytes%");
  for (const std::string& name : scenes) {
    const Scene scene = load_scene_or_model(name, SceneSearchPath::standard());
    RtScene rt(scene);
    std::set<uint32_t> moving_ids;
    for (const Object& o : scene.objects)
      if (o.moving()) moving_ids.insert(o.id);
    auto svgf = registries().denoisers.create("svgf_ao", nlohmann::json::object());
    std::map<std::string, RegionTally> tally;
    GBuffer prev_g;
    std::map<std::string, PassBuffer> prev;
    for (int k = 0; k <= frames; ++k) {
      const double t = 1.0 + k / 60.0, t_prev = k ? t - 1.0 / 60.0 : t;
      GBuffer g;
      rasterize({&scene, scene.camera.at(t, w, h), t, scene.camera.at(t_prev, w, h), t_prev}, g);
      const TraceResult traced = trace_passes(rt, g, trace.trace_for_frame(uint32_t(k)));
      std::map<std::string, PassBuffer> cur;
      if (const PassBuffer* v = traced.find("visibility")) cur["visibility"] = *v;
      if (const PassBuffer* a = traced.find("ao")) {
        ImageU8 noisy(w, h), out;
        std::memcpy(noisy.data(), a->bytes.data(), a->bytes.size());
        svgf->denoise({g, noisy, a->desc.full_scale, uint32_t(k), k > 0}, out);
        PassBuffer& ao = cur["ao"];
        ao.desc = {PassKind::Ao, w, h, 1, 255};
        ao.bytes.assign(out.data(), out.data() + size_t(w) * h);
      }
      if (k > 0) {
        // Disocclusions: the local fill of an all-zero buffer marks them (fully lit = 255).
        PassBuffer zero{{PassKind::Ao, w, h, 1, 255}, std::vector<uint8_t>(size_t(w) * h, 0)}, holes;
        hole_pred->predict({zero, prev_g, g}, holes);
        const PassBuffer* vis = cur.count("visibility") ? &cur["visibility"] : nullptr;
        const size_t stride = vis ? vis->desc.pixel_bytes() : 0;
        std::vector<uint8_t> region(size_t(w) * h, kRegions);  // kRegions: background
        for (int y = 0; y < h; ++y)
          for (int x = 0; x < w; ++x) {
            const size_t i = size_t(y) * w + x;
            if (!g.covered(x, y)) continue;
            const bool moving = moving_ids.count(g.object_id(x, y)) > 0;
            bool edge = false;
            if (vis)
              for (auto [dx, dy] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
                const int nx = x + dx, ny = y + dy;
                if (nx < 0 || ny < 0 || nx >= w || ny >= h) continue;
                const size_t j = size_t(ny) * w + nx;
                edge = edge || std::memcmp(&vis->bytes[i * stride], &vis->bytes[j * stride], stride) != 0;
              }
            region[i] = uint8_t(holes.bytes[i] == 255 ? kDisoccluded : moving ? kMoving : edge ? kPenumbra : kStatic);
          }
        for (auto& [pass, buf] : cur) {
          PassBuffer pred;
          (pass == "ao" ? ao_pred : bits_pred)->predict({prev[pass], prev_g, g}, pred);
          PassBuffer residual = buf;
          const size_t px_bytes = buf.desc.pixel_bytes();
          for (size_t b = 0; b < buf.bytes.size(); ++b)
            residual.bytes[b] =
                pass == "ao" ? uint8_t(buf.bytes[b] - pred.bytes[b]) : uint8_t(buf.bytes[b] ^ pred.bytes[b]);
          RegionTally& tl = tally[pass];
          std::vector<uint8_t> coded;
          zstd->encode(residual, {}, coded);
          tl.frame_bytes += coded.size();
          ++tl.frames;
          PassBuffer empty = residual;
          std::fill(empty.bytes.begin(), empty.bytes.end(), 0);
          zstd->encode(empty, {}, coded);
          const size_t base = coded.size();
          for (int r = 0; r < kRegions; ++r) {
            PassBuffer only = empty;
            for (size_t i = 0; i < region.size(); ++i) {
              if (region[i] != r) continue;
              ++tl.pixels[r];
              bool nz = false;
              for (size_t b = 0; b < px_bytes; ++b) {
                only.bytes[i * px_bytes + b] = residual.bytes[i * px_bytes + b];
                nz = nz || residual.bytes[i * px_bytes + b] != 0;
              }
              tl.nonzero[r] += nz;
            }
            zstd->encode(only, {}, coded);
            tl.bytes[r] += coded.size() - std::min(coded.size(), base);
          }
        }
      }
      prev_g = std::move(g);
      prev = std::move(cur);
    }
    for (const auto& [pass, t] : tally) {
      uint64_t px = 0, nz = 0, by = 0;
      for (int r = 0; r < kRegions; ++r) px += t.pixels[r], nz += t.nonzero[r], by += t.bytes[r];
      for (int r = 0; r < kRegions; ++r)
        std::printf("%-12s %-10s %-12s %7.1f%% %8.1f%% %9.0f %8.1f%%\n", name.c_str(), pass.c_str(), kRegionNames[r],
                    100.0 * double(t.pixels[r]) / double(std::max<uint64_t>(px, 1)),
                    100.0 * double(t.nonzero[r]) / double(std::max<uint64_t>(nz, 1)),
                    double(t.bytes[r]) / double(t.frames),
                    100.0 * double(t.bytes[r]) / double(std::max<uint64_t>(by, 1)));
      std::printf("%-12s %-10s %-12s %8s %8.1f%% %9.0f   (whole residual coded at once; B/frame)\n", name.c_str(),
                  pass.c_str(), "all", "", 100.0 * double(nz) / double(std::max<uint64_t>(px, 1)),
                  double(t.frame_bytes) / double(t.frames));
    }
  }
  return 0;
}
}  // namespace

int main(int argc, char** argv) {
  if (argc > 1 && std::string(argv[1]) == "--regions") {
    std::vector<std::string> scenes;
    int frames = 30;
    for (int i = 2; i < argc; ++i) {
      const std::string a = argv[i];
      if (a == "--frames" && i + 1 < argc) {
        frames = std::atoi(argv[++i]);
        if (frames < 1 || frames > 10000) {
          std::fprintf(stderr, "--frames %s: must be an integer in 1..10000\n", argv[i]);
          return 2;
        }
      } else {
        scenes.push_back(a);
      }
    }
    if (scenes.empty()) scenes = {"room", "classroom", "living-room"};
    try {
      return run_regions(scenes, frames);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_pass_coding --regions: %s\n", e.what());
      return 1;
    }
  }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  register_all();
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
