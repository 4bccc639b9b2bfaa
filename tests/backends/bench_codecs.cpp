// Codec speed at 1280x720 on realistic synthetic buffers (tests/support_buffers.h): each
// codec beside the library's own call on the same bytes in the same run (the ceiling):
//   lz4:  LZ4F_compressFrame / LZ4F_decompress with the same preferences
//   zstd: ZSTD_compress2 / ZSTD_decompressDCtx with the same parameters
//   h264, hevc, av1: a bare libavcodec send/receive loop with the same encoder settings
//         (x264, x265, libaom; dav1d decodes AV1; colour: with the same libswscale conversion),
//         on the same moving 8-frame sequence
// The ceilings take the bytes the library sees (for the planar layout: the planes, so our
// bit transposition counts against us). At the end a table gives ceiling time / our time
// (goal >= 90%) and, before the benchmarks, a table of what the delta codec saves over zstd
// on a panning camera.
//
// Run: build-codec/tests/bench_codecs [--benchmark_repetitions=5 --benchmark_report_aggregates_only=true]
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "core/buffers/buffer_layout.h"
#include "tests/support_buffers.h"

#include <benchmark/benchmark.h>
#include <lz4frame.h>
#include <zstd.h>

extern "C" {
#include <libavcodec/avcodec.h>
#include <libavutil/log.h>
#include <libavutil/opt.h>
#include <libswscale/swscale.h>
}

#include <cstdio>
#include <cstring>
#include <deque>
#include <map>

namespace dhr {
namespace {

using nlohmann::json;
constexpr int kWidth = 1280, kHeight = 720;

struct Buffers {
  PassBuffer noisy_ao8, smooth_ao, hard_vis4, soft_vis4, colour;
  std::vector<PassBuffer> ao_seq, colour_seq;  // 8 frames, panning 2 px/frame
};

const Buffers& buffers() {
  static const Buffers b = [] {
    Buffers r;
    const test::SyntheticView view{kWidth, kHeight};
    r.noisy_ao8 = test::make_noisy_ao(view, 8);
    r.smooth_ao = test::make_smooth_ao(view);
    r.hard_vis4 = test::make_hard_visibility(view, 4);
    r.soft_vis4 = test::make_soft_visibility(view, 4);
    r.colour = test::make_colour(view);
    for (int f = 0; f < 8; ++f) {
      const test::SyntheticView v{kWidth, kHeight, 2.0 * f, 0.0, uint32_t(f)};
      r.ao_seq.push_back(f == 0 ? r.smooth_ao : test::make_smooth_ao(v));
      r.colour_seq.push_back(f == 0 ? r.colour : test::make_colour(v));
    }
    return r;
  }();
  return b;
}

void set_counters(benchmark::State& state, size_t raw_bytes, size_t coded_bytes, bool encode) {
  const double frames = double(state.iterations());
  state.SetBytesProcessed(int64_t(raw_bytes) * state.iterations());  // MB/s of raw buffer
  state.counters["ratio"] = double(coded_bytes) / double(raw_bytes);
  state.counters["coded_MBps"] = benchmark::Counter(double(coded_bytes) * frames / 1e6, benchmark::Counter::kIsRate);
  state.SetLabel(encode ? "encode" : "decode");
}

// ---- our codecs (through the registry, as the benchmark uses them)

void bench_encode(benchmark::State& state, const char* codec_name, json params, const std::vector<PassBuffer>* seq) {
  auto codec = registries().codecs.create(codec_name, params);
  std::vector<uint8_t> out;
  size_t coded = 0, i = 0;
  for (auto _ : state) {
    codec->encode((*seq)[i++ % seq->size()], {}, out);
    coded += out.size();
    benchmark::DoNotOptimize(out.data());
  }
  set_counters(state, (*seq)[0].bytes.size(), coded / std::max<size_t>(state.iterations(), 1), true);
}

void bench_decode(benchmark::State& state, const char* codec_name, json params, const std::vector<PassBuffer>* seq) {
  auto encoder = registries().codecs.create(codec_name, params);
  std::vector<std::vector<uint8_t>> coded(seq->size());
  size_t total = 0;
  for (size_t i = 0; i < seq->size(); ++i) {
    encoder->encode((*seq)[i], {}, coded[i]);
    total += coded[i].size();
  }
  auto codec = registries().codecs.create(codec_name, params);
  PassBuffer out;
  std::string error;
  size_t i = 0;
  for (auto _ : state) {
    const size_t k = i++ % seq->size();
    if (!codec->decode(coded[k], (*seq)[k].desc, out, error)) {
      state.SkipWithError(error.c_str());
      break;
    }
    benchmark::DoNotOptimize(out.bytes.data());
  }
  set_counters(state, (*seq)[0].bytes.size(), total / seq->size(), false);
}

// ---- ceilings: the libraries called directly on the bytes they see

std::vector<uint8_t> coded_bytes_of(const PassBuffer& in, VisibilityLayout layout) {
  std::vector<uint8_t> scratch;
  const auto span = to_coded_layout(in, layout, scratch);
  return {span.begin(), span.end()};
}

LZ4F_preferences_t lz4_prefs(size_t n) {
  LZ4F_preferences_t p;
  std::memset(&p, 0, sizeof p);
  p.frameInfo.blockMode = LZ4F_blockLinked;
  p.frameInfo.contentChecksumFlag = LZ4F_contentChecksumEnabled;
  p.frameInfo.blockChecksumFlag = LZ4F_blockChecksumEnabled;
  p.frameInfo.contentSize = n;
  return p;
}

void ceiling_lz4(benchmark::State& state, const PassBuffer* in, VisibilityLayout layout, bool encode) {
  const std::vector<uint8_t> src = coded_bytes_of(*in, layout);
  const LZ4F_preferences_t prefs = lz4_prefs(src.size());
  std::vector<uint8_t> frame(LZ4F_compressFrameBound(src.size(), &prefs));
  const size_t frame_size = LZ4F_compressFrame(frame.data(), frame.size(), src.data(), src.size(), &prefs);
  if (encode) {
    for (auto _ : state) {
      size_t r = LZ4F_compressFrame(frame.data(), frame.size(), src.data(), src.size(), &prefs);
      benchmark::DoNotOptimize(r);
    }
  } else {
    LZ4F_dctx* dctx = nullptr;
    LZ4F_createDecompressionContext(&dctx, LZ4F_VERSION);
    std::vector<uint8_t> dst(src.size());
    for (auto _ : state) {
      size_t dst_size = dst.size(), src_size = frame_size;
      LZ4F_resetDecompressionContext(dctx);
      size_t r = LZ4F_decompress(dctx, dst.data(), &dst_size, frame.data(), &src_size, nullptr);
      benchmark::DoNotOptimize(r);
    }
    LZ4F_freeDecompressionContext(dctx);
  }
  set_counters(state, in->bytes.size(), frame_size, encode);
}

void ceiling_zstd(benchmark::State& state, const PassBuffer* in, VisibilityLayout layout, bool encode) {
  const std::vector<uint8_t> src = coded_bytes_of(*in, layout);
  ZSTD_CCtx* cctx = ZSTD_createCCtx();
  ZSTD_DCtx* dctx = ZSTD_createDCtx();
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_compressionLevel, 1);
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_checksumFlag, 1);
  std::vector<uint8_t> frame(ZSTD_compressBound(src.size())), dst(src.size());
  const size_t frame_size = ZSTD_compress2(cctx, frame.data(), frame.size(), src.data(), src.size());
  for (auto _ : state) {
    size_t r = encode ? ZSTD_compress2(cctx, frame.data(), frame.size(), src.data(), src.size())
                      : ZSTD_decompressDCtx(dctx, dst.data(), dst.size(), frame.data(), frame_size);
    benchmark::DoNotOptimize(r);
  }
  ZSTD_freeCCtx(cctx);
  ZSTD_freeDCtx(dctx);
  set_counters(state, in->bytes.size(), frame_size, encode);
}

// A bare libavcodec video encoder and decoder with the settings a video codec uses by default
// (backends/codec/h264.cpp, hevc.cpp, av1.cpp).
struct BareVideo {
  const char* codec;    // the registry name
  const char* encoder;  // libavcodec names
  const char* decoder;
  void (*options)(AVCodecContext*);  // the encoder's private options
  const char* label = nullptr;       // the benchmarks' name (null: codec)
  const char* params = "{}";         // the registry's parameters of the same settings
};

const BareVideo kBareVideos[] = {
    {"h264", "libx264", "h264",
     [](AVCodecContext* c) {
       av_opt_set(c->priv_data, "preset", "ultrafast", 0);
       av_opt_set(c->priv_data, "tune", "zerolatency", 0);
       av_opt_set(c->priv_data, "forced-idr", "1", 0);
       av_opt_set(c->priv_data, "crf", "23", 0);
       av_opt_set(c->priv_data, "x264-params", "scenecut=0:log=0:slice-max-size=1100", 0);
     }},
    // The preset the 1280x720 headline runs (experiments/hybrid_vs_remote_720p.json).
    {"h264", "libx264", "h264",
     [](AVCodecContext* c) {
       av_opt_set(c->priv_data, "preset", "fast", 0);
       av_opt_set(c->priv_data, "tune", "zerolatency", 0);
       av_opt_set(c->priv_data, "forced-idr", "1", 0);
       av_opt_set(c->priv_data, "crf", "23", 0);
       av_opt_set(c->priv_data, "x264-params", "scenecut=0:log=0:slice-max-size=1100", 0);
     },
     "h264_fast", R"({"preset": "fast"})"},
    {"hevc", "libx265", "hevc",
     [](AVCodecContext* c) {
       av_opt_set(c->priv_data, "preset", "ultrafast", 0);
       av_opt_set(c->priv_data, "tune", "zerolatency", 0);
       av_opt_set(c->priv_data, "forced-idr", "1", 0);
       av_opt_set(c->priv_data, "crf", "23", 0);
       av_opt_set(c->priv_data, "x265-params",
                  "log-level=error:scenecut=0:open-gop=0:repeat-headers=1:info=0:frame-threads=1:rc-lookahead=0:"
                  "bframes=0:wpp=1:pools=1",
                  0);
     }},
    {"av1", "libaom-av1", "libdav1d",
     [](AVCodecContext* c) {
       c->keyint_min = 60;
       av_opt_set(c->priv_data, "usage", "realtime", 0);
       av_opt_set(c->priv_data, "cpu-used", "8", 0);
       av_opt_set(c->priv_data, "lag-in-frames", "0", 0);
       av_opt_set(c->priv_data, "row-mt", "0", 0);
       av_opt_set(c->priv_data, "crf", "35", 0);
     }},
};

AVCodecContext* bare_encoder(const BareVideo& v, int w, int h, AVPixelFormat format) {
  const AVCodec* codec = avcodec_find_encoder_by_name(v.encoder);
  if (!codec) return nullptr;
  AVCodecContext* c = avcodec_alloc_context3(codec);
  c->width = w;
  c->height = h;
  c->time_base = {1, 60};
  c->framerate = {60, 1};
  c->pix_fmt = format;
  c->gop_size = 60;
  c->max_b_frames = 0;
  c->thread_count = 1;
  v.options(c);
  if (avcodec_open2(c, codec, nullptr) < 0) avcodec_free_context(&c);
  return c;
}

// Fills `frame` from an AO or colour buffer the way any libavcodec user would.
void fill_frame(AVFrame* frame, const PassBuffer& in, SwsContext* sws) {
  av_frame_make_writable(frame);
  if (in.desc.kind == PassKind::Colour) {
    const uint8_t* src[1] = {in.bytes.data()};
    const int stride[1] = {in.desc.width * 3};
    sws_scale(sws, src, stride, 0, in.desc.height, frame->data, frame->linesize);
  } else {
    for (int y = 0; y < in.desc.height; ++y)
      std::memcpy(frame->data[0] + ptrdiff_t(y) * frame->linesize[0], in.bytes.data() + size_t(y) * in.desc.width,
                  size_t(in.desc.width));
  }
}

void ceiling_video(benchmark::State& state, const BareVideo& v, const std::vector<PassBuffer>* seq, bool encode) {
  const bool colour = (*seq)[0].desc.kind == PassKind::Colour;
  const AVPixelFormat format = colour ? AV_PIX_FMT_YUV420P : AV_PIX_FMT_GRAY8;
  AVCodecContext* enc = bare_encoder(v, kWidth, kHeight, format);
  if (!enc) {
    state.SkipWithError((std::string("cannot open ") + v.encoder).c_str());
    return;
  }
  SwsContext* to_yuv = sws_getContext(kWidth, kHeight, AV_PIX_FMT_RGB24, kWidth, kHeight, AV_PIX_FMT_YUV420P,
                                      SWS_BILINEAR, nullptr, nullptr, nullptr);
  SwsContext* to_rgb = sws_getContext(kWidth, kHeight, AV_PIX_FMT_YUV420P, kWidth, kHeight, AV_PIX_FMT_RGB24,
                                      SWS_BILINEAR, nullptr, nullptr, nullptr);
  AVFrame* frame = av_frame_alloc();
  frame->format = format;
  frame->width = kWidth;
  frame->height = kHeight;
  av_frame_get_buffer(frame, 0);
  AVPacket* pkt = av_packet_alloc();
  int64_t pts = 0;
  size_t coded = 0;
  auto encode_one = [&](const PassBuffer& in, std::vector<uint8_t>* keep) {
    fill_frame(frame, in, to_yuv);
    frame->pts = pts++;
    avcodec_send_frame(enc, frame);
    while (avcodec_receive_packet(enc, pkt) == 0) {
      coded += size_t(pkt->size);
      if (keep) keep->insert(keep->end(), pkt->data, pkt->data + pkt->size);
      av_packet_unref(pkt);
    }
  };
  size_t i = 0;
  if (encode) {
    for (auto _ : state) encode_one((*seq)[i++ % seq->size()], nullptr);
    set_counters(state, (*seq)[0].bytes.size(), coded / std::max<size_t>(state.iterations(), 1), true);
  } else {
    std::vector<std::vector<uint8_t>> packets(seq->size());
    for (size_t k = 0; k < seq->size(); ++k) encode_one((*seq)[k], &packets[k]);
    // Restart the cycle on an IDR, as the codec benchmark does (its own encoder's frame 0).
    const AVCodec* codec = avcodec_find_decoder_by_name(v.decoder);
    AVCodecContext* dec = avcodec_alloc_context3(codec);
    dec->thread_count = 1;
    dec->flags |= AV_CODEC_FLAG_LOW_DELAY;
    avcodec_open2(dec, codec, nullptr);
    AVFrame* out = av_frame_alloc();
    std::vector<uint8_t> rgb(size_t(kWidth) * kHeight * 3 + 64);
    for (auto _ : state) {
      const auto& p = packets[i++ % packets.size()];
      av_new_packet(pkt, int(p.size()));
      std::memcpy(pkt->data, p.data(), p.size());
      avcodec_send_packet(dec, pkt);
      av_packet_unref(pkt);
      if (avcodec_receive_frame(dec, out) == 0) {
        if (colour) {
          uint8_t* dst[1] = {rgb.data()};
          const int stride[1] = {kWidth * 3};
          sws_scale(to_rgb, out->data, out->linesize, 0, kHeight, dst, stride);
        }
        av_frame_unref(out);
      }
    }
    set_counters(state, (*seq)[0].bytes.size(), coded / seq->size(), false);
    av_frame_free(&out);
    avcodec_free_context(&dec);
  }
  av_packet_free(&pkt);
  av_frame_free(&frame);
  sws_freeContext(to_yuv);
  sws_freeContext(to_rgb);
  avcodec_free_context(&enc);
}

// ---- ceiling / ours table

class RatioReporter : public benchmark::ConsoleReporter {
 public:
  void ReportRuns(const std::vector<Run>& runs) override {
    ConsoleReporter::ReportRuns(runs);
    for (const Run& r : runs) {
      if (r.error_occurred) continue;
      if (r.run_type == Run::RT_Aggregate && r.aggregate_name != "median") continue;
      std::string name = r.run_name.function_name;
      // CPU time of the benchmark thread (of the process where the library works in threads
      // of its own: hevc encoding): the codecs are single-threaded, and on a shared machine
      // wall time mostly measures the neighbours.
      times_[name] = r.GetAdjustedCPUTime();
    }
  }
  void Finalize() override {
    ConsoleReporter::Finalize();
    std::printf("\n%-44s %12s %12s %8s\n", "case (ceiling / ours, ms per frame)", "ours", "ceiling", "ratio");
    for (const auto& [name, t] : times_) {
      const auto c = times_.find(name + "/ceiling");
      if (c == times_.end()) continue;
      std::printf("%-44s %12.3f %12.3f %7.0f%%\n", name.c_str(), t, c->second, 100.0 * c->second / t);
    }
  }

 private:
  std::map<std::string, double> times_;
};

// What the delta codec saves over zstd on a panning camera at 720p (bytes per frame, mean of
// 6 frames incl. the keyframe). Smooth AO and the bitmask pan over one wider frame (cropped,
// so the scene is identical); noisy AO is regenerated per frame (new noise every frame).
void report_delta() {
  std::printf("delta (previous frame, no reprojection) vs zstd level 1, 1280x720, 6 frames each:\n");
  const int frames = 6;
  for (int pan : {0, 1, 2, 4}) {
    const int wide = kWidth + pan * (frames - 1);
    const test::SyntheticView big{wide, kHeight};
    const PassBuffer ao = test::make_smooth_ao(big), vis = test::make_hard_visibility(big, 4);
    std::vector<PassBuffer> ao_seq, vis_seq, noisy_seq;
    for (int f = 0; f < frames; ++f) {
      for (auto [src, seq] : {std::pair{&ao, &ao_seq}, {&vis, &vis_seq}}) {
        PassBuffer crop{src->desc, {}};
        crop.desc.width = kWidth;
        const size_t bpp = src->desc.byte_size() / (size_t(wide) * kHeight);
        for (int y = 0; y < kHeight; ++y) {
          const uint8_t* row = src->bytes.data() + (size_t(y) * wide + size_t(pan * f)) * bpp;
          crop.bytes.insert(crop.bytes.end(), row, row + size_t(kWidth) * bpp);
        }
        seq->push_back(std::move(crop));
      }
      if (pan == 0 || pan == 2)
        noisy_seq.push_back(test::make_noisy_ao({kWidth, kHeight, double(pan * f), 0.0, uint32_t(f)}, 8));
    }
    for (auto [label, seq] : {std::pair{"smooth_ao", &ao_seq}, {"hard_vis4", &vis_seq}, {"noisy_ao8", &noisy_seq}}) {
      if (seq->empty()) continue;
      double sizes[2] = {0, 0};
      const char* names[2] = {"zstd", "delta"};
      for (int k = 0; k < 2; ++k) {
        auto codec = registries().codecs.create(names[k], json::object());
        std::vector<uint8_t> out;
        for (const PassBuffer& b : *seq) {
          codec->encode(b, {}, out);
          sizes[k] += double(out.size()) / double(seq->size());
        }
      }
      std::printf("  pan %d px/frame %-10s zstd %9.0f B/frame  delta %9.0f B/frame  (%3.0f%%)\n", pan, label, sizes[0],
                  sizes[1], 100.0 * sizes[1] / sizes[0]);
    }
  }
  std::printf("\n");
}

void register_all() {
  const Buffers& b = buffers();
  static std::deque<std::vector<PassBuffer>> singles;  // stable addresses
  auto one = [&](const PassBuffer& p) {
    singles.push_back({p});
    return &singles.back();
  };
  struct Input {
    const char* name;
    const std::vector<PassBuffer>* seq;
    const char* layout;
  };
  const std::vector<Input> inputs{{"noisy_ao8", one(b.noisy_ao8), "planes"},
                                  {"smooth_ao", one(b.smooth_ao), "planes"},
                                  {"hard_vis4_planes", one(b.hard_vis4), "planes"},
                                  {"hard_vis4_interleaved", one(b.hard_vis4), "interleaved"},
                                  {"soft_vis4", one(b.soft_vis4), "planes"}};
  for (const char* codec : {"lz4", "zstd"})
    for (const Input& in : inputs)
      for (bool encode : {true, false}) {
        const std::string name = std::string(encode ? "encode/" : "decode/") + codec + "/" + in.name;
        const json params{{"layout", in.layout}};
        const VisibilityLayout layout = parse_visibility_layout(in.layout);
        const PassBuffer* buffer = &(*in.seq)[0];
        benchmark::RegisterBenchmark(name.c_str(), [=](benchmark::State& s) {
          encode ? bench_encode(s, codec, params, in.seq) : bench_decode(s, codec, params, in.seq);
        })->Unit(benchmark::kMillisecond);
        benchmark::RegisterBenchmark((name + "/ceiling").c_str(), [=](benchmark::State& s) {
          std::string(codec) == "lz4" ? ceiling_lz4(s, buffer, layout, encode)
                                      : ceiling_zstd(s, buffer, layout, encode);
        })->Unit(benchmark::kMillisecond);
      }
  for (const BareVideo& v : kBareVideos)
    for (auto [label, seq] : {std::pair{"smooth_ao_pan", &b.ao_seq}, {"colour_pan", &b.colour_seq}})
      for (bool encode : {true, false}) {
        const std::string name =
            std::string(encode ? "encode/" : "decode/") + (v.label ? v.label : v.codec) + "/" + label;
        const char* codec = v.codec;
        const json params = json::parse(v.params);
        // x265 encodes in threads of its own (a frame-encoder thread and its pool), so the
        // benchmark thread's CPU time misses its work: hevc encoding is timed in the process's
        // CPU time (all threads; the benchmark runs nothing else meanwhile).
        const bool process_cpu = encode && std::string(codec) == "hevc";
        auto* ours = benchmark::RegisterBenchmark(name.c_str(), [=](benchmark::State& s) {
          encode ? bench_encode(s, codec, params, seq) : bench_decode(s, codec, params, seq);
        });
        auto* ceiling = benchmark::RegisterBenchmark(
            (name + "/ceiling").c_str(), [=, &v](benchmark::State& s) { ceiling_video(s, v, seq, encode); });
        for (auto* b : {ours, ceiling}) {
          b->Unit(benchmark::kMillisecond);
          if (process_cpu) b->MeasureProcessCPUTime();
        }
      }
  // Delta on a static view (the best case) and zstd on the same frames, for the record.
  benchmark::RegisterBenchmark("encode/delta/smooth_ao_static", [seq = one(b.smooth_ao)](benchmark::State& s) {
    bench_encode(s, "delta", json::object(), seq);
  })->Unit(benchmark::kMillisecond);
}

}  // namespace
}  // namespace dhr

int main(int argc, char** argv) {
  av_log_set_level(AV_LOG_ERROR);
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  dhr::report_delta();
  dhr::register_all();
  dhr::RatioReporter reporter;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  benchmark::Shutdown();
  return 0;
}
