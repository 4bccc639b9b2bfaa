// hevc: H.265/HEVC video (ITU-T H.265) through libavcodec's libx265 encoder and its native
// HEVC decoder, on the shared libavcodec layer (backends/codec/av_video.h: pictures, full-range
// mapping of count planes, keyframes, rate control). Carries colour (4:2:0) and AO/soft-
// visibility planes (x265 takes GRAY8 here: 4:0:0, RExt profile), lossy or lossless
// (x265 lossless=1: transform and quantisation bypassed); bitmasks and lossless colour are
// refused as h264 refuses them.
//
// x265 settings: tune=zerolatency (no B-frames, no lookahead, one frame thread), scene cut
// off, closed GOP, forced keyframes are IDR pictures, VPS/SPS/PPS repeated before every IDR,
// no encoder-info SEI. Threads: a pool of `threads` x265 workers with wavefront parallel
// processing always on (pools=none would switch it off and change the bitstream) and one frame
// thread, so the bytes do not depend on `threads` (tests/backends/test_codecs.cpp checks 1 against 4).
//
// Parameters (the shared ones: av_video_params):
//   rate_control  crf | bitrate | lossless   lossless = x265 lossless=1           default crf
//   crf           0..51                      constant rate factor (crf mode)      default 23
//   bitrate_kbps  1..1000000                 target (bitrate mode; VBV max = target, buffer 1 s)
//   fps           1..1000                    frame rate the bitrate refers to     default 60
//   gop           1..100000                  keyframe (IDR) interval in frames    default 60
//   threads       1..16                      x265 pool threads (bytes independent) default 1
// Pictures smaller than 16x16 are padded to 16 (x265 refuses smaller ones).
//   preset        ultrafast..veryslow        x265 preset                          default ultrafast
// Example: {"name": "hevc", "params": {"crf": 23, "preset": "ultrafast"}}
#include "backends/codec/av_video.h"

namespace dhr {

CodecEntry make_hevc_codec() {
  std::vector<ParamSpec> params = av_video_params("x265", 23, 51, "x265 lossless=1", "the bytes do not depend on it");
  params.push_back(x26x_preset_param("x265"));
  return {
      "hevc",
      "H.265/HEVC (libx265 via libavcodec), zerolatency, VPS/SPS/PPS in-band; AO/soft-visibility as gray, colour as "
      "4:2:0",
      std::move(params), [](const Params& p) {
        AvVideoFormat f;
        f.name = "hevc";
        f.encoder = "libx265";
        f.decoder = "hevc";
        f.install_hint = "install libavcodec with x265 support";
        f.min_side = 16;
        f.stream_format = "hevc";
        f.configure_encoder = [preset = p.get_string("preset")](const AvVideoSettings& s, AvOptions& o) {
          std::string x265_params =
              "log-level=error:scenecut=0:open-gop=0:repeat-headers=1:info=0:frame-threads=1:rc-lookahead=0:"
              "bframes=0";
          x265_params += fmt::format(":wpp=1:pools={}", s.threads);
          if (s.rate_control == AvRateControl::Lossless) x265_params += ":lossless=1";
          o.set("preset", preset);
          o.set("tune", "zerolatency");
          o.set("forced-idr", "1");
          o.set("x265-params", x265_params);
        };
        return make_av_video_codec(std::move(f), av_video_settings(p));
      }};
}

}  // namespace dhr

// x265 3.5 (Debian 12) leaks about 1.9 KB per encoder it opens (FrameFilter::init, and the
// strings x265_param_parse and x265_copy_params duplicate); make_fuzz_corpus under ASan showed
// it. LeakSanitizer reads this hook, when the program is built with it, so that the sanitizer
// and fuzz runs (scripts/test.sh, scripts/fuzz.sh) report our leaks and not the library's.
extern "C" const char* __lsan_default_suppressions();
extern "C" const char* __lsan_default_suppressions() { return "leak:libx265.so\n"; }
