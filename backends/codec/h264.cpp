// h264: H.264/AVC video (ITU-T H.264) through libavcodec's libx264 encoder and its native
// H.264 decoder, on the shared libavcodec layer (backends/codec/av_video.h: pictures, full-range
// mapping of count planes, keyframes, rate control). This is what cloud gaming ships, so it is
// the fair codec for the remote-rendering baseline's colour frames (docs/architecture.md, "The
// frame loop"); for the DHR passes it carries 8-bit AO and soft-visibility planes, lossy or
// lossless. Bitmasks are refused: a lossy codec turns bits into wrong bits, and x264's lossless
// mode would code 1-bit data as 8-bit samples.
//
// x264 settings: tune=zerolatency (no B-frames, no lookahead), scene-cut detection off (so
// keyframes are predictable), forced keyframes are IDR pictures, SPS/PPS precede every IDR.
// x264 logs errors only: its warnings in bitrate mode (a VBV underflow, "max bitrate less than
// average" when libavcodec retargets the rate between frames) came every few frames; the log
// level does not change the bytes (checked with one thread: identical streams at log 0 and 1).
//
// Notes measured on this build (libavcodec 59.37, x264 0.164; tests/backends/test_codecs.cpp):
// - libx264 takes GRAY8 here, so AO goes as true 4:0:0 (4:2:0 with intra refresh: x264 crashes
//   on 4:0:0 with it); rate_control=lossless (qp 0, which x264 codes in the High 4:4:4
//   Predictive profile) returns AO and soft visibility bit-exactly. Colour is refused in lossless mode: 4:2:0 cannot return RGB exactly.
// - slice_max_size_bytes=1100 costs bytes: on a 720p smooth-AO pan at crf 23, 8.2 KB per
//   frame against 5.0 KB with one slice per picture (colour: 14.5 KB against 12.9 KB).
// - libavcodec's decoder warns "Possibly too many slices (n >= 32)" on pictures with more
//   than 32 slices; decoded quality (PSNR) was the same as with one slice, and lossless
//   pictures of several hundred slices decode bit-exactly.
//
// Parameters (the shared ones: av_video_params):
//   rate_control          crf | bitrate | lossless   lossless = qp 0                    default crf
//   crf                   0..51                      constant rate factor (crf mode)    default 23
//   bitrate_kbps          1..1000000                 target (bitrate mode: ABR, VBV max = target,
//                                                    VBV buffer = vbv_buffer_ms)        default 10000
//   vbv_buffer_ms         1..10000                   VBV buffer at the peak rate        default 1000
//   max_kbps              0..1000000                 crf mode: VBV peak (capped CRF)    default 0 (none)
//   chroma                420 | 444                  colour pictures' chroma            default 420
//   fps                   1..1000                    frame rate the bitrate refers to   default 60
//   gop                   1..100000                  keyframe (IDR) interval in frames  default 60
//   intra_refresh         true | false               periodic intra refresh over gop frames
//                                                    instead of IDR keyframes; the decoder
//                                                    goes on after a loss     default false
//   threads               1..16                      x264 threads (1: deterministic)    default 1
//   preset                ultrafast..veryslow        x264 preset                        default ultrafast
//   slice_max_size_bytes  0..100000                  x264 slice-max-size: each slice NAL at most this
//                                                    big, so a slice fits one 1200-byte packet
//                                                    payload; 0 = one slice per picture default 1100
// Example: {"name": "h264", "params": {"rate_control": "crf", "crf": 23, "preset": "ultrafast"}}
#include "backends/codec/av_video.h"

namespace dhr {

CodecEntry make_h264_codec() {
  std::vector<ParamSpec> params = av_video_params("x264", 23, 51, "qp 0", "1 gives deterministic output");
  params.push_back(x26x_preset_param("x264"));
  params.push_back(intra_refresh_param("x264"));
  params.push_back(ParamSpec::integer("slice_max_size_bytes", 1100, 0, 100000,
                                      "largest slice NAL in bytes (fits a 1200-byte packet payload); 0 = no limit"));
  return {"h264",
          "H.264 (libx264 via libavcodec), zerolatency, SPS/PPS in-band; AO/soft-visibility as gray, colour as 4:2:0",
          std::move(params), [](const Params& p) {
            AvVideoFormat f;
            f.name = "h264";
            f.encoder = "libx264";
            f.decoder = "h264";
            f.install_hint = "install libavcodec with x264 support";
            f.stream_format = "h264";
            f.retargets_bitrate = true;  // libavcodec's libx264 wrapper reconfigures x264 when bit_rate changes
            // x264 0.164 crashes (x264_8_trellis_coefn) on 4:0:0 pictures with intra refresh, at ultrafast
            // and fast (`ffmpeg -f lavfi -i testsrc -pix_fmt gray -c:v libx264 -intra-refresh 1`): those go
            // as 4:2:0 with constant chroma.
            f.gray_allowed = !p.get_bool("intra_refresh");
            f.configure_encoder = [preset = p.get_string("preset"), slice_max = p.get_int("slice_max_size_bytes")](
                                      const AvVideoSettings& s, AvOptions& o) {
              std::string x264_params = "scenecut=0:log=0";
              if (slice_max > 0) x264_params += fmt::format(":slice-max-size={}", slice_max);
              o.set("preset", preset);
              o.set("tune", "zerolatency");
              o.set("forced-idr", "1");
              if (s.intra_refresh) o.set("intra-refresh", "1");
              if (s.rate_control == AvRateControl::Lossless) o.set("qp", "0");
              o.set("x264-params", x264_params);
            };
            return make_av_video_codec(std::move(f), av_video_settings(p));
          }};
}

}  // namespace dhr
