// h264: H.264/AVC video (ITU-T H.264) through libavcodec's libx264 encoder and its native
// H.264 decoder. This is what cloud gaming ships, so it is the fair codec for the remote-
// rendering baseline's colour frames (design.md); for the DHR passes it carries 8-bit AO and
// soft-visibility planes, lossy or lossless. Bitmasks are refused: a lossy codec turns bits
// into wrong bits, and x264's lossless mode would code 1-bit data as 8-bit samples.
//
// Mapping of buffers to pictures:
//   Ao              one gray picture (x264 4:0:0 when the build offers GRAY8, else 4:2:0 with
//                   constant chroma 128); values are luma samples, full range.
//   SoftVisibility  the light planes stacked top to bottom in one gray picture (w x h*lights).
//   Colour          RGB8 -> YUV 4:2:0 (BT.601, limited range) with libswscale, and back.
// Odd sizes are padded to even by repeating the last column/row and cropped on decode.
// Lossy output values above an Ao/SoftVisibility full_scale are clamped to full_scale.
//
// The codec is stateful: one encoder and one decoder live in the object (P-frames reference
// earlier frames); reset() drops both. Every encode() returns one access unit as an Annex-B
// byte stream; no global header is set, so SPS/PPS precede every IDR picture and the bytes of
// a keyframe decode alone with any fresh H.264 decoder. Keyframes come every `gop` frames or
// when EncodeOptions::force_keyframe asks (an IDR); x264's scene-cut detection is off so that
// keyframes are predictable. tune=zerolatency (no B-frames, no lookahead): each frame's bits
// come out of encode() for that frame. A new buffer description starts a new stream.
//
// Notes measured on this build (libavcodec 59.37, x264 0.164; tests/test_codecs.cpp):
// - libx264 takes GRAY8 here, so AO goes as true 4:0:0; rate_control=lossless (qp 0, which
//   x264 codes in the High 4:4:4 Predictive profile) returns AO and soft visibility
//   bit-exactly. Colour is refused in lossless mode: 4:2:0 cannot return RGB exactly.
// - slice_max_size_bytes=1100 costs bytes: on a 720p smooth-AO pan at crf 23, 8.2 KB per
//   frame against 5.0 KB with one slice per picture (colour: 14.5 KB against 12.9 KB).
// - libavcodec's decoder warns "Possibly too many slices (n >= 32)" on pictures with more
//   than 32 slices; decoded quality (PSNR) was the same as with one slice, and lossless
//   pictures of several hundred slices decode bit-exactly.
//
// Parameters:
//   rate_control          crf | bitrate | lossless   x264 rate control; lossless = qp 0  default crf
//   crf                   0..51                      constant rate factor (crf mode)    default 23
//   bitrate_kbps          1..1000000                 target (bitrate mode: ABR, VBV max = target,
//                                                    VBV buffer = 1 s)                  default 10000
//   fps                   1..1000                    frame rate the bitrate refers to   default 60
//   preset                ultrafast..veryslow        x264 preset                        default ultrafast
//   gop                   1..100000                  keyframe interval in frames        default 60
//   slice_max_size_bytes  0..100000                  x264 slice-max-size: each slice NAL at most this
//                                                    big, so a slice fits one 1200-byte packet
//                                                    payload; 0 = one slice per picture default 1100
//   threads               1..16                      x264 threads (1: deterministic)    default 1
// Example: {"name": "h264", "params": {"rate_control": "crf", "crf": 23, "preset": "ultrafast"}}
#include "core/backend.h"

extern "C" {
#include <libavcodec/avcodec.h>
#include <libavutil/imgutils.h>
#include <libavutil/opt.h>
#include <libswscale/swscale.h>
}

#include <algorithm>
#include <cstring>

namespace dhr {
namespace {

enum class RateControl { Crf, Bitrate, Lossless };

std::string av_error_text(int code) {
  char text[AV_ERROR_MAX_STRING_SIZE] = {};
  av_strerror(code, text, sizeof text);
  return text;
}

// Is GRAY8 among libx264's input formats in this libavcodec build?
bool encoder_takes_gray(const AVCodec* codec) {
  if (!codec->pix_fmts) return false;
  for (const AVPixelFormat* f = codec->pix_fmts; *f != AV_PIX_FMT_NONE; ++f)
    if (*f == AV_PIX_FMT_GRAY8) return true;
  return false;
}

// The picture a buffer is coded as: its size before and after padding to even.
struct Geometry {
  int width = 0, height = 0;       // data size (SoftVisibility: planes stacked)
  int padded_width = 0, padded_height = 0;
  bool colour = false;
};

Geometry geometry_of(const PassDesc& desc) {
  Geometry g;
  g.width = desc.width;
  g.height = desc.kind == PassKind::SoftVisibility ? desc.height * desc.channels : desc.height;
  g.padded_width = g.width + (g.width & 1);
  g.padded_height = g.height + (g.height & 1);
  g.colour = desc.kind == PassKind::Colour;
  return g;
}

class H264Codec final : public Codec {
 public:
  explicit H264Codec(const Params& p)
      : crf_(p.get_int("crf")),
        bitrate_kbps_(p.get_int("bitrate_kbps")),
        fps_(p.get_int("fps")),
        preset_(p.get_string("preset")),
        gop_(p.get_int("gop")),
        slice_max_size_bytes_(p.get_int("slice_max_size_bytes")),
        threads_(p.get_int("threads")) {
    const std::string rc = p.get_string("rate_control");
    rate_control_ = rc == "lossless" ? RateControl::Lossless : rc == "bitrate" ? RateControl::Bitrate : RateControl::Crf;
    encoder_ = avcodec_find_encoder_by_name("libx264");
    if (!encoder_) fail("h264: this libavcodec has no libx264 encoder (install libavcodec with x264 support)");
    decoder_ = avcodec_find_decoder(AV_CODEC_ID_H264);
    if (!decoder_) fail("h264: this libavcodec has no H.264 decoder");
    gray_ = encoder_takes_gray(encoder_);
    packet_ = av_packet_alloc();
    if (!packet_) fail("h264: out of memory");
  }
  ~H264Codec() override {
    reset();
    av_packet_free(&packet_);
  }
  H264Codec(const H264Codec&) = delete;
  H264Codec& operator=(const H264Codec&) = delete;

  bool lossless() const override { return rate_control_ == RateControl::Lossless; }
  bool stateful() const override { return true; }  // P-frames reference earlier frames

  std::string refuses(const PassDesc& desc) const override {
    if (std::string why = desc.validate(); !why.empty()) return "invalid buffer description: " + why;
    if (desc.kind == PassKind::Visibility)
      return "h264 does not carry bitmasks (lossy coding flips bits; lossless codes 1-bit data as 8-bit "
             "samples): use lz4 or zstd";
    if (desc.kind == PassKind::Colour && lossless())
      return "h264 lossless codes YUV 4:2:0, which cannot return RGB bit-exactly: use lossy h264, lz4 or zstd";
    if (desc.width == 0 || desc.height == 0) return "h264 has no empty pictures";
    const Geometry g = geometry_of(desc);
    if (g.padded_height > kMaxImageSide)
      return fmt::format("{} light planes of {} rows stack into a {}-row picture, above {}", desc.channels,
                         desc.height, g.padded_height, kMaxImageSide);
    return {};
  }

  void encode(const PassBuffer& in, const EncodeOptions& options, std::vector<uint8_t>& out) override {
    if (std::string why = refuses(in.desc); !why.empty()) fail("h264: cannot encode this buffer: {}", why);
    if (in.bytes.size() != in.desc.byte_size())
      fail("h264: a {}x{} {} buffer holds {} bytes, {} expected", in.desc.width, in.desc.height,
           pass_kind_name(in.desc.kind), in.bytes.size(), in.desc.byte_size());
    if (!enc_ || !(enc_desc_ == in.desc)) open_encoder(in.desc);
    fill_picture(in);
    frame_->pts = next_pts_++;
    frame_->pict_type = options.force_keyframe ? AV_PICTURE_TYPE_I : AV_PICTURE_TYPE_NONE;
    frame_->key_frame = options.force_keyframe ? 1 : 0;
    if (int r = avcodec_send_frame(enc_, frame_); r < 0) fail("h264: avcodec_send_frame failed: {}", av_error_text(r));
    out.clear();
    for (;;) {
      const int r = avcodec_receive_packet(enc_, packet_);
      if (r == AVERROR(EAGAIN)) break;
      if (r < 0) fail("h264: avcodec_receive_packet failed: {}", av_error_text(r));
      out.insert(out.end(), packet_->data, packet_->data + packet_->size);
      av_packet_unref(packet_);
    }
    // zerolatency has no lookahead: a frame that stays in the encoder is a configuration bug.
    if (out.empty()) fail("h264: libx264 returned no bits for frame {}", frame_->pts);
  }

  bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) override {
    if (std::string why = refuses(desc); !why.empty()) {
      error = "h264: " + why;
      return false;
    }
    if (in.empty()) {
      error = "h264: empty input";
      return false;
    }
    if (!dec_ && !open_decoder(error)) return false;
    // The decoder may read up to AV_INPUT_BUFFER_PADDING_SIZE bytes past the data.
    if (int r = av_new_packet(packet_, int(in.size())); r < 0) {
      error = "h264: out of memory for a packet";
      return false;
    }
    std::memcpy(packet_->data, in.data(), in.size());
    const int sent = avcodec_send_packet(dec_, packet_);
    av_packet_unref(packet_);
    if (sent < 0) {
      error = fmt::format("h264: corrupt bitstream: {}", av_error_text(sent));
      return false;
    }
    int r = avcodec_receive_frame(dec_, dec_frame_);
    if (r == AVERROR(EAGAIN)) {
      error = "h264: the bytes hold no displayable picture (a P-frame without its reference?)";
      return false;
    }
    if (r < 0) {
      error = fmt::format("h264: decoding failed: {}", av_error_text(r));
      return false;
    }
    // One encode() is one picture: more than one means foreign input.
    int extra = 0;
    while (avcodec_receive_frame(dec_, extra_frame_) == 0) {
      ++extra;
      av_frame_unref(extra_frame_);
    }
    bool ok = false;
    if (extra > 0)
      error = fmt::format("h264: the bytes hold {} pictures, one expected", extra + 1);
    else
      ok = picture_to_buffer(desc, out, error);
    av_frame_unref(dec_frame_);
    return ok;
  }

  void reset() override {
    avcodec_free_context(&enc_);
    avcodec_free_context(&dec_);
    av_frame_free(&frame_);
    av_frame_free(&dec_frame_);
    av_frame_free(&extra_frame_);
    av_frame_free(&rgb_);
    sws_freeContext(to_yuv_);
    sws_freeContext(to_rgb_);
    to_yuv_ = to_rgb_ = nullptr;
    enc_desc_ = PassDesc{};
    next_pts_ = 0;
  }

 private:
  void open_encoder(const PassDesc& desc) {
    enc_desc_ = PassDesc{};  // stays invalid if opening fails, so the next encode retries
    avcodec_free_context(&enc_);
    av_frame_free(&frame_);
    sws_freeContext(to_yuv_);
    to_yuv_ = nullptr;
    const Geometry g = geometry_of(desc);
    enc_ = avcodec_alloc_context3(encoder_);
    frame_ = av_frame_alloc();
    if (!enc_ || !frame_) fail("h264: out of memory");
    enc_->width = g.padded_width;
    enc_->height = g.padded_height;
    enc_->time_base = AVRational{1, fps_};
    enc_->framerate = AVRational{fps_, 1};
    enc_->pix_fmt = (!g.colour && gray_) ? AV_PIX_FMT_GRAY8 : AV_PIX_FMT_YUV420P;
    enc_->gop_size = gop_;
    enc_->max_b_frames = 0;
    enc_->thread_count = threads_;
    enc_->color_range = g.colour ? AVCOL_RANGE_MPEG : AVCOL_RANGE_JPEG;
    if (g.colour) {
      enc_->colorspace = AVCOL_SPC_SMPTE170M;
      enc_->color_primaries = AVCOL_PRI_SMPTE170M;
      enc_->color_trc = AVCOL_TRC_SMPTE170M;
    }
    std::string x264_params = "scenecut=0:log=1";
    if (slice_max_size_bytes_ > 0) x264_params += fmt::format(":slice-max-size={}", slice_max_size_bytes_);
    set_option("preset", preset_);
    set_option("tune", "zerolatency");
    set_option("forced-idr", "1");
    switch (rate_control_) {
      case RateControl::Crf: set_option("crf", std::to_string(crf_)); break;
      case RateControl::Lossless: set_option("qp", "0"); break;
      case RateControl::Bitrate:
        enc_->bit_rate = int64_t(bitrate_kbps_) * 1000;
        enc_->rc_max_rate = enc_->bit_rate;
        enc_->rc_buffer_size = int(std::min<int64_t>(enc_->bit_rate, INT32_MAX));
        break;
    }
    set_option("x264-params", x264_params);
    if (int r = avcodec_open2(enc_, encoder_, nullptr); r < 0)
      fail("h264: cannot open libx264 for a {}x{} picture: {}", g.padded_width, g.padded_height, av_error_text(r));
    frame_->format = enc_->pix_fmt;
    frame_->width = g.padded_width;
    frame_->height = g.padded_height;
    frame_->color_range = enc_->color_range;
    if (int r = av_frame_get_buffer(frame_, 0); r < 0) fail("h264: cannot allocate a picture: {}", av_error_text(r));
    if (g.colour) {
      to_yuv_ = sws_getContext(g.padded_width, g.padded_height, AV_PIX_FMT_RGB24, g.padded_width, g.padded_height,
                               AV_PIX_FMT_YUV420P, SWS_BILINEAR, nullptr, nullptr, nullptr);
      if (!to_yuv_) fail("h264: libswscale cannot convert RGB24 to YUV420P at {}x{}", g.padded_width, g.padded_height);
    }
    enc_desc_ = desc;
    next_pts_ = 0;
  }

  void set_option(const char* key, const std::string& value) {
    if (int r = av_opt_set(enc_->priv_data, key, value.c_str(), 0); r < 0)
      fail("h264: libx264 rejects option {}={}: {}", key, value, av_error_text(r));
  }

  bool open_decoder(std::string& error) {
    dec_ = avcodec_alloc_context3(decoder_);
    dec_frame_ = av_frame_alloc();
    extra_frame_ = av_frame_alloc();
    if (!dec_ || !dec_frame_ || !extra_frame_) fail("h264: out of memory");
    dec_->thread_count = 1;  // frame threads would delay output by a frame per thread
    dec_->flags |= AV_CODEC_FLAG_LOW_DELAY;
    // Fail on damaged slices instead of concealing them, so corruption is reported.
    dec_->err_recognition = AV_EF_EXPLODE | AV_EF_CAREFUL | AV_EF_BITSTREAM | AV_EF_BUFFER;
    if (int r = avcodec_open2(dec_, decoder_, nullptr); r < 0) {
      error = fmt::format("h264: cannot open the H.264 decoder: {}", av_error_text(r));
      avcodec_free_context(&dec_);
      return false;
    }
    return true;
  }

  // Writes the buffer into frame_ (padding by edge replication).
  void fill_picture(const PassBuffer& in) {
    if (int r = av_frame_make_writable(frame_); r < 0) fail("h264: cannot write a picture: {}", av_error_text(r));
    const Geometry g = geometry_of(in.desc);
    if (!g.colour) {
      for (int y = 0; y < g.padded_height; ++y) {
        const uint8_t* src = in.bytes.data() + size_t(std::min(y, g.height - 1)) * size_t(g.width);
        uint8_t* dst = frame_->data[0] + ptrdiff_t(y) * frame_->linesize[0];
        std::memcpy(dst, src, size_t(g.width));
        if (g.padded_width > g.width) dst[g.width] = src[g.width - 1];
      }
      if (frame_->format == AV_PIX_FMT_YUV420P)
        for (int c = 1; c <= 2; ++c)
          for (int y = 0; y < g.padded_height / 2; ++y)
            std::memset(frame_->data[c] + ptrdiff_t(y) * frame_->linesize[c], 128, size_t(g.padded_width / 2));
      return;
    }
    // libswscale's vector code may read and write past the end of a row, so it only ever
    // sees AVFrame buffers (aligned and padded), never the caller's vector.
    AVFrame* rgb = rgb_frame(g);
    for (int y = 0; y < g.padded_height; ++y) {
      const uint8_t* src = in.bytes.data() + size_t(std::min(y, g.height - 1)) * size_t(g.width) * 3;
      uint8_t* dst = rgb->data[0] + ptrdiff_t(y) * rgb->linesize[0];
      std::memcpy(dst, src, size_t(g.width) * 3);
      if (g.padded_width > g.width) std::memcpy(dst + size_t(g.width) * 3, src + size_t(g.width - 1) * 3, 3);
    }
    sws_scale(to_yuv_, rgb->data, rgb->linesize, 0, g.padded_height, frame_->data, frame_->linesize);
  }

  // An RGB24 picture of the padded size, reallocated when the size changes.
  AVFrame* rgb_frame(const Geometry& g) {
    if (rgb_ && (rgb_->width != g.padded_width || rgb_->height != g.padded_height)) av_frame_free(&rgb_);
    if (!rgb_) {
      rgb_ = av_frame_alloc();
      if (!rgb_) fail("h264: out of memory");
      rgb_->format = AV_PIX_FMT_RGB24;
      rgb_->width = g.padded_width;
      rgb_->height = g.padded_height;
      if (int r = av_frame_get_buffer(rgb_, 0); r < 0) fail("h264: cannot allocate a picture: {}", av_error_text(r));
    }
    return rgb_;
  }

  // Checks dec_frame_ against `desc` and crops it into `out`.
  bool picture_to_buffer(const PassDesc& desc, PassBuffer& out, std::string& error) {
    const Geometry g = geometry_of(desc);
    const AVFrame* f = dec_frame_;
    if (f->width != g.padded_width || f->height != g.padded_height) {
      error = fmt::format("h264: decoded a {}x{} picture, {}x{} expected for a {}x{} {} buffer", f->width, f->height,
                          g.padded_width, g.padded_height, desc.width, desc.height, pass_kind_name(desc.kind));
      return false;
    }
    if ((f->flags & AV_FRAME_FLAG_CORRUPT) || f->decode_error_flags) {
      error = "h264: the decoder reports a damaged picture";
      return false;
    }
    const auto format = AVPixelFormat(f->format);
    const bool yuv420 = format == AV_PIX_FMT_YUV420P || format == AV_PIX_FMT_YUVJ420P;
    if (!(yuv420 || (!g.colour && format == AV_PIX_FMT_GRAY8))) {
      error = fmt::format("h264: decoded pixel format {} is not 8-bit 4:2:0 or gray", int(format));
      return false;
    }
    out.desc = desc;
    out.bytes.resize(desc.byte_size());
    if (!g.colour) {
      const uint8_t limit = uint8_t(desc.full_scale);
      for (int y = 0; y < g.height; ++y) {
        const uint8_t* src = f->data[0] + ptrdiff_t(y) * f->linesize[0];
        uint8_t* dst = out.bytes.data() + size_t(y) * size_t(g.width);
        for (int x = 0; x < g.width; ++x) dst[x] = std::min(src[x], limit);
      }
      return true;
    }
    // Returns the same context while the size stays the same.
    to_rgb_ = sws_getCachedContext(to_rgb_, g.padded_width, g.padded_height, AV_PIX_FMT_YUV420P, g.padded_width,
                                   g.padded_height, AV_PIX_FMT_RGB24, SWS_BILINEAR, nullptr, nullptr, nullptr);
    if (!to_rgb_) {
      error = "h264: libswscale cannot convert YUV420P to RGB24";
      return false;
    }
    AVFrame* rgb = rgb_frame(g);
    sws_scale(to_rgb_, f->data, f->linesize, 0, g.padded_height, rgb->data, rgb->linesize);
    for (int y = 0; y < g.height; ++y)
      std::memcpy(out.bytes.data() + size_t(y) * size_t(g.width) * 3, rgb->data[0] + ptrdiff_t(y) * rgb->linesize[0],
                  size_t(g.width) * 3);
    return true;
  }

  RateControl rate_control_ = RateControl::Crf;
  int crf_;
  int bitrate_kbps_;
  int fps_;
  std::string preset_;
  int gop_;
  int slice_max_size_bytes_;
  int threads_;

  const AVCodec* encoder_ = nullptr;
  const AVCodec* decoder_ = nullptr;
  bool gray_ = false;
  AVCodecContext* enc_ = nullptr;
  AVCodecContext* dec_ = nullptr;
  AVFrame* frame_ = nullptr;
  AVFrame* dec_frame_ = nullptr;
  AVFrame* extra_frame_ = nullptr;
  AVPacket* packet_ = nullptr;
  SwsContext* to_yuv_ = nullptr;
  SwsContext* to_rgb_ = nullptr;
  PassDesc enc_desc_{};
  int64_t next_pts_ = 0;
  AVFrame* rgb_ = nullptr;  // RGB24 picture of the padded size (colour only)
};

}  // namespace

CodecEntry make_h264_codec() {
  return {"h264",
          "H.264 (libx264 via libavcodec), zerolatency, SPS/PPS in-band; AO/soft-visibility as gray, colour as 4:2:0",
          {ParamSpec::choice("rate_control", "crf", {"crf", "bitrate", "lossless"},
                             "x264 rate control: constant rate factor, target bitrate, or lossless (qp 0)"),
           ParamSpec::integer("crf", 23, 0, 51, "constant rate factor (crf mode): lower is better quality"),
           ParamSpec::integer("bitrate_kbps", 10000, 1, 1000000, "target bitrate in kbit/s (bitrate mode)"),
           ParamSpec::integer("fps", 60, 1, 1000, "frame rate the bitrate refers to (bitrate mode)"),
           ParamSpec::choice("preset", "ultrafast",
                             {"ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower",
                              "veryslow"},
                             "x264 speed preset"),
           ParamSpec::integer("gop", 60, 1, 100000, "keyframe (IDR) interval in frames"),
           ParamSpec::integer("slice_max_size_bytes", 1100, 0, 100000,
                              "largest slice NAL in bytes (fits a 1200-byte packet payload); 0 = no limit"),
           ParamSpec::integer("threads", 1, 1, 16, "x264 threads (1 gives deterministic output)")},
          [](const Params& p) { return std::make_unique<H264Codec>(p); }};
}

}  // namespace dhr
