// zstd: a Zstandard frame (libzstd, RFC 8878) with the content size in the frame header and
// the content checksum (XXH64, low 32 bits) on, so that corrupt or truncated data is detected
// instead of decoding into wrong bytes. One compression and one decompression context are
// kept for the codec's life: creating them per frame costs more than coding a small frame.
//
// Level 1 is the default: on noisy 8-ray AO it is both smaller and faster than level 3.
// Visibility bitmasks are coded as one bit-plane per light by default (core/buffers/buffer_layout.h);
// the layout is not stored in the frame: encoder and decoder take it from the same
// parameters, and the frame stays a standard Zstandard frame.
//
// Parameters:
//   level    1..19                  compression level                       default 1
//   layout   interleaved | planes   how a Visibility buffer is coded        default planes
// Example: {"name": "zstd", "params": {"level": 3, "layout": "interleaved"}}
//
// Decoding checks, before writing anything, that the frame declares exactly the content
// size the buffer description implies (unknown or unreadable sizes are rejected), that it
// carries a checksum and that no bytes follow it.
#include "core/backend/backend.h"
#include "core/buffers/buffer_layout.h"

#include <zstd.h>

namespace dhr {
namespace {

constexpr uint32_t kZstdMagic = 0xFD2FB528u;  // RFC 8878, 3.1.1

class ZstdCodec final : public Codec {
 public:
  explicit ZstdCodec(const Params& p)
      : level_(p.get_int("level")), layout_(parse_visibility_layout(p.get_string("layout"))) {
    cctx_ = ZSTD_createCCtx();
    dctx_ = ZSTD_createDCtx();
    if (!cctx_ || !dctx_) {
      ZSTD_freeCCtx(cctx_);
      ZSTD_freeDCtx(dctx_);
      fail("zstd: cannot create contexts (out of memory?)");
    }
    check(ZSTD_CCtx_setParameter(cctx_, ZSTD_c_compressionLevel, level_), "set level");
    check(ZSTD_CCtx_setParameter(cctx_, ZSTD_c_checksumFlag, 1), "set checksum flag");
    check(ZSTD_CCtx_setParameter(cctx_, ZSTD_c_contentSizeFlag, 1), "set content size flag");
  }
  ~ZstdCodec() override {
    ZSTD_freeCCtx(cctx_);
    ZSTD_freeDCtx(dctx_);
  }
  ZstdCodec(const ZstdCodec&) = delete;
  ZstdCodec& operator=(const ZstdCodec&) = delete;

  bool lossless() const override { return true; }

  void encode(const PassBuffer& in, const EncodeOptions&, std::vector<uint8_t>& out) override {
    const std::span<const uint8_t> src = to_coded_layout(in, layout_, scratch_);
    out.resize(ZSTD_compressBound(src.size()));
    // compress2 resets the session and pledges src.size(), which puts it in the header.
    const size_t r = ZSTD_compress2(cctx_, out.data(), out.size(), src.data(), src.size());
    check(r, "ZSTD_compress2");
    out.resize(r);
  }

  bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) override {
    if (std::string why = desc.validate(); !why.empty()) {
      error = "zstd: invalid buffer description: " + why;
      return false;
    }
    const size_t expected = coded_size(desc, layout_);
    const unsigned long long declared = ZSTD_getFrameContentSize(in.data(), in.size());
    if (declared == ZSTD_CONTENTSIZE_ERROR) {
      error = fmt::format("zstd: not a zstd frame or header truncated ({} bytes)", in.size());
      return false;
    }
    if (declared == ZSTD_CONTENTSIZE_UNKNOWN) {
      error = "zstd: frame does not declare its content size";
      return false;
    }
    if (declared != expected) {
      error = fmt::format("zstd: frame declares {} bytes of content, {} expected for a {}x{} {} buffer", declared,
                          expected, desc.width, desc.height, pass_kind_name(desc.kind));
      return false;
    }
    // Frame header descriptor, bit 2 = content checksum flag (RFC 8878, 3.1.1.1.1). The
    // header is at least 6 bytes once its content size was readable. A skippable frame
    // reports a content size of 0, so the magic number is checked too.
    const uint32_t magic = uint32_t(in[0]) | uint32_t(in[1]) << 8 | uint32_t(in[2]) << 16 | uint32_t(in[3]) << 24;
    if (magic != kZstdMagic || !(in[4] & 0x04)) {
      error = "zstd: frame without a content checksum (not written by this codec)";
      return false;
    }
    const size_t frame_bytes = ZSTD_findFrameCompressedSize(in.data(), in.size());
    if (ZSTD_isError(frame_bytes)) {
      error = fmt::format("zstd: corrupt or truncated frame: {}", ZSTD_getErrorName(frame_bytes));
      return false;
    }
    if (frame_bytes != in.size()) {
      error = fmt::format("zstd: {} trailing bytes after the frame", in.size() - frame_bytes);
      return false;
    }
    const bool convert = needs_layout_conversion(desc, layout_);
    std::vector<uint8_t>& dst = convert ? scratch_ : out.bytes;
    dst.resize(expected);
    uint8_t dummy = 0;
    const size_t r = ZSTD_decompressDCtx(dctx_, expected ? dst.data() : &dummy, expected, in.data(), in.size());
    if (ZSTD_isError(r)) {
      error = fmt::format("zstd: corrupt frame: {}", ZSTD_getErrorName(r));
      return false;
    }
    if (r != expected) {
      error = fmt::format("zstd: frame holds {} bytes, {} expected", r, expected);
      return false;
    }
    out.desc = desc;
    if (convert && !from_coded_planes(desc, scratch_, out.bytes, error)) {
      error = "zstd: " + error;
      return false;
    }
    return true;
  }

 private:
  static void check(size_t r, const char* what) {
    if (ZSTD_isError(r)) fail("zstd: {} failed: {}", what, ZSTD_getErrorName(r));
  }

  int level_;
  VisibilityLayout layout_;
  ZSTD_CCtx* cctx_ = nullptr;
  ZSTD_DCtx* dctx_ = nullptr;
  std::vector<uint8_t> scratch_;  // planar bytes of a Visibility buffer
};

}  // namespace

CodecEntry make_zstd_codec() {
  return {"zstd",
          "Zstandard frame (libzstd) with content size and checksum; bitmasks as bit-planes",
          {ParamSpec::integer("level", 1, 1, 19, "compression level (1: smallest and fastest on noisy AO)"),
           ParamSpec::choice("layout", "planes", {"interleaved", "planes"},
                             "visibility bitmasks: one bit-plane per light, or the canonical per-pixel bytes")},
          [](const Params& p) { return std::make_unique<ZstdCodec>(p); }};
}

}  // namespace dhr
