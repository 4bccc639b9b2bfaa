// libFuzzer target: every registered codec's decode() on arbitrary bytes. Codecs are taken from
// registries().codecs.entries(), so a codec added later is fuzzed with no change here: one
// instance with default parameters, plus one per value of each choice parameter (layouts and
// modes often change the decoder's path). Input: the codec's name, a 0 byte, a variant byte
// (which of its instances), 8 bytes giving two PassDescs (a third is fixed), then the encoded
// stream; an unknown name picks an instance from its first byte. One instance per input keeps
// runs fast (a video codec's reset() is expensive). Checked: decode() never crashes or throws, and
// when it returns true the buffer has exactly the description's size. The input also drives a
// round trip: the bytes, made a valid buffer of the first description, are encoded and
// decoded, and a lossless codec must give them back exactly.
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "tests/fuzz/fuzz_common.h"

#include <algorithm>
#include <memory>
#include <string>
#include <vector>

namespace {

using namespace dhr;

struct Instance {
  std::string name;
  std::string label;
  std::unique_ptr<Codec> codec;
};

std::vector<Instance> make_instances() {
  std::vector<Instance> out;
  for (const auto& e : registries().codecs.entries()) {
    std::vector<nlohmann::json> variants{nlohmann::json::object()};
    for (const auto& spec : e.params)
      for (const auto& choice : spec.choices)
        if (choice != spec.default_value) variants.push_back({{spec.name, choice}});
    for (const auto& params : variants) {
      try {
        out.push_back({e.name, e.name + params.dump(), registries().codecs.create(e.name, params)});
      } catch (const Error&) {
        // A combination the codec refuses at creation (a parameter depending on another).
      }
    }
  }
  return out;
}

PassDesc desc_from(uint8_t b0, uint8_t b1, uint8_t b2, uint8_t b3) {
  PassDesc d;
  d.kind = PassKind(1 + b0 % 4);
  d.width = b1 % 49;  // 0..48: small, so that decoding stays fast; 0 tests empty buffers
  d.height = b2 % 49;
  d.full_scale = 1 + (b0 >> 2) % 255;
  // Depth: a colour byte pattern with b3's high bit set (older seeds keep their kinds); its
  // full_scale is the code's bits, 8..16.
  if (d.kind == PassKind::Colour && (b3 & 0x80)) {
    d.kind = PassKind::Depth;
    d.full_scale = 8 + (b0 >> 2) % 9;
  }
  // Channels within the kind's range (core/buffers/pass_buffer.cpp), at most 8 planes of 8 bits.
  const PassKindInfo& k = *find_pass_kind(uint8_t(d.kind));
  const int most = k.layout == PassLayout::Bitmask ? k.max_channels : std::min(k.max_channels, 8);
  d.channels = k.min_channels + b3 % (most - k.min_channels + 1);
  return d;
}

// A buffer that is valid for `desc` (values within full_scale, unused bitmask bits zero),
// filled from `src` (cycled).
PassBuffer buffer_from(const PassDesc& desc, std::span<const uint8_t> src) {
  PassBuffer b{desc, std::vector<uint8_t>(desc.byte_size(), 0)};
  if (src.empty()) return b;
  for (size_t i = 0; i < b.bytes.size(); ++i) b.bytes[i] = src[i % src.size()];
  if (desc.layout() == PassLayout::Planes8)
    for (auto& v : b.bytes) v = uint8_t(v % (desc.full_scale + 1));
  if (desc.layout() == PassLayout::Bitmask && desc.channels % 8) {
    const size_t per_pixel = size_t((desc.channels + 7) / 8);
    const uint8_t last_mask = uint8_t((1u << (desc.channels % 8)) - 1);
    for (size_t i = per_pixel - 1; i < b.bytes.size(); i += per_pixel) b.bytes[i] &= last_mask;
  }
  return b;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static std::vector<Instance> instances = make_instances();
  if (instances.empty() || size == 0) return 0;
  // Select the instance: by name when the input starts with a registered codec's name.
  const size_t name_end = size_t(std::find(data, data + std::min<size_t>(size, 32), 0) - data);
  const std::string name(reinterpret_cast<const char*>(data), name_end < size ? name_end : 0);
  std::vector<Instance*> named;
  for (auto& inst : instances)
    if (inst.name == name) named.push_back(&inst);
  size_t pos = name_end < size ? name_end + 1 : 1;
  const uint8_t variant = pos < size ? data[pos++] : 0;
  Instance& inst = named.empty() ? instances[data[0] % instances.size()] : *named[variant % named.size()];
  if (size - std::min(pos, size) < 8) return 0;
  const uint8_t* d = data + pos;
  const PassDesc descs[3] = {desc_from(d[0], d[1], d[2], d[3]), desc_from(d[4], d[5], d[6], d[7]),
                             PassDesc{PassKind(1 + d[0] % 4), 16, 16, d[0] % 4 == 3 ? 3 : 1, 255}};
  const std::span<const uint8_t> stream(d + 8, size - pos - 8);

  Codec& c = *inst.codec;
  for (const PassDesc& desc : descs) {
    c.reset();
    PassBuffer out;
    std::string error;
    if (c.decode(stream, desc, out, error)) {
      DHR_FUZZ_CHECK(out.desc == desc);
      DHR_FUZZ_CHECK(out.bytes.size() == desc.byte_size());
    } else {
      DHR_FUZZ_CHECK(!error.empty());
    }
  }
  // Round trip of a valid buffer made from the input.
  const PassDesc& desc = descs[0];
  if (!c.refuses(desc).empty()) return 0;
  const PassBuffer in = buffer_from(desc, stream);
  c.reset();
  std::vector<uint8_t> encoded;
  EncodeOptions options = EncodeOptions::keyframe();
  GBuffer blank;  // a codec that predicts through G-buffers needs this frame's, even for a keyframe
  if (c.gbuffers_referenced() > 0) {
    blank.resize(desc.width, desc.height);
    options.context = {0, &blank, {}};
  }
  c.encode(in, options, encoded);
  c.reset();
  PassBuffer out;
  std::string error;
  const bool ok = c.decode(encoded, desc, out, error);
  if (!ok) std::fprintf(stderr, "%s: round trip failed: %s\n", inst.label.c_str(), error.c_str());
  DHR_FUZZ_CHECK(ok);
  DHR_FUZZ_CHECK(out.bytes.size() == desc.byte_size());
  if (c.lossless()) DHR_FUZZ_CHECK(out.bytes == in.bytes);
  return 0;
}
