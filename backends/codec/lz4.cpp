// lz4: the LZ4 frame format (liblz4's LZ4F API, frame spec v1.6.2) with a block checksum and
// a content checksum (xxHash32) and the content size in the frame header, so that a corrupt
// or truncated frame is detected instead of decoding into wrong bytes (without checksums,
// single bit flips can decode without error into wrong bytes; tests/backends/test_codecs.cpp
// `CodecConformance.BitFlipsAreDetectedOrHarmless` holds lz4 to detecting them). The paper
// names LZ4 as the lossless codec for its bitmasks; fast mode is its choice for speed.
//
// Visibility bitmasks are coded as one bit-plane per light by default (core/buffers/buffer_layout.h);
// the layout is not stored in the frame: encoder and decoder take it from the same
// parameters, and the frame stays a standard LZ4 frame of the (planar) bytes.
//
// Parameters:
//   mode          fast | hc            LZ4 (fast) or LZ4-HC                       default fast
//   acceleration  1..65537 (fast)      larger = faster, larger output             default 1
//   level         3..12 (hc)           LZ4-HC level; LZ4F treats levels below 3   default 9
//                                      as fast mode, so hc starts at 3
//   layout        interleaved | planes how a Visibility buffer is coded           default planes
// Example: {"name": "lz4", "params": {"mode": "hc", "level": 9}}
//
// Decoding checks, before writing anything, that the frame declares checksums and exactly
// the content size the buffer description implies; any library error, trailing bytes after
// the frame, or a short frame returns false with a message.
#include "core/backend/backend.h"
#include "core/buffers/buffer_layout.h"

#include <lz4frame.h>

#include <cstring>

namespace dhr {
namespace {

class Lz4Codec final : public Codec {
 public:
  explicit Lz4Codec(const Params& p)
      : hc_(p.get_string("mode") == "hc"),
        acceleration_(p.get_int("acceleration")),
        level_(p.get_int("level")),
        layout_(parse_visibility_layout(p.get_string("layout"))) {
    if (LZ4F_isError(LZ4F_createCompressionContext(&cctx_, LZ4F_VERSION)) ||
        LZ4F_isError(LZ4F_createDecompressionContext(&dctx_, LZ4F_VERSION))) {
      LZ4F_freeCompressionContext(cctx_);
      LZ4F_freeDecompressionContext(dctx_);
      fail("lz4: cannot create LZ4F contexts (out of memory?)");
    }
  }
  ~Lz4Codec() override {
    LZ4F_freeCompressionContext(cctx_);
    LZ4F_freeDecompressionContext(dctx_);
  }
  Lz4Codec(const Lz4Codec&) = delete;
  Lz4Codec& operator=(const Lz4Codec&) = delete;

  bool lossless() const override { return true; }

  void encode(const PassBuffer& in, const EncodeOptions&, std::vector<uint8_t>& out) override {
    const std::span<const uint8_t> src = to_coded_layout(in, layout_, scratch_);
    const LZ4F_preferences_t prefs = preferences(src.size());
    const size_t capacity = LZ4F_HEADER_SIZE_MAX + LZ4F_compressBound(src.size(), &prefs);
    out.resize(capacity);
    size_t pos = 0;
    auto step = [&](size_t r, const char* call) {
      if (LZ4F_isError(r)) fail("lz4: {} failed: {}", call, LZ4F_getErrorName(r));
      pos += r;
    };
    step(LZ4F_compressBegin(cctx_, out.data(), capacity, &prefs), "LZ4F_compressBegin");
    if (!src.empty())
      step(LZ4F_compressUpdate(cctx_, out.data() + pos, capacity - pos, src.data(), src.size(), nullptr),
           "LZ4F_compressUpdate");
    step(LZ4F_compressEnd(cctx_, out.data() + pos, capacity - pos, nullptr), "LZ4F_compressEnd");
    out.resize(pos);
  }

  bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) override {
    if (decode_frame(in, desc, out, error)) return true;
    // liblz4 1.9.4's LZ4F_resetDecompressionContext() does not clear the remaining content
    // size of a frame left unfinished, and a frame without a declared size (the empty
    // buffer's) does not set it either: the next empty frame then fails with
    // ERROR_frameSize_wrong. A fresh context after every failure (a rare path) avoids that.
    LZ4F_dctx* fresh = nullptr;
    if (!LZ4F_isError(LZ4F_createDecompressionContext(&fresh, LZ4F_VERSION))) {
      LZ4F_freeDecompressionContext(dctx_);
      dctx_ = fresh;
    }
    return false;
  }

 private:
  bool decode_frame(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) {
    if (std::string why = desc.validate(); !why.empty()) {
      error = "lz4: invalid buffer description: " + why;
      return false;
    }
    if (in.empty()) {
      error = "lz4: empty input";
      return false;
    }
    const size_t expected = coded_size(desc, layout_);
    LZ4F_resetDecompressionContext(dctx_);
    LZ4F_frameInfo_t info{};
    size_t header_bytes = in.size();
    if (size_t r = LZ4F_getFrameInfo(dctx_, &info, in.data(), &header_bytes); LZ4F_isError(r)) {
      error = fmt::format("lz4: bad frame header: {}", LZ4F_getErrorName(r));
      return false;
    }
    if (info.frameType != LZ4F_frame || info.contentChecksumFlag != LZ4F_contentChecksumEnabled ||
        info.blockChecksumFlag != LZ4F_blockChecksumEnabled) {
      error = "lz4: frame without block and content checksums (not written by this codec)";
      return false;
    }
    // An LZ4 frame cannot declare a content size of 0 (0 means "not given"), so an empty
    // buffer's frame carries none; any other frame must declare exactly `expected`.
    if (info.contentSize != expected) {
      error = fmt::format("lz4: frame declares {} bytes of content, {} expected for a {}x{} {} buffer",
                          info.contentSize, expected, desc.width, desc.height, pass_kind_name(desc.kind));
      return false;
    }
    const bool convert = needs_layout_conversion(desc, layout_);
    std::vector<uint8_t>& dst = convert ? scratch_ : out.bytes;
    dst.resize(expected);
    uint8_t dummy = 0;  // LZ4F wants a valid pointer even for 0 bytes
    uint8_t* const dst_begin = expected ? dst.data() : &dummy;
    size_t src_pos = header_bytes, dst_pos = 0;
    for (;;) {
      size_t dst_size = expected - dst_pos;
      size_t src_size = in.size() - src_pos;
      const size_t r = LZ4F_decompress(dctx_, dst_begin + dst_pos, &dst_size, in.data() + src_pos, &src_size, nullptr);
      if (LZ4F_isError(r)) {
        error = fmt::format("lz4: corrupt frame: {}", LZ4F_getErrorName(r));
        return false;
      }
      src_pos += src_size;
      dst_pos += dst_size;
      if (r == 0) break;  // frame complete, checksums verified
      if (src_pos == in.size() || (src_size == 0 && dst_size == 0)) {
        error = fmt::format("lz4: truncated frame ({} of {} bytes decoded)", dst_pos, expected);
        return false;
      }
    }
    if (src_pos != in.size()) {
      error = fmt::format("lz4: {} trailing bytes after the frame", in.size() - src_pos);
      return false;
    }
    if (dst_pos != expected) {
      error = fmt::format("lz4: frame holds {} bytes, {} expected", dst_pos, expected);
      return false;
    }
    out.desc = desc;
    if (convert && !from_coded_planes(desc, scratch_, out.bytes, error)) {
      error = "lz4: " + error;
      return false;
    }
    return true;
  }

  LZ4F_preferences_t preferences(size_t content_size) const {
    LZ4F_preferences_t prefs;
    std::memset(&prefs, 0, sizeof prefs);
    prefs.frameInfo.blockMode = LZ4F_blockLinked;
    prefs.frameInfo.contentChecksumFlag = LZ4F_contentChecksumEnabled;
    prefs.frameInfo.blockChecksumFlag = LZ4F_blockChecksumEnabled;
    prefs.frameInfo.contentSize = content_size;
    // LZ4F: a negative level -a means fast mode with acceleration a + 1.
    prefs.compressionLevel = hc_ ? level_ : 1 - acceleration_;
    return prefs;
  }

  bool hc_;
  int acceleration_;
  int level_;
  VisibilityLayout layout_;
  LZ4F_cctx* cctx_ = nullptr;
  LZ4F_dctx* dctx_ = nullptr;
  std::vector<uint8_t> scratch_;  // planar bytes of a Visibility buffer
};

}  // namespace

CodecEntry make_lz4_codec() {
  return {"lz4",
          "LZ4 frame (liblz4) with block and content checksums; bitmasks as bit-planes",
          {ParamSpec::choice("mode", "fast", {"fast", "hc"}, "LZ4 fast or LZ4-HC"),
           ParamSpec::integer("acceleration", 1, 1, 65537, "fast mode: larger is faster with a larger output"),
           ParamSpec::integer("level", 9, 3, 12, "hc mode: LZ4-HC compression level"),
           ParamSpec::choice("layout", "planes", {"interleaved", "planes"},
                             "visibility bitmasks: one bit-plane per light, or the canonical per-pixel bytes")},
          [](const Params& p) { return std::make_unique<Lz4Codec>(p); }};
}

}  // namespace dhr
