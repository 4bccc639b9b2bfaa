// raw: the buffer's bytes as they are, no compression. The baseline every codec is measured
// against, and the paper's uncompressed remote-rendering frame.
//
// Parameters: none.   Example: {"name": "raw"}
#include "core/backend/backend.h"

#include <algorithm>

namespace dhr {
namespace {

class RawCodec final : public Codec {
 public:
  bool lossless() const override { return true; }
  void encode(const PassBuffer& in, const EncodeOptions&, std::vector<uint8_t>& out) override {
    out.assign(in.bytes.begin(), in.bytes.end());
  }
  bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) override {
    if (std::string why = desc.validate(); !why.empty()) {
      error = "raw: invalid buffer description: " + why;
      return false;
    }
    if (in.size() != desc.byte_size()) {
      error = fmt::format("raw: {} bytes received, {} expected for a {}x{} {} buffer", in.size(), desc.byte_size(),
                          desc.width, desc.height, pass_kind_name(desc.kind));
      return false;
    }
    out.desc = desc;
    out.bytes.assign(in.begin(), in.end());
    return true;
  }
};

}  // namespace

CodecEntry make_raw_codec() {
  return {"raw", "uncompressed bytes (the baseline)", {}, [](const Params&) { return std::make_unique<RawCodec>(); }};
}

}  // namespace dhr
