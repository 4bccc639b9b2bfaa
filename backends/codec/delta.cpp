// delta: temporal prediction before a lossless coder. Beyond the paper (which codes every frame
// alone): the frame is predicted from one the client already holds, and only the residual is
// coded: a bitmask is XORed with its prediction and byte buffers (AO, soft visibility, colour)
// are coded as the byte difference mod 256, then the residual goes through lz4 or zstd (with
// their checksums and bit-plane layout).
//
// The prediction (`predictor`):
//   none          the reference frame as it is (no reprojection): almost all zero residual where
//                 the camera holds still, poor where it moves;
//   reprojection  the registered reprojection predictor carries the reference frame to this
//                 frame through the G-buffers of both frames, exactly as the client's display
//                 does (backends/predict/reprojection.cpp). Server and client run the same
//                 deterministic prediction on G-buffers that agree bit for bit (the server's for
//                 the camera it traced, the client's own rasterization of it: FrameContext),
//                 so the residual is what the client cannot predict: disocclusions, moving
//                 objects, changed shadows and noise.
//
// References and losses (docs/architecture.md, "Pass coding against what the client holds"):
// both ends keep the last `references` frames (encoder: the frames it coded, which a lossless
// coder reconstructs exactly; decoder: the frames it decoded). A frame is predicted from the
// newest coded frame; after a loss the client reports the newest frame it holds
// (Codec::holds(), EncodeOptions::client_holds) and the encoder predicts the next frame from
// that one instead of sending a keyframe (a keyframe when it no longer keeps it). The decoder
// refuses a frame whose reference or G-buffers it does not hold, so a loss never yields wrong
// bytes, only a failure until the recovery frame arrives. Keyframes come every
// `keyframe_interval` frames, on EncodeOptions::force_keyframe without a reported reference, on
// the first frame, after reset() and when the buffer description changes.
//
// Stream: every output starts with a 9-byte header: type ('K' keyframe, 'D' delta), the
// frame's index (the context's frame when it has a G-buffer, else a count of coded frames) and
// the index of the frame it was predicted from (uint32 little-endian). With a predictor, 12
// more bytes follow: the CRC-32C of the frame itself and the mask of predicted planes (uint64,
// bit p: plane p, a light of a bitmask or a channel of an 8-bit pass, is coded against the
// prediction; a clear bit: coded as it is). The inner coder's checksum covers the residual
// only; the CRC covers the reconstruction, so a client whose prediction differed from the
// server's (G-buffers that do not agree) gets a decode error, never wrong bytes.
//
// Why planes are chosen: soft shadows from one jittered ray per light (the paper's bitmask)
// are fresh noise every frame inside a penumbra; there the XOR of two frames holds more
// changes than the frame itself, and a light with wide penumbrae is better coded alone. The
// choice codes every plane alone twice (its cost is in bench_pass_coding).
//
// Parameters:
//   inner              lz4 | zstd             the lossless coder of the residual      default zstd
//   level              1..19                  zstd level; with lz4: 1 = fast, 3..12 = hc level
//                                                                                     default 1
//   layout             interleaved | planes   bitmask layout handed to the inner coder default planes
//   keyframe_interval  1..100000              a keyframe every this many frames       default 30
//   predictor          none | reprojection    how the reference is carried to this frame
//                                                                                     default none
//   filter             nearest | bilinear     the reprojection's filter for 8-bit passes
//                                                                                     default bilinear
//   references         1..64                  frames each end keeps as references     default 8
//   plane_choice       true | false           with a predictor and several planes (lights of a
//                                             bitmask, channels of an 8-bit pass): predict only the
//                                             planes whose residual the inner coder codes smaller
//                                             than the plane itself (each coded alone, both ways)
//                                                                                     default true
//   intra_check        true | false           with a predictor: also code the frame alone and send
//                                             whichever is smaller (a keyframe when it is)
//                                                                                     default true
// Example: {"name": "delta", "params": {"inner": "zstd", "level": 1, "predictor": "reprojection"}}
#include "backends/codec/reference_frames.h"
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "core/base/checksum.h"

#include <algorithm>
#include <cstring>
#include <deque>
#include <optional>

namespace dhr {
namespace {

constexpr size_t kHeaderBytes = kFrameStartBytes;  // type, frame, reference
constexpr size_t kPredictedBytes = 12;             // with a predictor: CRC-32C of the frame, mask of predicted planes

// Planes of a buffer: the lights of a bitmask (bit p % 8 of byte p / 8 of each pixel), the
// channels of an 8-bit buffer (byte p of each pixel).
int plane_count(const PassDesc& d) {
  return d.layout() == PassLayout::Bitmask || d.layout() == PassLayout::Planes8 ? d.channels : 1;
}

uint64_t all_planes(const PassDesc& d) {
  const int planes = plane_count(d);
  return planes >= 64 ? ~uint64_t(0) : (uint64_t(1) << planes) - 1;
}

// residual = cur - prev (XOR for bitmasks); apply(residual, prev) inverts it.
void make_residual(const PassBuffer& cur, const PassBuffer& prev, std::vector<uint8_t>& residual) {
  residual.resize(cur.bytes.size());
  const uint8_t* c = cur.bytes.data();
  const uint8_t* p = prev.bytes.data();
  if (cur.desc.layout() == PassLayout::Bitmask)
    for (size_t i = 0; i < residual.size(); ++i) residual[i] = c[i] ^ p[i];
  else
    for (size_t i = 0; i < residual.size(); ++i) residual[i] = uint8_t(c[i] - p[i]);
}

void apply_residual(std::vector<uint8_t>& bytes, const PassBuffer& prev, PassKind kind) {
  const uint8_t* p = prev.bytes.data();
  if (pass_layout(kind) == PassLayout::Bitmask)
    for (size_t i = 0; i < bytes.size(); ++i) bytes[i] ^= p[i];
  else
    for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = uint8_t(bytes[i] + p[i]);
}

// The prediction with the planes outside `mask` cleared (zero: those planes are coded as they are).
void mask_planes(PassBuffer& prediction, uint64_t mask) {
  const PassDesc& d = prediction.desc;
  const int planes = plane_count(d);
  if (mask == all_planes(d)) return;
  const size_t stride = d.pixel_bytes();
  std::vector<uint8_t> keep(stride, 0);  // per byte of a pixel: what survives
  for (int p = 0; p < planes; ++p)
    if (mask >> p & 1) {
      if (d.layout() == PassLayout::Bitmask)
        keep[size_t(p / 8)] |= uint8_t(1u << (p % 8));
      else
        keep[size_t(p)] = 0xff;
    }
  for (size_t i = 0; i < prediction.bytes.size(); ++i) prediction.bytes[i] &= keep[i % stride];
}

// Plane `p` of `b` (its bit p, or byte p, of every pixel) as a one-plane buffer of the same
// kind; `minus`: the same plane of a prediction to subtract first (XOR for bitmasks).
void extract_plane(const PassBuffer& b, const PassBuffer* minus, int p, PassBuffer& out) {
  const PassDesc& d = b.desc;
  out.desc = {d.kind, d.width, d.height, 1, d.full_scale};
  const size_t n = size_t(d.width) * size_t(d.height), stride = d.pixel_bytes();
  out.bytes.resize(n);
  const uint8_t* c = b.bytes.data();
  const uint8_t* q = minus ? minus->bytes.data() : nullptr;
  if (d.layout() == PassLayout::Bitmask) {
    const size_t byte = size_t(p / 8);
    const int bit = p % 8;
    for (size_t i = 0; i < n; ++i) {
      const uint8_t v = uint8_t(c[i * stride + byte] ^ (q ? q[i * stride + byte] : 0));
      out.bytes[i] = uint8_t(v >> bit & 1);
    }
  } else {
    for (size_t i = 0; i < n; ++i)
      out.bytes[i] = uint8_t(c[i * stride + size_t(p)] - (q ? q[i * stride + size_t(p)] : 0));
  }
}

nlohmann::json inner_params(const std::string& inner, int level, const std::string& layout) {
  if (inner == "zstd") return {{"level", level}, {"layout", layout}};
  if (level == 1) return {{"mode", "fast"}, {"layout", layout}};
  if (level >= 3 && level <= 12) return {{"mode", "hc"}, {"level", level}, {"layout", layout}};
  fail("codec 'delta': level {} is not valid with inner lz4 (valid: 1 = fast, 3..12 = hc level)", level);
}

class DeltaCodec final : public Codec {
 public:
  explicit DeltaCodec(const Params& p)
      : keyframe_interval_(p.get_int("keyframe_interval")),
        references_(p.get_int("references")),
        plane_choice_(p.get_bool("plane_choice")),
        intra_check_(p.get_bool("intra_check")),
        inner_(registries().codecs.create(
            p.get_string("inner"), inner_params(p.get_string("inner"), p.get_int("level"), p.get_string("layout")))) {
    if (p.get_string("predictor") != "none")
      carrier_.emplace("delta",
                       registries().predictors.create(p.get_string("predictor"), {{"filter", p.get_string("filter")}}));
  }

  bool lossless() const override { return true; }
  bool stateful() const override { return true; }  // frames reference earlier ones
  std::string refuses(const PassDesc& desc) const override {
    if (carrier_ && (desc.layout() == PassLayout::Rgb8 || desc.layout() == PassLayout::Code16))
      return fmt::format(
          "delta with predictor reprojection carries lighting passes only ({} frames have no G-buffer "
          "prediction here; use predictor none)",
          pass_kind_name(desc.kind));
    return inner_->refuses(desc);
  }
  int gbuffers_referenced() const override { return carrier_ ? references_ : 0; }
  int holds() const override { return newest_reference(decoded_); }

  void encode(const PassBuffer& in, const EncodeOptions& options, std::vector<uint8_t>& out) override {
    const FrameContext& ctx = options.context;
    const uint32_t index = coded_frame_index("delta", in, options, carrier_.has_value(), next_index_, coded_frames_);
    const auto [ref_chosen, ref_gbuf] = choose_reference(
        coded_frames_, options, in.desc, since_key_ + 1 >= uint32_t(keyframe_interval_), carrier_.has_value());
    const Reference* ref = ref_chosen;

    uint64_t mask = 0;  // planes coded against the prediction
    if (ref) {
      const PassBuffer* prediction = &ref->buffer;  // without a predictor: the reference as it is
      mask = all_planes(in.desc);
      if (carrier_) {
        PassBuffer& predicted = carrier_->carry(*ref, *ref_gbuf, index, *ctx.gbuf);
        prediction = &predicted;
        if (plane_choice_ && plane_count(in.desc) > 1) {
          mask = choose_planes(in, predicted);
          mask_planes(predicted, mask);
        }
      }
      if (mask != 0) {
        residual_.desc = in.desc;
        make_residual(in, *prediction, residual_.bytes);
        inner_->encode(residual_, {}, coded_);
      }
      if (mask == 0 || (carrier_ && intra_check_)) {
        inner_->encode(in, {}, intra_);
        if (mask == 0 || intra_.size() <= coded_.size()) {
          ref = nullptr;  // coded alone: a keyframe
          coded_.swap(intra_);
        }
      }
    } else {
      inner_->encode(in, {}, coded_);
    }
    const size_t header = header_bytes();
    out.resize(header + coded_.size());
    put_frame_start(out.data(), {!ref, index, ref ? ref->frame : index});
    if (carrier_) {
      put_u32(out.data() + kHeaderBytes, crc32c(in.bytes));
      put_u64(out.data() + kHeaderBytes + 4, ref ? mask : 0);
    }
    std::memcpy(out.data() + header, coded_.data(), coded_.size());
    // Only now, after everything that can throw, does the state move on.
    since_key_ = ref ? since_key_ + 1 : 0;
    keep_reference(coded_frames_, {index, in}, references_);
    next_index_ = index + 1;
  }

  bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) override {
    return decode_in_context(in, desc, FrameContext{}, out, error);
  }

  bool decode_in_context(std::span<const uint8_t> in, const PassDesc& desc, const FrameContext& ctx, PassBuffer& out,
                         std::string& error) override {
    const size_t header = header_bytes();
    FrameStart start;
    if (error = read_frame_start("delta", in, header, start); !error.empty()) return false;
    const uint32_t index = start.index, reference = start.reference;
    const uint64_t mask = carrier_ ? get_u64(in.data() + kHeaderBytes + 4) : all_planes(desc);
    if (carrier_ && ((mask & ~all_planes(desc)) != 0 || (start.keyframe && mask != 0))) {
      error = fmt::format(
          "delta: plane mask {:#x} is not valid for a {} {} with {} planes (valid: {})", mask,
          start.keyframe ? "keyframe of" : "frame of", pass_kind_name(desc.kind), plane_count(desc),
          start.keyframe ? std::string("0 on a keyframe") : fmt::format("bits within {:#x}", all_planes(desc)));
      return false;
    }
    const Reference* ref = nullptr;
    if (!start.keyframe &&
        !(error = find_delta_reference("delta", decoded_, start, desc, ctx, carrier_.has_value(), ref)).empty())
      return false;
    PassBuffer decoded;
    if (!inner_->decode(in.subspan(header), desc, decoded, error)) {
      error = "delta: " + error;
      return false;
    }
    if (ref) {
      const PassBuffer* prediction = &ref->buffer;
      if (carrier_) {
        PassBuffer& predicted = carrier_->carry(*ref, *ctx.gbuffer_of(reference), index, *ctx.gbuf);
        mask_planes(predicted, mask);
        prediction = &predicted;
      }
      apply_residual(decoded.bytes, *prediction, desc.kind);
    }
    if (carrier_) {
      const uint32_t expected = get_u32(in.data() + kHeaderBytes), got = crc32c(decoded.bytes);
      if (got != expected) {
        error = fmt::format(
            "delta: frame {} reconstructed from frame {} does not match the server's (CRC-32C "
            "{:08x}, expected {:08x}): the two ends' predictions or references differ",
            index, reference, got, expected);
        return false;
      }
    }
    keep_reference(decoded_, {index, decoded}, references_);
    out = std::move(decoded);
    return true;
  }

  void reset() override {
    inner_->reset();
    if (carrier_) carrier_->reset();
    coded_frames_.clear();
    decoded_.clear();
    since_key_ = 0;
    next_index_ = 0;
  }

 private:
  // The planes to code against the prediction: those whose residual the inner coder codes
  // smaller than the plane itself (each plane coded alone, both ways).
  uint64_t choose_planes(const PassBuffer& cur, const PassBuffer& prediction) {
    uint64_t mask = 0;
    for (int p = 0; p < plane_count(cur.desc); ++p) {
      extract_plane(cur, nullptr, p, plane_);
      inner_->encode(plane_, {}, intra_);
      extract_plane(cur, &prediction, p, plane_);
      inner_->encode(plane_, {}, coded_);
      if (coded_.size() < intra_.size()) mask |= uint64_t(1) << p;
    }
    return mask;
  }

  size_t header_bytes() const { return kHeaderBytes + (carrier_ ? kPredictedBytes : 0); }

  int keyframe_interval_, references_;
  bool plane_choice_, intra_check_;
  std::unique_ptr<Codec> inner_;
  std::optional<ReferenceCarrier> carrier_;  // none: predictor none
  // Encoder state.
  std::deque<Reference> coded_frames_;
  uint32_t since_key_ = 0, next_index_ = 0;
  PassBuffer residual_, plane_;
  std::vector<uint8_t> coded_, intra_;
  // Decoder state.
  std::deque<Reference> decoded_;
};

}  // namespace

CodecEntry make_delta_codec() {
  return {
      "delta",
      "temporal delta (XOR / byte difference) against a frame the client holds, carried to this frame by "
      "reprojection or not, before lz4 or zstd; keyframes every N",
      {ParamSpec::choice("inner", "zstd", {"lz4", "zstd"}, "lossless coder of the residual"),
       ParamSpec::integer("level", 1, 1, 19, "zstd level; with lz4: 1 = fast, 3..12 = hc level"),
       ParamSpec::choice("layout", "planes", {"interleaved", "planes"},
                         "visibility bitmasks: one bit-plane per light, or the canonical per-pixel bytes"),
       ParamSpec::integer("keyframe_interval", 30, 1, 100000, "a keyframe every this many frames"),
       ParamSpec::choice("predictor", "none", {"none", "reprojection"},
                         "how the reference frame is carried to this frame: as it is, or reprojected through "
                         "both frames' G-buffers"),
       ParamSpec::choice("filter", "bilinear", {"nearest", "bilinear"},
                         "the reprojection's filter for 8-bit passes (bitmasks: always nearest)"),
       ParamSpec::integer("references", 8, 1, 64, "frames each end keeps as references (loss recovery)"),
       ParamSpec::boolean("plane_choice", true,
                          "with a predictor and several planes: predict only the planes (lights, channels) whose "
                          "residual the inner coder codes smaller than the plane itself"),
       ParamSpec::boolean("intra_check", true,
                          "with a predictor: also code the frame alone and send the smaller (a keyframe when it is)")},
      [](const Params& p) { return std::make_unique<DeltaCodec>(p); }};
}

}  // namespace dhr
