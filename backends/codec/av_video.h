// The libavcodec video layer that the h264, hevc and av1 codecs share (docs/adding-a-backend.md):
// one stateful Codec that drives a libavcodec encoder and decoder, maps buffers to pictures,
// and applies the rate control common to them. A video codec file only names its encoder and
// decoder, sets the encoder's own options (preset, tuning, lossless switch) and lists its
// parameters.
//
// Mapping of buffers to pictures:
//   Ao              one gray picture (4:0:0 when the encoder offers GRAY8, else 4:2:0 with
//                   constant chroma 128); values are luma samples, full range.
//   SoftVisibility  the light planes stacked top to bottom in one gray picture (w x h*lights).
//   Colour          RGB8 -> YUV 4:2:0 (BT.601, limited range) with libswscale, and back; 4:4:4
//                   (full-resolution chroma) where the parameter chroma is "444".
// Full-range mapping (lossy rate control only): an Ao/SoftVisibility value v of 0..full_scale
// is coded as round(v * 255 / full_scale) and decoded back as round(u * full_scale / 255), so a
// count plane (0..8 soft-visibility samples, 0..N AO rays) uses the whole sample range and the
// quantiser treats it as it treats a 0..255 plane. Without coding loss the mapping returns every
// value exactly; lossless rate control does not map (its bytes are those of the plain values).
// Decoded values above full_scale are clamped to full_scale.
// Odd sizes are padded to even (and to the encoder's smallest side) by repeating the last
// column/row, and cropped on decode.
//
// Every encode() returns one access unit; no global header is set, so stream headers (SPS/PPS,
// VPS, the AV1 sequence header) precede every keyframe and a keyframe decodes alone with any
// fresh decoder. Keyframes come every `gop` frames or when EncodeOptions::force_keyframe asks.
// No B-frames and no lookahead: each frame's bits come out of encode() for that frame. A new
// buffer description starts a new stream; reset() drops encoder and decoder.
#pragma once

#include "core/backend/backend.h"

extern "C" {
#include <libavcodec/avcodec.h>
}

#include <algorithm>
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace dhr {

enum class AvRateControl { Crf, Bitrate, Lossless };

// The parameters every libavcodec video codec has (av_video_params lists them).
struct AvVideoSettings {
  AvRateControl rate_control = AvRateControl::Crf;
  int crf = 23;
  int bitrate_kbps = 10000;
  int fps = 60;
  int gop = 60;
  int threads = 1;
  bool chroma444 = false;  // colour pictures as YUV 4:4:4 (else 4:2:0)
  // The VBV: a buffer of vbv_buffer_ms at the peak rate (bitrate mode: the target; crf mode:
  // max_kbps, a capped CRF; 0: uncapped) bounds how far one frame may pass the average.
  int vbv_buffer_ms = 1000;
  int max_kbps = 0;
  // Periodic intra refresh instead of keyframes (h264; x265's did not heal): a column of intra blocks sweeps
  // the picture once every `gop` frames; the decoder goes on after a loss and the picture heals
  // within one sweep (Codec::heals_after_loss). Keyframes come only when forced.
  bool intra_refresh = false;
};

// rate_control, crf (0..crf_max, default crf_default), bitrate_kbps, fps, gop, threads, chroma,
// vbv_buffer_ms, max_kbps; the
// notes say how the encoder codes losslessly and what its thread count does to the bytes.
std::vector<ParamSpec> av_video_params(const std::string& encoder_label, int crf_default, int crf_max,
                                       const std::string& lossless_note, const std::string& threads_note);
AvVideoSettings av_video_settings(const Params& p);
// "intra_refresh": periodic intra refresh (h264: its configure_encoder sets the encoder's option).
ParamSpec intra_refresh_param(const std::string& encoder_label);
// "preset": the speed presets x264 and x265 share, ultrafast..veryslow (default ultrafast).
ParamSpec x26x_preset_param(const std::string& encoder_label);

// Sets private options of an encoder context; fails naming the codec, option and value.
class AvOptions {
 public:
  AvOptions(const std::string& codec, AVCodecContext* context) : codec_(codec), context_(context) {}
  void set(const char* key, const std::string& value);
  AVCodecContext* context() const { return context_; }

 private:
  const std::string& codec_;
  AVCodecContext* context_;
};

struct AvVideoFormat {
  std::string name;           // the registry name: prefixes every message ("h264")
  std::string encoder;        // libavcodec encoder name ("libx264")
  std::string decoder;        // libavcodec decoder name ("h264")
  std::string install_hint;   // said when the encoder or decoder is missing
  int min_side = 2;           // smaller pictures are padded to this width/height (even)
  std::string stream_format;  // Codec::stream_format(): "h264", "hevc", "ivf"
  // The encoder follows a bitrate changed between frames (bitrate mode): Codec::takes_target_kbps.
  bool retargets_bitrate = false;
  // Sets the encoder's own options on a context whose size, pixel format, time base, gop,
  // threads, colour description and (bitrate mode) rates are set; the crf option is set by
  // the layer in crf mode. Lossless mode must be switched on here.
  std::function<void(const AvVideoSettings&, AvOptions&)> configure_encoder;
  // The encoder may take GRAY8 pictures (where it lists them) for AO and soft visibility; false:
  // they go as 4:2:0 with constant chroma.
  bool gray_allowed = true;
  // Decoder private options (name, value), e.g. dav1d's frame delay.
  std::vector<std::pair<std::string, std::string>> decoder_options;
};

// Lookup tables of the full-range mapping above for one full_scale: to_picture[v] =
// round(v * 255 / full_scale), from_picture[u] = round(u * full_scale / 255). With map = false
// both are the identity up to full_scale (values above it clamp to it).
struct FullRangeMap {
  std::array<uint8_t, 256> to_picture{}, from_picture{};
  FullRangeMap(int full_scale, bool map) {
    const int fs = std::clamp(full_scale, 1, 255);
    for (int v = 0; v < 256; ++v) {
      to_picture[size_t(v)] = map ? uint8_t((std::min(v, fs) * 255 + fs / 2) / fs) : uint8_t(v);
      from_picture[size_t(v)] = map ? uint8_t((v * fs + 127) / 255) : uint8_t(std::min(v, fs));
    }
  }
};

std::unique_ptr<Codec> make_av_video_codec(AvVideoFormat format, AvVideoSettings settings);

// Is `format` among `encoder`'s input formats (unknown encoder: false)?
bool av_encoder_takes(const char* encoder, AVPixelFormat format);

}  // namespace dhr
