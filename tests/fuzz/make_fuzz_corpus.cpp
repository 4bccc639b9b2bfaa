// Writes the seed corpora of the fuzz targets into DIR/<target>/ (tests/fuzz/corpus/ in the
// repository). Seeds are small valid inputs the fuzzer mutates from: real packets for the
// header parser, programs that exercise every assembler operation, and each codec's own
// output for the decoders. Usage: make_fuzz_corpus DIR (rerun after a format change).
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "core/base/rng.h"
#include "core/live/live_protocol.h"
#include "core/net/packet.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace {

using namespace dhr;
namespace fs = std::filesystem;
using Bytes = std::vector<uint8_t>;

void write(const fs::path& dir, const std::string& name, const Bytes& b) {
  fs::create_directories(dir);
  std::ofstream f(dir / name, std::ios::binary);
  f.write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
  if (!f) fail("make_fuzz_corpus: cannot write {}", (dir / name).string());
}

Bytes pattern(size_t n, uint32_t salt) {
  Bytes b(n);
  for (size_t i = 0; i < n; ++i) b[i] = uint8_t(i / 7 + (rng_bits({salt, uint32_t(i)}) & 7));
  return b;
}

void header_seeds(const fs::path& dir) {
  PacketMeta m;
  m.stream_id = 1;
  m.desc = {PassKind::Ao, 32, 24, 1, 16};
  m.codec_id = codec_id("zstd");
  m.frame_id = 42;
  m.first_sequence = 1000;
  write(dir, "single", packetize(m, pattern(60, 1))[0]);
  const auto three = packetize(m, pattern(250, 2), 100);
  write(dir, "first_of_3", three[0]);
  write(dir, "last_of_3", three[2]);
  write(dir, "empty_pass", packetize(m, {})[0]);
  m.desc = {PassKind::Visibility, 16, 16, 64, 255};
  write(dir, "visibility64", packetize(m, pattern(40, 3))[0]);
  m.desc = {PassKind::Colour, 20, 10, 3, 255};
  m.first_sequence = 0xFFFFFFFF;  // wraps inside the pass
  write(dir, "colour_wrap", packetize(m, pattern(30, 4), 16)[1]);
  auto bad = three[1];
  bad[0] = 'X';
  write(dir, "bad_magic", bad);
  write(dir, "header_only", Bytes(three[1].begin(), three[1].begin() + kPacketHeaderBytes));
  // Live mode's control messages share the target (the server and client parse both).
  ControlMessage c;
  c.type = ControlType::Hello;
  c.text = R"({"protocol": 1, "width": 320, "height": 180})";
  write(dir, "control_hello", encode_control(c));
  c.type = ControlType::Camera;
  c.session = 0x12345679;
  c.camera.frame = 17;
  c.camera.scene_time_s = 0.25;
  c.camera.camera = Camera::look_at({1, 2, 3}, {0, 1, 0}, {0, 1, 0}, 60.0f, 320, 180, 0.05f, 100.0f);
  c.camera.holds[1] = 12;  // after a loss: the AO stream's decoder holds frame 12
  write(dir, "control_camera", encode_control(c));
  c.type = ControlType::Bye;
  c.text = "client done";
  write(dir, "control_bye", encode_control(c));
}

// Programs for fuzz_assembler (see its LLVMFuzzerTestOneInput): 5 configuration bytes, then
// operations [op][pick lo][pick hi] with operands after some of them.
struct Program {
  Bytes b;
  explicit Program(uint8_t in_flight, uint8_t streams, uint8_t budget, uint8_t timeout, uint8_t flags)
      : b{in_flight, streams, budget, timeout, flags} {}
  Program& op(uint8_t code, uint16_t pick = 0) {
    b.insert(b.end(), {code, uint8_t(pick), uint8_t(pick >> 8)});
    return *this;
  }
  Program& gen(uint8_t stream, uint16_t size, uint16_t chunk, uint8_t tick = 0) {
    op(uint8_t(0 | tick));
    b.insert(b.end(), {stream, uint8_t(size), uint8_t(size >> 8), uint8_t(chunk), uint8_t(chunk >> 8)});
    return *this;
  }
  Program& raw(const Bytes& d, bool reseal) {
    op(uint8_t(7 | (reseal ? 8 : 0)), uint16_t(d.size()));
    b.insert(b.end(), d.begin(), d.end());
    return *this;
  }
};

constexpr uint8_t kTick = 0x10 | (3 << 5);  // poll after advancing the clock 3 ms

void assembler_seeds(const fs::path& dir) {
  Program in_order(7, 3, 1, 50, 0);
  for (int f = 0; f < 3; ++f) {
    in_order.gen(uint8_t(f % 2), uint16_t(1000 + 900 * f), 399);
    for (int k = 0; k < 5; ++k) in_order.op(1 | kTick);
  }
  write(dir, "in_order", in_order.b);

  Program shuffled(3, 2, 0, 20, 1);
  shuffled.gen(0, 3000, 500).gen(1, 0, 100).gen(0, 2400, 800).gen(2, 5999, 1200);
  for (int k = 0; k < 16; ++k) shuffled.op(uint8_t(k % 3 == 0 ? 3 : 2), uint16_t(k * 7919));
  shuffled.op(1 | kTick);
  write(dir, "shuffled_duplicates", shuffled.b);

  Program lossy(1, 1, 0, 5, 0);
  lossy.gen(0, 4000, 1000).op(4, 1).op(5, 2);
  lossy.b.insert(lossy.b.end(), {0x34, 0x12});
  lossy.op(6, 0);
  lossy.b.insert(lossy.b.end(), {20, 0});
  for (int k = 0; k < 6; ++k) lossy.op(1 | kTick);
  lossy.gen(0, 100, 1300).op(1);  // chunk above the limit
  write(dir, "loss_corruption_timeout", lossy.b);

  PacketMeta m;
  m.desc = {PassKind::SoftVisibility, 8, 8, 2, 64};
  Program raw(4, 2, 0, 100, 2);
  for (const auto& d : packetize(m, pattern(300, 5), 128)) raw.raw(d, true);
  raw.raw(pattern(50, 6), false).op(1 | kTick);
  write(dir, "raw_resealed", raw.b);
}

// Seeds for fuzz_decoders: codec name, 0, variant 0, two descriptions, the codec's own output.
// desc bytes for fuzz_decoders' desc_from(): kind, width, height, channels, full_scale <= 64.
Bytes desc_bytes(const PassDesc& d) {
  if (d.kind == PassKind::Depth)  // fuzz_decoders' desc_from: a colour pattern with b3's high bit
    return {uint8_t((int(PassKind::Colour) - 1) | (d.full_scale - 8) << 2), uint8_t(d.width), uint8_t(d.height), 0x81};
  const uint8_t b0 = uint8_t((int(d.kind) - 1) | ((d.full_scale - 1) % 64) << 2);
  return {b0, uint8_t(d.width), uint8_t(d.height), uint8_t(d.channels - 1)};
}

// A fuzz_decoders input: the codec's name, a 0 byte, the variant, the description twice (the
// decoder is tried with both) and the coded stream.
Bytes decoder_seed(const std::string& codec, uint8_t variant, const PassDesc& d, const Bytes& encoded) {
  Bytes seed(codec.begin(), codec.end());
  seed.push_back(0);  // end of the name
  seed.push_back(variant);
  const Bytes desc = desc_bytes(d);
  seed.insert(seed.end(), desc.begin(), desc.end());
  seed.insert(seed.end(), desc.begin(), desc.end());
  seed.insert(seed.end(), encoded.begin(), encoded.end());
  return seed;
}

// A buffer of `d` filled with pattern(salt), its 8-bit samples kept within full_scale.
PassBuffer valid_buffer(const PassDesc& d, uint32_t salt) {
  PassBuffer in{d, pattern(d.byte_size(), salt)};
  if (d.kind == PassKind::Ao || d.kind == PassKind::SoftVisibility)
    for (auto& v : in.bytes) v = uint8_t(v % (d.full_scale + 1));
  return in;
}

void decoder_seeds(const fs::path& dir) {
  const PassDesc descs[] = {{PassKind::Ao, 16, 16, 1, 16},
                            {PassKind::Colour, 16, 12, 3, 1},
                            {PassKind::Visibility, 12, 12, 8, 1},
                            {PassKind::SoftVisibility, 10, 10, 2, 32},
                            {PassKind::Depth, 12, 10, 2, 12}};
  for (const auto& e : registries().codecs.entries()) {
    auto codec = registries().codecs.create(e.name, nlohmann::json::object());
    for (const auto& d : descs) {
      if (!codec->refuses(d).empty()) continue;
      const PassBuffer in = valid_buffer(d, 7);
      Bytes encoded;
      codec->reset();
      codec->encode(in, EncodeOptions::keyframe(), encoded);
      write(dir, e.name + "_" + pass_kind_name(d.kind), decoder_seed(e.name, 0, d, encoded));  // 0: default parameters
    }
  }
  // Codecs predicting through G-buffers (delta, delta_video): keyframes (which need no
  // prediction to decode), under the variant index fuzz_decoders gives {"predictor":
  // "reprojection"} (its variants: the defaults, then each non-default choice of each parameter,
  // in the parameters' order).
  int predicting = 0;
  for (const auto& e : registries().codecs.entries()) {
    int variant = 1, reprojection = -1;
    for (const auto& spec : e.params)
      for (const auto& choice : spec.choices) {
        if (choice == spec.default_value) continue;
        if (spec.name == "predictor" && choice == "reprojection") reprojection = variant;
        ++variant;
      }
    if (reprojection < 0) continue;
    ++predicting;
    auto codec = registries().codecs.create(e.name, {{"predictor", "reprojection"}});
    for (const auto& d : descs) {
      if (!codec->refuses(d).empty()) continue;
      const PassBuffer in = valid_buffer(d, 11);
      GBuffer blank;
      blank.resize(d.width, d.height);
      EncodeOptions options = EncodeOptions::keyframe();
      options.context = {0, &blank, {}};
      Bytes encoded;
      codec->reset();
      codec->encode(in, options, encoded);
      write(dir, e.name + "_reprojection_" + pass_kind_name(d.kind),
            decoder_seed(e.name, uint8_t(reprojection), d, encoded));
    }
  }
  if (predicting == 0) throw Error("make_fuzz_corpus: no codec has a predictor 'reprojection' (delta had)");
  write(dir, "unknown_name", Bytes{'?', 0, 0, 0, 16, 16, 0, 1, 1, 1, 0, 0xFF});
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: make_fuzz_corpus DIR  (writes DIR/fuzz_<target>/...)\n");
    return 2;
  }
  try {
    const fs::path root = argv[1];
    header_seeds(root / "fuzz_packet_header");
    assembler_seeds(root / "fuzz_assembler");
    decoder_seeds(root / "fuzz_decoders");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "make_fuzz_corpus: %s\n", e.what());
    return 1;
  }
  return 0;
}
