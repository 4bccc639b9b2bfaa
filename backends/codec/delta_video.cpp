// delta_video: temporal prediction before a lossy video coder. Like delta, a frame is
// predicted from one the client already holds, carried to this frame by the registered
// predictor through both frames' G-buffers (or taken as it is), and only the residual is sent;
// unlike delta the residual goes through h264, hevc or av1 at a rate the user chooses, so the
// client does not get the frame back exactly. Both ends therefore predict from the
// reconstruction, never from the frame: the encoder decodes its own output with a second
// decoder of the inner codec, exactly as the client will, and keeps that as its reference
// (docs/architecture.md, "Pass coding against what the client holds").
//
// 8-bit passes (AO, soft visibility) only. Frame and prediction are taken to the full range
// (0..255, the video layer's mapping of a count plane, backends/codec/av_video.h) and the
// residual r = clamp(frame - prediction + 128, 0, 255) is coded as a 0..255 plane; the
// reconstruction is clamp(prediction + r' - 128) mapped back to the pass's range, r' the
// decoded residual. A difference beyond +-127 (a disocclusion from black to white) is clipped;
// the next frame, predicted from the clipped reconstruction, carries the rest. A keyframe codes
// the frame itself (in the full range) as an IDR picture, so the inner stream only ever sees
// one buffer description.
//
// Losses: the inner stream has references of its own, so nothing decodes right after a lost
// picture until an IDR. The client's decoder reports the newest reconstruction it holds
// (Codec::holds()); the encoder predicts the next frame from it and codes that residual as an
// IDR picture: the inner stream restarts, the prediction does not. In between the client
// refuses every frame: its reference is missing, or (the inner decoder conceals missing
// pictures rather than failing) its reconstruction's CRC-32C is not the server's.
//
// Stream: every output starts with a 17-byte header: type ('K' keyframe, 'D' delta), the
// frame's index (the context's frame when it has a G-buffer, else a count of coded frames),
// the index of the frame it was predicted from, the CRC-32C of the inner codec's access unit
// that follows and the CRC-32C of the encoder's reconstruction (uint32 little-endian each).
// The first keeps damaged bits from the inner decoder (a video stream has no checksum of its
// own); the second makes any difference between the two ends' reconstructions a decode error,
// never wrong bytes.
//
// Parameters:
//   inner              h264 | hevc | av1      the video coder of the residual      default h264
//   rate_control       crf | bitrate          the inner coder's rate control      default crf
//   crf                0..63                  its constant rate factor (h264, hevc: up to 51)
//                                                                                  default 23
//   bitrate_kbps       1..1000000             its target (bitrate mode); a stream's bit budget
//                                             (stream_kbps) moves it where the inner coder
//                                             follows one (h264)                   default 10000
//   fps                1..1000                the frame rate the bitrate refers to default 60
//   keyframe_interval  1..100000              a keyframe (IDR) every this many frames
//                                                                                  default 60
//   predictor          none | reprojection    how the reference is carried to this frame
//                                                                                  default none
//   filter             nearest | bilinear     the reprojection's filter             default bilinear
//   references         1..64                  reconstructions each end keeps (loss recovery)
//                                                                                  default 8
// The inner coder runs at its own defaults otherwise (x264/x265 ultrafast, libaom cpu-used 8).
// Example: {"name": "delta_video", "params": {"inner": "h264", "crf": 30, "predictor": "reprojection"}}
#include "backends/codec/av_video.h"
#include "backends/codec/reference_frames.h"
#include "backends/register_all.h"
#include "core/base/checksum.h"

#include <algorithm>
#include <cstring>
#include <deque>
#include <optional>

namespace dhr {
namespace {

// The frame start (type, frame, reference), then the CRC-32C of the bits and of the reconstruction.
constexpr size_t kBitsCrcAt = kFrameStartBytes, kReconstructionCrcAt = kFrameStartBytes + 4;
constexpr size_t kHeaderBytes = kFrameStartBytes + 8;
constexpr int kResidualZero = 128;

nlohmann::json inner_params(const Params& p) {
  nlohmann::json j = {{"rate_control", p.get_string("rate_control")},
                      {"fps", p.get_int("fps")},
                      {"gop", 100000}};  // keyframes are delta_video's to force
  if (p.get_string("rate_control") == "crf")
    j["crf"] = p.get_int("crf");
  else
    j["bitrate_kbps"] = p.get_int("bitrate_kbps");
  return j;
}

std::unique_ptr<Codec> make_inner(const Params& p) {
  try {
    return registries().codecs.create(p.get_string("inner"), inner_params(p));
  } catch (const Error& e) {
    fail("codec 'delta_video': its inner {} does not take these parameters: {}", p.get_string("inner"), e.what());
  }
}

// The buffer description the inner coder sees: the pass's, in the full range.
PassDesc full_range(PassDesc d) {
  d.full_scale = 255;
  return d;
}

class DeltaVideoCodec final : public Codec {
 public:
  explicit DeltaVideoCodec(const Params& p)
      : keyframe_interval_(p.get_int("keyframe_interval")),
        references_(p.get_int("references")),
        inner_name_(p.get_string("inner")),
        encoder_(make_inner(p)),
        mirror_(make_inner(p)),
        decoder_(make_inner(p)) {
    if (p.get_string("predictor") != "none")
      carrier_.emplace("delta_video",
                       registries().predictors.create(p.get_string("predictor"), {{"filter", p.get_string("filter")}}));
  }

  bool lossless() const override { return false; }
  bool stateful() const override { return true; }
  bool takes_target_kbps() const override { return encoder_->takes_target_kbps(); }
  int gbuffers_referenced() const override { return carrier_ ? references_ : 0; }
  int holds() const override { return newest_reference(decoded_); }

  std::string refuses(const PassDesc& desc) const override {
    if (std::string why = desc.validate(); !why.empty()) return "invalid buffer description: " + why;
    if (desc.layout() != PassLayout::Planes8)
      return fmt::format(
          "delta_video codes 8-bit passes (AO, soft visibility), not a {} pass: a bitmask's residual "
          "is its XOR (use delta); colour and depth go to the video codecs and lz4/zstd as they are",
          pass_kind_name(desc.kind));
    return encoder_->refuses(full_range(desc));
  }

  void encode(const PassBuffer& in, const EncodeOptions& options, std::vector<uint8_t>& out) override {
    if (std::string why = refuses(in.desc); !why.empty()) fail("delta_video: cannot encode this buffer: {}", why);
    const FrameContext& ctx = options.context;
    const uint32_t index = coded_frame_index("delta_video", in, options, carrier_.has_value(), next_index_, coded_);
    const auto [ref, ref_gbuf] = choose_reference(coded_, options, in.desc,
                                                  since_key_ + 1 >= uint32_t(keyframe_interval_), carrier_.has_value());

    const FullRangeMap range(in.desc.full_scale, true);
    const PassBuffer* prediction = nullptr;
    picture_.desc = full_range(in.desc);
    picture_.bytes.resize(in.bytes.size());
    if (ref) {
      prediction = carrier_ ? &carrier_->carry(*ref, *ref_gbuf, index, *ctx.gbuf) : &ref->buffer;
      for (size_t i = 0; i < in.bytes.size(); ++i) {
        const int r = range.to_picture[in.bytes[i]] - range.to_picture[prediction->bytes[i]] + kResidualZero;
        picture_.bytes[i] = uint8_t(std::clamp(r, 0, 255));
      }
    } else {
      for (size_t i = 0; i < in.bytes.size(); ++i) picture_.bytes[i] = range.to_picture[in.bytes[i]];
    }
    // A keyframe, and the first residual after a loss, restart the inner stream.
    EncodeOptions inner;
    inner.force_keyframe = !ref || options.client_holds >= 0;
    inner.target_kbps = options.target_kbps;
    encoder_->encode(picture_, inner, bits_);
    // The reconstruction, as the client's decoder will make it.
    std::string error;
    if (!mirror_->decode(bits_, picture_.desc, decoded_picture_, error))
      fail("delta_video: the encoder cannot decode its own {} picture of frame {}: {}", inner_name_, index, error);
    Reference rec{index, reconstruct(decoded_picture_, prediction, in.desc, range)};

    out.resize(kHeaderBytes + bits_.size());
    put_frame_start(out.data(), {!ref, index, ref ? ref->frame : index});
    put_u32(out.data() + kBitsCrcAt, crc32c(bits_));
    put_u32(out.data() + kReconstructionCrcAt, crc32c(rec.buffer.bytes));
    std::memcpy(out.data() + kHeaderBytes, bits_.data(), bits_.size());
    since_key_ = ref ? since_key_ + 1 : 0;
    keep_reference(coded_, std::move(rec), references_);
    next_index_ = index + 1;
  }

  bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) override {
    return decode_in_context(in, desc, FrameContext{}, out, error);
  }

  bool decode_in_context(std::span<const uint8_t> in, const PassDesc& desc, const FrameContext& ctx, PassBuffer& out,
                         std::string& error) override {
    if (std::string why = refuses(desc); !why.empty()) {
      error = "delta_video: " + why;
      return false;
    }
    FrameStart start;
    if (error = read_frame_start("delta_video", in, kHeaderBytes, start); !error.empty()) return false;
    const uint32_t index = start.index, reference = start.reference;
    const Reference* ref = nullptr;
    const PassBuffer* prediction = nullptr;
    if (!start.keyframe &&
        !(error = find_delta_reference("delta_video", decoded_, start, desc, ctx, carrier_.has_value(), ref)).empty())
      return false;
    const std::span<const uint8_t> bits = in.subspan(kHeaderBytes);
    if (const uint32_t expected = get_u32(in.data() + kBitsCrcAt), got = crc32c(bits); got != expected) {
      error = fmt::format(
          "delta_video: frame {}: the {} bytes after the header are damaged (CRC-32C {:08x}, expected "
          "{:08x})",
          index, bits.size(), got, expected);
      return false;
    }
    if (!decoder_->decode(bits, full_range(desc), decoded_picture_, error)) {
      error = "delta_video: " + error;
      return false;
    }
    if (ref)
      prediction = carrier_ ? &carrier_->carry(*ref, *ctx.gbuffer_of(reference), index, *ctx.gbuf) : &ref->buffer;
    PassBuffer rec = reconstruct(decoded_picture_, prediction, desc, FullRangeMap(desc.full_scale, true));
    if (const uint32_t expected = get_u32(in.data() + kReconstructionCrcAt), got = crc32c(rec.bytes); got != expected) {
      error = fmt::format(
          "delta_video: frame {} reconstructed{} does not match the server's (CRC-32C {:08x}, "
          "expected {:08x}): a picture of the inner stream was lost or damaged, or the two ends' "
          "predictions differ",
          index, ref ? fmt::format(" from frame {}", reference) : std::string(), got, expected);
      return false;
    }
    keep_reference(decoded_, {index, rec}, references_);
    out = std::move(rec);
    return true;
  }

  void reset() override {
    encoder_->reset();
    mirror_->reset();
    decoder_->reset();
    if (carrier_) carrier_->reset();
    coded_.clear();
    decoded_.clear();
    since_key_ = 0;
    next_index_ = 0;
  }

 private:
  // The pass from a decoded full-range picture: the frame itself (no prediction), or the
  // prediction plus the residual; `range`: the pass's full-range map.
  static PassBuffer reconstruct(const PassBuffer& picture, const PassBuffer* prediction, const PassDesc& desc,
                                const FullRangeMap& range) {
    PassBuffer rec;
    rec.desc = desc;
    rec.bytes.resize(picture.bytes.size());
    if (!prediction) {
      for (size_t i = 0; i < rec.bytes.size(); ++i) rec.bytes[i] = range.from_picture[picture.bytes[i]];
      return rec;
    }
    for (size_t i = 0; i < rec.bytes.size(); ++i) {
      const int v = range.to_picture[prediction->bytes[i]] + picture.bytes[i] - kResidualZero;
      rec.bytes[i] = range.from_picture[size_t(std::clamp(v, 0, 255))];
    }
    return rec;
  }

  int keyframe_interval_, references_;
  std::string inner_name_;
  std::unique_ptr<Codec> encoder_, mirror_, decoder_;  // the inner coder: encoding, its reconstruction, decoding
  std::optional<ReferenceCarrier> carrier_;            // none: predictor none
  // Encoder state: the reconstructions of the frames coded.
  std::deque<Reference> coded_;
  uint32_t since_key_ = 0, next_index_ = 0;
  PassBuffer picture_, decoded_picture_;
  std::vector<uint8_t> bits_;
  // Decoder state.
  std::deque<Reference> decoded_;
};

}  // namespace

CodecEntry make_delta_video_codec() {
  return {"delta_video",
          "temporal prediction from the reconstruction the client holds (reprojected or not), the residual through "
          "h264, hevc or av1; for lossy 8-bit passes",
          {ParamSpec::choice("inner", "h264", {"h264", "hevc", "av1"}, "the video coder of the residual"),
           ParamSpec::choice("rate_control", "crf", {"crf", "bitrate"}, "the inner coder's rate control"),
           ParamSpec::integer("crf", 23, 0, 63, "constant rate factor (crf mode; h264 and hevc take 0..51)"),
           ParamSpec::integer("bitrate_kbps", 10000, 1, 1000000, "target bitrate in kbit/s (bitrate mode)"),
           ParamSpec::integer("fps", 60, 1, 1000, "frame rate the bitrate refers to (bitrate mode)"),
           ParamSpec::integer("keyframe_interval", 60, 1, 100000, "a keyframe (IDR picture) every this many frames"),
           ParamSpec::choice("predictor", "none", {"none", "reprojection"},
                             "how the reference reconstruction is carried to this frame: as it is, or reprojected "
                             "through both frames' G-buffers"),
           ParamSpec::choice("filter", "bilinear", {"nearest", "bilinear"}, "the reprojection's filter"),
           ParamSpec::integer("references", 8, 1, 64, "reconstructions each end keeps as references (loss recovery)")},
          [](const Params& p) { return std::make_unique<DeltaVideoCodec>(p); }};
}

}  // namespace dhr
