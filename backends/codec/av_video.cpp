// The libavcodec video layer of h264, hevc and av1: see av_video.h.
#include "backends/codec/av_video.h"

extern "C" {
#include <libavutil/imgutils.h>
#include <libavutil/opt.h>
#include <libavutil/pixdesc.h>
#include <libswscale/swscale.h>
}

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>

namespace dhr {
namespace {

std::string av_error_text(int code) {
  char text[AV_ERROR_MAX_STRING_SIZE] = {};
  av_strerror(code, text, sizeof text);
  return text;
}

class AvVideoCodec final : public Codec {
 public:
  AvVideoCodec(AvVideoFormat format, AvVideoSettings settings) : f_(std::move(format)), s_(settings) {
    encoder_ = avcodec_find_encoder_by_name(f_.encoder.c_str());
    if (!encoder_) fail("{}: this libavcodec has no {} encoder ({})", f_.name, f_.encoder, f_.install_hint);
    decoder_ = avcodec_find_decoder_by_name(f_.decoder.c_str());
    if (!decoder_) fail("{}: this libavcodec has no {} decoder ({})", f_.name, f_.decoder, f_.install_hint);
    gray_ = f_.gray_allowed && av_encoder_takes(f_.encoder.c_str(), AV_PIX_FMT_GRAY8);
    packet_ = av_packet_alloc();
    if (!packet_) fail("{}: out of memory", f_.name);
  }
  ~AvVideoCodec() override {
    reset();
    av_packet_free(&packet_);
  }
  AvVideoCodec(const AvVideoCodec&) = delete;
  AvVideoCodec& operator=(const AvVideoCodec&) = delete;

  bool lossless() const override { return s_.rate_control == AvRateControl::Lossless; }
  bool stateful() const override { return true; }  // P-frames reference earlier frames
  bool heals_after_loss() const override { return s_.intra_refresh; }
  bool takes_target_kbps() const override { return s_.rate_control == AvRateControl::Bitrate && f_.retargets_bitrate; }
  std::string stream_format() const override { return f_.stream_format; }

  std::string refuses(const PassDesc& desc) const override {
    if (std::string why = desc.validate(); !why.empty()) return "invalid buffer description: " + why;
    if (desc.layout() == PassLayout::Bitmask)
      return fmt::format(
          "{} does not carry bitmasks (lossy coding flips bits; lossless codes 1-bit data as 8-bit "
          "samples): use lz4 or zstd",
          f_.name);
    if (desc.layout() == PassLayout::Code16)
      return fmt::format(
          "{} does not carry depth (16-bit codes split into a high and a low byte plane: a lossy step "
          "in the high byte moves the depth by 1/256 of its range): use lz4 or zstd",
          f_.name);
    if (desc.layout() == PassLayout::Rgb8 && lossless())
      return fmt::format("{} lossless codes YUV 4:2:0, which cannot return RGB bit-exactly: use lossy {}, lz4 or zstd",
                         f_.name, f_.name);
    if (desc.width == 0 || desc.height == 0) return fmt::format("{} has no empty pictures", f_.name);
    const Geometry g = geometry_of(desc);
    if (g.padded_height > kMaxImageSide)
      return fmt::format("{} light planes of {} rows stack into a {}-row picture, above {}", desc.channels, desc.height,
                         g.padded_height, kMaxImageSide);
    return {};
  }

  void encode(const PassBuffer& in, const EncodeOptions& options, std::vector<uint8_t>& out) override {
    if (std::string why = refuses(in.desc); !why.empty()) fail("{}: cannot encode this buffer: {}", f_.name, why);
    if (in.bytes.size() != in.desc.byte_size())
      fail("{}: a {}x{} {} buffer holds {} bytes, {} expected", f_.name, in.desc.width, in.desc.height,
           pass_kind_name(in.desc.kind), in.bytes.size(), in.desc.byte_size());
    if (!enc_ || !(enc_desc_ == in.desc)) open_encoder(in.desc);
    if (options.target_kbps > 0.0 && takes_target_kbps()) {  // a bit budget's share, from this frame on
      enc_->bit_rate = std::max<int64_t>(1000, std::llround(std::min(options.target_kbps, 1e9) * 1000.0));
      enc_->rc_max_rate = enc_->bit_rate;
      enc_->rc_buffer_size = vbv_bits(enc_->bit_rate);
    }
    fill_picture(in);
    frame_->pts = next_pts_++;
    frame_->pict_type = options.force_keyframe ? AV_PICTURE_TYPE_I : AV_PICTURE_TYPE_NONE;
    frame_->key_frame = options.force_keyframe ? 1 : 0;
    if (int r = avcodec_send_frame(enc_, frame_); r < 0)
      fail("{}: avcodec_send_frame failed: {}", f_.name, av_error_text(r));
    out.clear();
    for (;;) {
      const int r = avcodec_receive_packet(enc_, packet_);
      if (r == AVERROR(EAGAIN)) break;
      if (r < 0) fail("{}: avcodec_receive_packet failed: {}", f_.name, av_error_text(r));
      out.insert(out.end(), packet_->data, packet_->data + packet_->size);
      av_packet_unref(packet_);
    }
    // No lookahead: a frame that stays in the encoder is a configuration bug.
    if (out.empty()) fail("{}: {} returned no bits for frame {}", f_.name, f_.encoder, frame_->pts);
  }

  bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) override {
    if (std::string why = refuses(desc); !why.empty()) {
      error = f_.name + ": " + why;
      return false;
    }
    if (in.empty()) {
      error = f_.name + ": empty input";
      return false;
    }
    if (!dec_ && !open_decoder(error)) return false;
    // The decoder may read up to AV_INPUT_BUFFER_PADDING_SIZE bytes past the data.
    if (int r = av_new_packet(packet_, int(in.size())); r < 0) {
      error = f_.name + ": out of memory for a packet";
      return false;
    }
    std::memcpy(packet_->data, in.data(), in.size());
    const int sent = avcodec_send_packet(dec_, packet_);
    av_packet_unref(packet_);
    if (sent < 0) {
      error = fmt::format("{}: corrupt bitstream: {}", f_.name, av_error_text(sent));
      return false;
    }
    int r = avcodec_receive_frame(dec_, dec_frame_);
    if (r == AVERROR(EAGAIN)) {
      error = f_.name + ": the bytes hold no displayable picture (a P-frame without its reference?)";
      return false;
    }
    if (r < 0) {
      error = fmt::format("{}: decoding failed: {}", f_.name, av_error_text(r));
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
      error = fmt::format("{}: the bytes hold {} pictures, one expected", f_.name, extra + 1);
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
  // The picture a buffer is coded as: its size before and after padding (to even, and to the
  // encoder's smallest picture side).
  struct Geometry {
    int width = 0, height = 0;  // data size (SoftVisibility: planes stacked)
    int padded_width = 0, padded_height = 0;
    bool colour = false;
  };

  Geometry geometry_of(const PassDesc& desc) const {
    Geometry g;
    g.width = desc.width;
    g.height = desc.layout() == PassLayout::Planes8 ? desc.height * desc.channels : desc.height;
    g.padded_width = std::max(g.width + (g.width & 1), f_.min_side);
    g.padded_height = std::max(g.height + (g.height & 1), f_.min_side);
    g.colour = desc.layout() == PassLayout::Rgb8;
    return g;
  }

  // The VBV buffer in bits: vbv_buffer_ms at `rate` bit/s.
  int vbv_bits(int64_t rate) const { return int(std::clamp<int64_t>(rate * s_.vbv_buffer_ms / 1000, 1, INT32_MAX)); }

  void open_encoder(const PassDesc& desc) {
    enc_desc_ = PassDesc{};  // stays invalid if opening fails, so the next encode retries
    avcodec_free_context(&enc_);
    av_frame_free(&frame_);
    sws_freeContext(to_yuv_);
    to_yuv_ = nullptr;
    const Geometry g = geometry_of(desc);
    enc_ = avcodec_alloc_context3(encoder_);
    frame_ = av_frame_alloc();
    if (!enc_ || !frame_) fail("{}: out of memory", f_.name);
    enc_->width = g.padded_width;
    enc_->height = g.padded_height;
    enc_->time_base = AVRational{1, s_.fps};
    enc_->framerate = AVRational{s_.fps, 1};
    enc_->pix_fmt = (!g.colour && gray_)         ? AV_PIX_FMT_GRAY8
                    : (g.colour && s_.chroma444) ? AV_PIX_FMT_YUV444P
                                                 : AV_PIX_FMT_YUV420P;
    if (enc_->pix_fmt == AV_PIX_FMT_YUV444P && !av_encoder_takes(f_.encoder.c_str(), AV_PIX_FMT_YUV444P))
      fail("{}: {} does not take 4:4:4 pictures (chroma \"444\"); use chroma \"420\"", f_.name, f_.encoder);
    enc_->gop_size = s_.gop;
    enc_->max_b_frames = 0;
    enc_->thread_count = s_.threads;
    enc_->color_range = g.colour ? AVCOL_RANGE_MPEG : AVCOL_RANGE_JPEG;
    if (g.colour) {
      enc_->colorspace = AVCOL_SPC_SMPTE170M;
      enc_->color_primaries = AVCOL_PRI_SMPTE170M;
      enc_->color_trc = AVCOL_TRC_SMPTE170M;
    }
    AvOptions options(f_.name, enc_);
    switch (s_.rate_control) {
      case AvRateControl::Crf:
        options.set("crf", std::to_string(s_.crf));
        if (s_.max_kbps > 0) {  // a capped CRF: the VBV at max_kbps
          enc_->rc_max_rate = int64_t(s_.max_kbps) * 1000;
          enc_->rc_buffer_size = vbv_bits(enc_->rc_max_rate);
        }
        break;
      case AvRateControl::Lossless: break;  // configure_encoder switches it on
      case AvRateControl::Bitrate:
        enc_->bit_rate = int64_t(s_.bitrate_kbps) * 1000;
        enc_->rc_max_rate = enc_->bit_rate;
        enc_->rc_buffer_size = vbv_bits(enc_->bit_rate);
        break;
    }
    f_.configure_encoder(s_, options);
    if (int r = avcodec_open2(enc_, encoder_, nullptr); r < 0)
      fail("{}: cannot open {} for a {}x{} picture: {}", f_.name, f_.encoder, g.padded_width, g.padded_height,
           av_error_text(r));
    frame_->format = enc_->pix_fmt;
    frame_->width = g.padded_width;
    frame_->height = g.padded_height;
    frame_->color_range = enc_->color_range;
    if (int r = av_frame_get_buffer(frame_, 0); r < 0)
      fail("{}: cannot allocate a picture: {}", f_.name, av_error_text(r));
    if (g.colour) {
      to_yuv_ = sws_getContext(g.padded_width, g.padded_height, AV_PIX_FMT_RGB24, g.padded_width, g.padded_height,
                               enc_->pix_fmt, SWS_BILINEAR, nullptr, nullptr, nullptr);
      if (!to_yuv_)
        fail("{}: libswscale cannot convert RGB24 to {} at {}x{}", f_.name, av_get_pix_fmt_name(enc_->pix_fmt),
             g.padded_width, g.padded_height);
    }
    enc_desc_ = desc;
    next_pts_ = 0;
  }

  bool open_decoder(std::string& error) {
    dec_ = avcodec_alloc_context3(decoder_);
    dec_frame_ = av_frame_alloc();
    extra_frame_ = av_frame_alloc();
    if (!dec_ || !dec_frame_ || !extra_frame_) fail("{}: out of memory", f_.name);
    dec_->thread_count = 1;  // frame threads would delay output by a frame per thread
    dec_->flags |= AV_CODEC_FLAG_LOW_DELAY;
    // Fail on damaged slices instead of concealing them, so corruption is reported; except
    // under intra refresh, where a picture predicted from a lost frame is concealed and shown
    // (the stream heals by itself; damaged bytes are still caught by each frame's checksum).
    dec_->err_recognition = s_.intra_refresh ? 0 : AV_EF_EXPLODE | AV_EF_CAREFUL | AV_EF_BITSTREAM | AV_EF_BUFFER;
    if (s_.intra_refresh) {
      dec_->flags |= AV_CODEC_FLAG_OUTPUT_CORRUPT;
      dec_->flags2 |= AV_CODEC_FLAG2_SHOW_ALL;
    }
    for (const auto& [key, value] : f_.decoder_options)
      if (int r = av_opt_set(dec_->priv_data, key.c_str(), value.c_str(), 0); r < 0)
        fail("{}: the {} decoder rejects option {}={}: {}", f_.name, f_.decoder, key, value, av_error_text(r));
    if (int r = avcodec_open2(dec_, decoder_, nullptr); r < 0) {
      error = fmt::format("{}: cannot open the {} decoder: {}", f_.name, f_.decoder, av_error_text(r));
      avcodec_free_context(&dec_);
      return false;
    }
    return true;
  }

  // Writes the buffer into frame_ (padding by edge replication; count planes mapped to full range).
  void fill_picture(const PassBuffer& in) {
    if (int r = av_frame_make_writable(frame_); r < 0)
      fail("{}: cannot write a picture: {}", f_.name, av_error_text(r));
    const Geometry g = geometry_of(in.desc);
    if (!g.colour) {
      const FullRangeMap range(in.desc.full_scale, !lossless());
      for (int y = 0; y < g.padded_height; ++y) {
        const uint8_t* src = in.bytes.data() + size_t(std::min(y, g.height - 1)) * size_t(g.width);
        uint8_t* dst = frame_->data[0] + ptrdiff_t(y) * frame_->linesize[0];
        if (in.desc.full_scale == 255)
          std::memcpy(dst, src, size_t(g.width));  // the mapping is the identity
        else
          for (int x = 0; x < g.width; ++x) dst[x] = range.to_picture[src[x]];
        std::memset(dst + g.width, dst[g.width - 1], size_t(g.padded_width - g.width));
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
      for (int x = g.width; x < g.padded_width; ++x) std::memcpy(dst + size_t(x) * 3, src + size_t(g.width - 1) * 3, 3);
    }
    sws_scale(to_yuv_, rgb->data, rgb->linesize, 0, g.padded_height, frame_->data, frame_->linesize);
  }

  // An RGB24 picture of the padded size, reallocated when the size changes.
  AVFrame* rgb_frame(const Geometry& g) {
    if (rgb_ && (rgb_->width != g.padded_width || rgb_->height != g.padded_height)) av_frame_free(&rgb_);
    if (!rgb_) {
      rgb_ = av_frame_alloc();
      if (!rgb_) fail("{}: out of memory", f_.name);
      rgb_->format = AV_PIX_FMT_RGB24;
      rgb_->width = g.padded_width;
      rgb_->height = g.padded_height;
      if (int r = av_frame_get_buffer(rgb_, 0); r < 0)
        fail("{}: cannot allocate a picture: {}", f_.name, av_error_text(r));
    }
    return rgb_;
  }

  // Checks dec_frame_ against `desc` and crops it into `out`.
  bool picture_to_buffer(const PassDesc& desc, PassBuffer& out, std::string& error) {
    const Geometry g = geometry_of(desc);
    const AVFrame* f = dec_frame_;
    if (f->width != g.padded_width || f->height != g.padded_height) {
      error =
          fmt::format("{}: decoded a {}x{} picture, {}x{} expected for a {}x{} {} buffer", f_.name, f->width, f->height,
                      g.padded_width, g.padded_height, desc.width, desc.height, pass_kind_name(desc.kind));
      return false;
    }
    if (((f->flags & AV_FRAME_FLAG_CORRUPT) || f->decode_error_flags) && !s_.intra_refresh) {
      error = f_.name + ": the decoder reports a damaged picture";
      return false;
    }
    const auto format = AVPixelFormat(f->format);
    const bool yuv420 = format == AV_PIX_FMT_YUV420P || format == AV_PIX_FMT_YUVJ420P;
    const bool yuv444 = format == AV_PIX_FMT_YUV444P || format == AV_PIX_FMT_YUVJ444P;
    if (!(yuv420 || (g.colour && yuv444) || (!g.colour && format == AV_PIX_FMT_GRAY8))) {
      error =
          fmt::format("{}: decoded pixel format {} is not 8-bit 4:2:0, 4:4:4 (colour) or gray", f_.name, int(format));
      return false;
    }
    out.desc = desc;
    out.bytes.resize(desc.byte_size());
    if (!g.colour) {
      const FullRangeMap range(desc.full_scale, !lossless());
      for (int y = 0; y < g.height; ++y) {
        const uint8_t* src = f->data[0] + ptrdiff_t(y) * f->linesize[0];
        uint8_t* dst = out.bytes.data() + size_t(y) * size_t(g.width);
        if (desc.full_scale == 255)
          std::memcpy(dst, src, size_t(g.width));  // the mapping is the identity
        else
          for (int x = 0; x < g.width; ++x) dst[x] = range.from_picture[src[x]];
      }
      return true;
    }
    // Returns the same context while the size stays the same.
    const AVPixelFormat picture = yuv444 ? AV_PIX_FMT_YUV444P : AV_PIX_FMT_YUV420P;
    to_rgb_ = sws_getCachedContext(to_rgb_, g.padded_width, g.padded_height, picture, g.padded_width, g.padded_height,
                                   AV_PIX_FMT_RGB24, SWS_BILINEAR, nullptr, nullptr, nullptr);
    if (!to_rgb_) {
      error = fmt::format("{}: libswscale cannot convert {} to RGB24", f_.name, av_get_pix_fmt_name(picture));
      return false;
    }
    AVFrame* rgb = rgb_frame(g);
    sws_scale(to_rgb_, f->data, f->linesize, 0, g.padded_height, rgb->data, rgb->linesize);
    for (int y = 0; y < g.height; ++y)
      std::memcpy(out.bytes.data() + size_t(y) * size_t(g.width) * 3, rgb->data[0] + ptrdiff_t(y) * rgb->linesize[0],
                  size_t(g.width) * 3);
    return true;
  }

  AvVideoFormat f_;
  AvVideoSettings s_;
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

void AvOptions::set(const char* key, const std::string& value) {
  if (int r = av_opt_set(context_->priv_data, key, value.c_str(), 0); r < 0)
    fail("{}: the encoder rejects option {}={}: {}", codec_, key, value, av_error_text(r));
}

bool av_encoder_takes(const char* encoder, AVPixelFormat format) {
  const AVCodec* codec = avcodec_find_encoder_by_name(encoder);
  if (!codec || !codec->pix_fmts) return false;
  for (const AVPixelFormat* f = codec->pix_fmts; *f != AV_PIX_FMT_NONE; ++f)
    if (*f == format) return true;
  return false;
}

std::vector<ParamSpec> av_video_params(const std::string& encoder_label, int crf_default, int crf_max,
                                       const std::string& lossless_note, const std::string& threads_note) {
  return {
      ParamSpec::choice(
          "rate_control", "crf", {"crf", "bitrate", "lossless"},
          encoder_label + " rate control: constant rate factor, target bitrate, or lossless (" + lossless_note + ")"),
      ParamSpec::integer("crf", crf_default, 0, crf_max, "constant rate factor (crf mode): lower is better quality"),
      ParamSpec::integer("bitrate_kbps", 10000, 1, 1000000, "target bitrate in kbit/s (bitrate mode)"),
      ParamSpec::integer("fps", 60, 1, 1000, "frame rate the bitrate refers to (bitrate mode)"),
      ParamSpec::integer("gop", 60, 1, 100000, "keyframe interval in frames"),
      ParamSpec::integer("threads", 1, 1, 16, encoder_label + " threads (" + threads_note + ")"),
      ParamSpec::integer("vbv_buffer_ms", 1000, 1, 10000,
                         "VBV buffer in ms at the peak rate (bitrate mode: the target; crf mode: max_kbps): "
                         "smaller bounds each frame's size more tightly (one frame interval: CBR per frame)"),
      ParamSpec::integer("max_kbps", 0, 0, 1000000,
                         "crf mode: cap the rate with a VBV at this peak (capped CRF; 0: uncapped)"),
      ParamSpec::choice("chroma", "420", {"420", "444"},
                        "colour pictures' chroma: 4:2:0 (half-resolution chroma, what streaming ships) or 4:4:4")};
}

ParamSpec intra_refresh_param(const std::string& encoder_label) {
  return ParamSpec::boolean("intra_refresh", false,
                            encoder_label +
                                " periodic intra refresh: a column of intra blocks sweeps the picture every gop "
                                "frames instead of keyframes; after a loss the decoder goes on and the picture "
                                "heals within one sweep (no keyframe request)");
}

ParamSpec x26x_preset_param(const std::string& encoder_label) {
  return ParamSpec::choice(
      "preset", "ultrafast",
      {"ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow"},
      encoder_label + " speed preset");
}

AvVideoSettings av_video_settings(const Params& p) {
  AvVideoSettings s;
  const std::string rc = p.get_string("rate_control");
  s.rate_control = rc == "lossless"  ? AvRateControl::Lossless
                   : rc == "bitrate" ? AvRateControl::Bitrate
                                     : AvRateControl::Crf;
  s.crf = p.get_int("crf");
  s.bitrate_kbps = p.get_int("bitrate_kbps");
  s.fps = p.get_int("fps");
  s.gop = p.get_int("gop");
  s.threads = p.get_int("threads");
  s.chroma444 = p.get_string("chroma") == "444";
  s.vbv_buffer_ms = p.get_int("vbv_buffer_ms");
  s.max_kbps = p.get_int("max_kbps");
  s.intra_refresh = p.effective().contains("intra_refresh") && p.get_bool("intra_refresh");
  return s;
}

std::unique_ptr<Codec> make_av_video_codec(AvVideoFormat format, AvVideoSettings settings) {
  return std::make_unique<AvVideoCodec>(std::move(format), settings);
}

}  // namespace dhr
