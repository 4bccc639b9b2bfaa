// av1: AV1 video (AOMedia) through libavcodec's libaom-av1 encoder and the dav1d decoder
// (libdav1d), on the shared libavcodec layer (backends/codec/av_video.h: pictures, full-range
// mapping of count planes, keyframes, rate control). Carries colour (4:2:0) and AO/soft-
// visibility planes (libaom takes GRAY8 here: monochrome sequence), lossy or lossless (libaom
// lossless=1); bitmasks and lossless colour are refused as h264 refuses them. Each encode()
// returns one temporal unit of low-overhead OBUs; the sequence header precedes every key
// frame. SVT-AV1 is not used: this build's libsvtav1 takes no gray input.
//
// libaom settings: usage=realtime (lossless: good, see below), lag-in-frames=0 (each frame's bits come out for that
// frame), keyframes exactly every `gop` frames (kf_min_dist = kf_max_dist) or when forced.
// dav1d runs with one thread and a frame delay of one (libavcodec's low-delay flag).
//
// Parameters (the shared ones: av_video_params):
//   rate_control  crf | bitrate | lossless   lossless = libaom lossless=1         default crf
//   crf           0..63                      constant quality level (crf mode)    default 35
//   bitrate_kbps  1..1000000                 target (bitrate mode)                default 10000
//   fps           1..1000                    frame rate the bitrate refers to     default 60
//   gop           1..100000                  keyframe interval in frames          default 60
//   threads       1..16                      libaom threads (row-mt off: bytes independent) default 1
//   cpu_used      0..8                       libaom speed (higher is faster)      default 8
// Example: {"name": "av1", "params": {"crf": 35, "cpu_used": 8}}
#include "backends/codec/av_video.h"

namespace dhr {

CodecEntry make_av1_codec() {
  std::vector<ParamSpec> params =
      av_video_params("libaom", 35, 63, "libaom lossless=1", "row-mt off: the bytes do not depend on it");
  params.push_back(ParamSpec::integer("cpu_used", 8, 0, 8, "libaom speed/quality trade-off: higher is faster"));
  return {"av1",
          "AV1 (libaom-av1 encoder, dav1d decoder, via libavcodec), realtime, no lookahead; AO/soft-visibility as "
          "monochrome, colour as 4:2:0",
          std::move(params), [](const Params& p) {
            AvVideoFormat f;
            f.name = "av1";
            f.encoder = "libaom-av1";
            f.decoder = "libdav1d";
            f.install_hint = "install libavcodec with libaom and libdav1d support";
            f.stream_format = "ivf";
            f.configure_encoder = [cpu_used = p.get_int("cpu_used")](const AvVideoSettings& s, AvOptions& o) {
              o.context()->keyint_min = s.gop;
              o.set("usage", s.rate_control == AvRateControl::Lossless ? "good" : "realtime");
              o.set("cpu-used", std::to_string(cpu_used));
              o.set("lag-in-frames", "0");
              o.set("row-mt", "0");
              // A capped CRF: libaom has no VBV in its constant-quality mode; with a target bitrate
              // beside the crf, libavcodec runs it as constrained quality (CQ), max_kbps the target.
              if (s.rate_control == AvRateControl::Crf && s.max_kbps > 0)
                o.context()->bit_rate = int64_t(s.max_kbps) * 1000;
              if (s.rate_control == AvRateControl::Lossless) {
                // In realtime mode lossless=1 left inter frames lossy (tests/backends/test_codecs.cpp found it):
                // lossless runs in good-quality mode with the quantiser pinned at 0.
                o.context()->qmin = 0;
                o.context()->qmax = 0;
                o.set("crf", "0");
                o.set("aom-params", "lossless=1");
              }
            };
            return make_av_video_codec(std::move(f), av_video_settings(p));
          }};
}

}  // namespace dhr
