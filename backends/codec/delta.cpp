// delta: temporal prediction from the previous frame before a lossless coder. Beyond the
// paper (which codes every frame alone): a bitmask is XORed with the previous frame's bitmask
// and byte buffers (AO, soft visibility, colour) are coded as the byte difference mod 256,
// then the residual goes through lz4 or zstd (with their checksums and bit-plane layout).
// Where the camera holds still the residual is almost all zero; where it moves, the
// unprojected previous frame predicts badly: without the G-buffer this codec cannot reproject,
// so it only pays off for static or slow views. Reprojected deltas come with the frame loop.
//
// Stream: every output starts with a 9-byte header: type ('K' keyframe, 'D' delta), the
// frame's index and the index of the frame it was predicted from (uint32 little-endian). The
// decoder keeps its last decoded frame and refuses a delta whose reference it does not hold
// (a lost or skipped frame), so a loss never yields wrong bytes, only a failure until the next
// keyframe. Keyframes come every `keyframe_interval` frames, on
// EncodeOptions::force_keyframe, on the first frame, after reset() and when the buffer
// description changes.
//
// Parameters:
//   inner              lz4 | zstd             the lossless coder of the residual      default zstd
//   level              1..19                  zstd level; with lz4: 1 = fast, 3..12 = hc level
//                                                                                     default 1
//   layout             interleaved | planes   bitmask layout handed to the inner coder default planes
//   keyframe_interval  1..100000              a keyframe every this many frames       default 30
// Example: {"name": "delta", "params": {"inner": "zstd", "level": 1, "keyframe_interval": 30}}
#include "backends/register_all.h"
#include "core/backend.h"

#include <cstring>

namespace dhr {
namespace {

constexpr size_t kHeaderBytes = 9;
constexpr uint8_t kKeyframe = 'K', kDelta = 'D';

void put_u32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = uint8_t(v >> (8 * i));
}
uint32_t get_u32(const uint8_t* p) {
  return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}

// residual = cur - prev (XOR for bitmasks); apply(residual, prev) inverts it.
void make_residual(const PassBuffer& cur, const PassBuffer& prev, std::vector<uint8_t>& residual) {
  residual.resize(cur.bytes.size());
  const uint8_t* c = cur.bytes.data();
  const uint8_t* p = prev.bytes.data();
  if (cur.desc.kind == PassKind::Visibility)
    for (size_t i = 0; i < residual.size(); ++i) residual[i] = c[i] ^ p[i];
  else
    for (size_t i = 0; i < residual.size(); ++i) residual[i] = uint8_t(c[i] - p[i]);
}

void apply_residual(std::vector<uint8_t>& bytes, const PassBuffer& prev, PassKind kind) {
  const uint8_t* p = prev.bytes.data();
  if (kind == PassKind::Visibility)
    for (size_t i = 0; i < bytes.size(); ++i) bytes[i] ^= p[i];
  else
    for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = uint8_t(bytes[i] + p[i]);
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
        inner_(registries().codecs.create(
            p.get_string("inner"), inner_params(p.get_string("inner"), p.get_int("level"), p.get_string("layout")))) {}

  bool lossless() const override { return true; }
  bool stateful() const override { return true; }  // frames reference the previous one
  std::string refuses(const PassDesc& desc) const override { return inner_->refuses(desc); }

  void encode(const PassBuffer& in, const EncodeOptions& options, std::vector<uint8_t>& out) override {
    if (std::string why = in.desc.validate(); !why.empty()) fail("delta: invalid buffer description: {}", why);
    if (in.bytes.size() != in.desc.byte_size())
      fail("delta: a {}x{} {} buffer holds {} bytes, {} expected", in.desc.width, in.desc.height,
           pass_kind_name(in.desc.kind), in.bytes.size(), in.desc.byte_size());
    const bool key = options.force_keyframe || !has_prev_ || !(prev_.desc == in.desc) ||
                     since_key_ + 1 >= uint32_t(keyframe_interval_);
    const uint32_t index = next_index_;
    if (key) {
      inner_->encode(in, {}, coded_);
    } else {
      residual_.desc = in.desc;
      make_residual(in, prev_, residual_.bytes);
      inner_->encode(residual_, {}, coded_);
    }
    out.resize(kHeaderBytes + coded_.size());
    out[0] = key ? kKeyframe : kDelta;
    put_u32(out.data() + 1, index);
    put_u32(out.data() + 5, key ? index : prev_index_);
    std::memcpy(out.data() + kHeaderBytes, coded_.data(), coded_.size());
    // Only now, after everything that can throw, does the state move on.
    prev_.desc = in.desc;
    prev_.bytes = in.bytes;
    has_prev_ = true;
    prev_index_ = index;
    since_key_ = key ? 0 : since_key_ + 1;
    ++next_index_;
  }

  bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) override {
    if (in.size() < kHeaderBytes) {
      error = fmt::format("delta: {} bytes, shorter than the {}-byte header", in.size(), kHeaderBytes);
      return false;
    }
    const uint8_t type = in[0];
    const uint32_t index = get_u32(in.data() + 1), reference = get_u32(in.data() + 5);
    if (type != kKeyframe && type != kDelta) {
      error = fmt::format("delta: unknown frame type {:#04x}", type);
      return false;
    }
    if (type == kKeyframe && reference != index) {
      error = "delta: corrupt keyframe header";
      return false;
    }
    if (type == kDelta && !(has_ref_ && ref_index_ == reference && ref_.desc == desc)) {
      error = has_ref_ ? fmt::format("delta: frame {} needs frame {}, the decoder holds frame {}", index, reference,
                                     ref_index_)
                       : fmt::format("delta: frame {} needs frame {}, the decoder holds none", index, reference);
      return false;
    }
    PassBuffer decoded;
    if (!inner_->decode(in.subspan(kHeaderBytes), desc, decoded, error)) {
      error = "delta: " + error;
      return false;
    }
    if (type == kDelta) apply_residual(decoded.bytes, ref_, desc.kind);
    ref_ = decoded;
    ref_index_ = index;
    has_ref_ = true;
    out = std::move(decoded);
    return true;
  }

  void reset() override {
    inner_->reset();
    has_prev_ = has_ref_ = false;
    since_key_ = 0;
    next_index_ = 0;
  }

 private:
  int keyframe_interval_;
  std::unique_ptr<Codec> inner_;
  // Encoder state.
  PassBuffer prev_;
  bool has_prev_ = false;
  uint32_t prev_index_ = 0, since_key_ = 0, next_index_ = 0;
  PassBuffer residual_;
  std::vector<uint8_t> coded_;
  // Decoder state.
  PassBuffer ref_;
  bool has_ref_ = false;
  uint32_t ref_index_ = 0;
};

}  // namespace

CodecEntry make_delta_codec() {
  return {"delta",
          "previous-frame delta (XOR / byte difference, no reprojection) before lz4 or zstd; keyframes every N",
          {ParamSpec::choice("inner", "zstd", {"lz4", "zstd"}, "lossless coder of the residual"),
           ParamSpec::integer("level", 1, 1, 19, "zstd level; with lz4: 1 = fast, 3..12 = hc level"),
           ParamSpec::choice("layout", "planes", {"interleaved", "planes"},
                             "visibility bitmasks: one bit-plane per light, or the canonical per-pixel bytes"),
           ParamSpec::integer("keyframe_interval", 30, 1, 100000, "a keyframe every this many frames")},
          [](const Params& p) { return std::make_unique<DeltaCodec>(p); }};
}

}  // namespace dhr
