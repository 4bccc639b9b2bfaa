// Codec conformance over every registered codec (pbrt-v4 style: one loop over all
// implementations checks the shared promises), plus the layout conversions and what is
// specific to lz4/zstd (checksums), h264 (a standard bitstream, keyframes, state) and delta.
//
// The conformance suite is value-parameterised over the registry, so every codec shows up by
// name in the output (CodecConformance/...) and a newly registered codec is tested without
// editing this file: Defaults/<codec> runs each codec at its default parameters,
// Configurations/<codec>_<params> the further configurations listed below, and
// Throwaway/<codec> a codec registered only here, in a local Registries object, to show that
// the loops pick up whatever a registry holds. What the suite checks is chosen from the
// codec itself: refuses(desc) skips the pass layouts it cannot carry, lossless() picks
// bit-exact or bounded-error checks, stateful() the loss and keyframe behaviour.
#include "backends/register_all.h"
#include "core/backend/backend.h"
#include "core/base/checksum.h"
#include "core/base/rng.h"
#include "core/base/stream_dump.h"
#include "core/buffers/buffer_layout.h"
#include "core/buffers/depth_pass.h"
#include "core/buffers/gbuffer.h"
#include "tests/support_buffers.h"

#include <gtest/gtest.h>

extern "C" {
#include <libavcodec/avcodec.h>
#include <libavutil/log.h>
}

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <numeric>
#include <limits>
#include <map>
#include <optional>
#include <ostream>
#include <set>

namespace dhr {
namespace {

using nlohmann::json;
using test::SyntheticView;

// Parameters that make a codec that is lossy by default lossless (its lossless configuration
// is then tested bit-exact too). A lossy codec without an entry is tested at its defaults only,
// with bounded-error checks.
const std::map<std::string, json>& lossless_params() {
  static const std::map<std::string, json> m{{"h264", {{"rate_control", "lossless"}}},
                                             {"hevc", {{"rate_control", "lossless"}}},
                                             {"av1", {{"rate_control", "lossless"}}}};
  return m;
}

// Further configurations worth the whole suite: other modes and layouts of the same codec.
const std::multimap<std::string, json>& extra_params() {
  static const std::multimap<std::string, json> m{
      {"lz4", {{"mode", "hc"}, {"level", 9}}},
      {"lz4", {{"layout", "interleaved"}, {"acceleration", 8}}},
      {"zstd", {{"level", 9}}},
      {"zstd", {{"layout", "interleaved"}}},
      {"delta", {{"inner", "lz4"}, {"keyframe_interval", 2}}},
      {"h264", {{"intra_refresh", true}, {"gop", 4}}},
  };
  return m;
}

// What the Codec interface cannot tell, for the codecs that promise less than the rest. A new
// codec needs no entry: it is held to every promise (checksummed frames, exact framing,
// validated input) until an entry here says why it cannot be.
struct Exemption {
  bool no_checksum = false;        // a corrupt frame may decode into wrong bytes
  bool loose_framing = false;      // trailing bytes and some prefixes of a frame still decode
  bool accepts_any_bytes = false;  // decodes any right-sized bytes; copies any input unchecked
  const char* why = "";
  bool half_frame_decodes = false;  // the first half of a one-slice frame may decode (wrongly)
};
const std::map<std::string, Exemption>& exemptions() {
  static const std::map<std::string, Exemption> m{
      {"raw", {true, false, true, "the baseline: the buffer's bytes as they are, no header"}},
      {"h264",
       {true, true, false,
        "a standard Annex-B stream: no checksum, trailing zeros are legal, "
        "a prefix holds whole slices"}},
      {"hevc",
       {true, true, false,
        "a standard Annex-B stream: no checksum, trailing zeros are legal, a prefix holds whole slices; "
        "libavcodec's HEVC decoder does not notice a slice cut short inside its CABAC data",
        true}},
      {"av1", {true, true, false, "standard OBUs: no checksum, trailing bits and padding OBUs are legal"}},
  };
  return m;
}
Exemption exemption(const std::string& name) {
  auto it = exemptions().find(name);
  return it == exemptions().end() ? Exemption{} : it->second;
}

// The default of a codec's `inner` parameter (the codec it wraps), or "".
std::string inner_default(const Registry<Codec>& registry, const std::string& name) {
  for (const ParamSpec& p : registry.get(name).params)
    if (p.name == "inner" && p.default_value.is_string()) return p.default_value.get<std::string>();
  return {};
}

// One codec configuration under test: a registry (the global one, or a local one), a codec
// name and its parameters.
struct Variant {
  const Registry<Codec>* registry = nullptr;
  std::string name;
  json params = json::object();
  std::string label() const { return name + params.dump(); }
  std::unique_ptr<Codec> create() const { return registry->create(name, params); }
};
void PrintTo(const Variant& v, std::ostream* os) { *os << v.label(); }

// Every codec of `registry` at its defaults.
std::vector<Variant> default_variants(const Registry<Codec>& registry) {
  std::vector<Variant> v;
  for (const auto& e : registry.entries()) v.push_back({&registry, e.name, json::object()});
  return v;
}

// The lossless configurations of lossy codecs, and the further configurations.
std::vector<Variant> configured_variants(const Registry<Codec>& registry) {
  std::vector<Variant> v;
  for (const auto& e : registry.entries()) {
    if (auto it = lossless_params().find(e.name); it != lossless_params().end())
      v.push_back({&registry, e.name, it->second});
    auto [first, last] = extra_params().equal_range(e.name);
    for (auto it = first; it != last; ++it) v.push_back({&registry, e.name, it->second});
  }
  return v;
}

// "lz4_mode_hc_level_9": the codec name, then each parameter, as a GoogleTest name.
std::string variant_test_name(const ::testing::TestParamInfo<Variant>& info) {
  std::string s = info.param.name;
  for (const auto& [k, value] : info.param.params.items())
    s += "_" + k + "_" + (value.is_string() ? value.get<std::string>() : value.dump());
  for (char& c : s)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return s;
}

// ---- the throwaway codec: registered only in a local Registries object below.
//
// crc_copy: the buffer's bytes behind a 9-byte header (magic 'T', CRC-32C of the payload,
// payload size), lossless and stateless; it refuses colour, so that refusal is exercised too.
class CrcCopyCodec final : public Codec {
 public:
  bool lossless() const override { return true; }
  std::string refuses(const PassDesc& desc) const override {
    return desc.kind == PassKind::Colour ? "crc_copy carries no colour (a test codec)" : "";
  }
  void encode(const PassBuffer& in, const EncodeOptions&, std::vector<uint8_t>& out) override {
    if (std::string why = refuses(in.desc); !why.empty()) fail("crc_copy: {}", why);
    if (std::string why = in.desc.validate(); !why.empty()) fail("crc_copy: {}", why);
    if (in.bytes.size() != in.desc.byte_size())
      fail("crc_copy: {} bytes for a {}-byte buffer", in.bytes.size(), in.desc.byte_size());
    out.assign(kHeader, 0);
    out[0] = 'T';
    put32(out.data() + 1, crc32c(in.bytes));
    put32(out.data() + 5, uint32_t(in.bytes.size()));
    out.insert(out.end(), in.bytes.begin(), in.bytes.end());
  }
  bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) override {
    if (std::string why = desc.validate(); !why.empty()) return reject(error, "invalid buffer description: " + why);
    if (in.size() < kHeader || in[0] != 'T') return reject(error, "no crc_copy header");
    const auto payload = in.subspan(kHeader);
    if (get32(in.data() + 5) != payload.size() || payload.size() != desc.byte_size())
      return reject(error, "wrong payload size");
    if (get32(in.data() + 1) != crc32c(payload)) return reject(error, "checksum mismatch");
    out.desc = desc;
    out.bytes.assign(payload.begin(), payload.end());
    return true;
  }

 private:
  static constexpr size_t kHeader = 9;
  static bool reject(std::string& error, const std::string& why) {
    error = "crc_copy: " + why;
    return false;
  }
  static void put32(uint8_t* p, uint32_t v) {
    for (int i = 0; i < 4; ++i) p[i] = uint8_t(v >> (8 * i));
  }
  static uint32_t get32(const uint8_t* p) {
    return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
  }
};

CodecEntry make_crc_copy_codec() {
  return {"crc_copy", "bytes behind a CRC-32C header (a throwaway test codec)", {}, [](const Params&) {
            return std::make_unique<CrcCopyCodec>();
          }};
}

// A registry of its own holding only the throwaway codec (the real codecs run under Defaults).
const Registries& throwaway_registries() {
  static const Registries r = [] {
    Registries local;
    local.codecs.add(make_crc_copy_codec());
    return local;
  }();
  return r;
}

bool has_codec(const char* name) { return registries().codecs.find(name) != nullptr; }

struct Case {
  std::string name;
  PassBuffer buffer;
};

// The depth pass (12 bits) of a floor seen by a rolled camera (so that depth varies along rows
// and columns), with background above its horizon.
PassBuffer planar_depth(int w, int h) {
  const Camera cam = Camera::look_at({0.0f, 1.5f, 0.0f}, {0.0f, 0.0f, -4.0f},
                                     glm::normalize(glm::vec3(0.4f, 1.0f, 0.0f)), 60.0f, w, h, 0.05f, 100.0f);
  ImageF depth(w, h, kBackgroundDepth);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const Ray r = cam.primary_ray(float(x) + 0.5f, float(y) + 0.5f);
      if (r.direction.y < 0.0f) depth(x, y) = cam.view_depth(r.origin - r.direction * (r.origin.y / r.direction.y));
    }
  return pack_depth(depth, cam, 12);
}

std::vector<Case> cases_at(int w, int h) {
  const SyntheticView view{w, h, 0.0, 0.0, 0, 7};
  std::vector<Case> c;
  c.push_back({"constant_ao", test::make_constant({PassKind::Ao, w, h, 1, 255}, 200)});
  c.push_back({"random_ao", test::make_random({PassKind::Ao, w, h, 1, 255}, 11)});
  c.push_back({"noisy_ao_8", test::make_noisy_ao(view, 8)});
  c.push_back({"smooth_ao", test::make_smooth_ao(view)});
  c.push_back({"hard_vis_4", test::make_hard_visibility(view, 4)});
  c.push_back({"constant_vis_4", test::make_constant({PassKind::Visibility, w, h, 4, 255}, 0xFF)});
  c.push_back({"random_vis_1", test::make_random({PassKind::Visibility, w, h, 1, 255}, 12)});
  c.push_back({"random_vis_64", test::make_random({PassKind::Visibility, w, h, 64, 255}, 13)});
  c.push_back({"random_soft_3", test::make_random({PassKind::SoftVisibility, w, h, 3, 255}, 14)});
  c.push_back({"random_colour", test::make_random({PassKind::Colour, w, h, 3, 255}, 15)});
  c.push_back({"hard_vis_1", test::make_hard_visibility(view, 1)});
  c.push_back({"hard_vis_64", test::make_hard_visibility(view, 64)});
  c.push_back({"soft_vis_4", test::make_soft_visibility(view, 4)});
  c.push_back({"soft_vis_2_noisy16", test::make_soft_visibility(view, 2, 16)});
  c.push_back({"colour", test::make_colour(view)});
  c.push_back({"random_depth", test::make_random({PassKind::Depth, w, h, 2, 16}, 16)});
  c.push_back({"planar_depth", planar_depth(w, h)});
  return c;
}

// The lowest PSNR a lossy codec at its defaults may give on smooth content (smooth AO, the
// synthetic colour image) of 64x40 pixels; h264 at crf 23 measured 34-35 dB there.
constexpr double kLossyFloorDb = 30.0;

// A decoded buffer against its input: the same description always; bit-exact from a lossless
// codec; from a lossy one values within full scale and, when `smooth`, the PSNR floor.
void expect_decoded(const Codec& codec, const std::string& label, const PassBuffer& in, const PassBuffer& out,
                    bool smooth) {
  ASSERT_EQ(out.desc, in.desc) << label;
  ASSERT_EQ(out.bytes.size(), in.bytes.size()) << label;
  if (codec.lossless()) {
    EXPECT_TRUE(out.bytes == in.bytes) << label << " not bit-exact";
    return;
  }
  if (in.desc.kind == PassKind::Ao || in.desc.kind == PassKind::SoftVisibility) {
    for (uint8_t v : out.bytes) ASSERT_LE(v, in.desc.full_scale) << label;
  }
  if (smooth && !in.bytes.empty()) {
    EXPECT_GE(test::buffer_psnr_db(in, out), kLossyFloorDb) << label;
  }
}

// Encodes then decodes with the same object, checking the result with expect_decoded (no PSNR
// floor: the cases include noise and tiny sizes). `refused` is set (and only the refusal
// checked) when the codec refuses the buffer.
void expect_round_trip(Codec& codec, const std::string& label, const Case& c, bool& refused) {
  refused = false;
  if (std::string why = codec.refuses(c.buffer.desc); !why.empty()) {
    refused = true;
    EXPECT_THROW(
        {
          std::vector<uint8_t> bytes;
          codec.encode(c.buffer, {}, bytes);
        },
        Error)
        << label << " " << c.name << ": encode of a refused buffer must throw";
    return;
  }
  std::vector<uint8_t> bytes;
  codec.encode(c.buffer, {}, bytes);
  PassBuffer out;
  std::string error;
  const std::string where =
      label + " " + c.name + " " + std::to_string(c.buffer.desc.width) + "x" + std::to_string(c.buffer.desc.height);
  ASSERT_TRUE(codec.decode(bytes, c.buffer.desc, out, error)) << where << ": " << error;
  expect_decoded(codec, where, c.buffer, out, false);
}

class QuietAv : public ::testing::Environment {
 public:
  // Corrupt input makes the H.264 decoder log every damaged slice; the tests feed it plenty.
  void SetUp() override { av_log_set_level(AV_LOG_QUIET); }
};
const auto* const kQuietAv = ::testing::AddGlobalTestEnvironment(new QuietAv);

// ---------------------------------------------------------------- layout conversions

// Reference: one bit at a time, straight from the layout definitions.
std::vector<uint8_t> naive_planes(const PassBuffer& b) {
  const size_t n = size_t(b.desc.width) * b.desc.height, bpp = size_t(b.desc.channels + 7) / 8;
  const size_t plane = (n + 7) / 8;
  std::vector<uint8_t> p(plane * size_t(b.desc.channels), 0);
  for (size_t i = 0; i < n; ++i)
    for (int l = 0; l < b.desc.channels; ++l)
      if ((b.bytes[i * bpp + size_t(l / 8)] >> (l % 8)) & 1) p[size_t(l) * plane + i / 8] |= uint8_t(1u << (i % 8));
  return p;
}

TEST(BufferLayout, PlanesMatchDefinitionAndRoundTripExactly) {
  for (int lights : {1, 3, 7, 8, 9, 16, 17, 63, 64})
    for (auto [w, h] : {std::pair{1, 1}, {3, 3}, {8, 1}, {16, 1}, {17, 13}, {61, 7}, {0, 0}, {5, 0}}) {
      const PassDesc desc{PassKind::Visibility, w, h, lights, 255};
      const PassBuffer in = test::make_random(desc, uint64_t(lights * 100 + w));
      std::vector<uint8_t> planes(visibility_planes_size(desc));
      visibility_to_planes(desc, in.bytes, planes);
      EXPECT_EQ(planes, naive_planes(in)) << lights << " lights " << w << "x" << h;
      std::vector<uint8_t> back(desc.byte_size());
      EXPECT_TRUE(visibility_from_planes(desc, planes, back));
      EXPECT_EQ(back, in.bytes) << lights << " lights " << w << "x" << h;
    }
}

TEST(BufferLayout, SizesFollowTheDefinition) {
  EXPECT_EQ(visibility_plane_bytes(17, 13), 28u);  // 221 bits
  EXPECT_EQ(visibility_planes_size({PassKind::Visibility, 17, 13, 4, 255}), 112u);
  EXPECT_EQ(visibility_planes_size({PassKind::Visibility, 1280, 720, 4, 255}), 460800u);  // half of 1 byte/px
}

TEST(BufferLayout, UnusedBitsAreRejected) {
  const PassDesc desc{PassKind::Visibility, 3, 3, 4, 255};
  PassBuffer in = test::make_constant(desc, 0x0F);
  EXPECT_TRUE(visibility_unused_bits_clear(desc, in.bytes));
  in.bytes[4] |= 0x10;  // light 4 of a 4-light mask
  EXPECT_FALSE(visibility_unused_bits_clear(desc, in.bytes));
  std::vector<uint8_t> planes(visibility_planes_size(desc));
  EXPECT_THROW(visibility_to_planes(desc, in.bytes, planes), Error);
}

TEST(BufferLayout, PaddingBitsAreCorruption) {
  const PassDesc desc{PassKind::Visibility, 3, 3, 2, 255};  // 9 px: 2 bytes a plane, 7 padding bits
  std::vector<uint8_t> planes(visibility_planes_size(desc), 0);
  std::vector<uint8_t> out(desc.byte_size());
  EXPECT_TRUE(visibility_from_planes(desc, planes, out));
  planes[3] = 0x02;  // second plane, pixel 9 (does not exist)
  EXPECT_FALSE(visibility_from_planes(desc, planes, out));
}

TEST(BufferLayout, WrongSizesAndKindsThrow) {
  const PassDesc desc{PassKind::Visibility, 4, 4, 4, 255};
  std::vector<uint8_t> in(desc.byte_size()), planes(visibility_planes_size(desc) + 1);
  EXPECT_THROW(visibility_to_planes(desc, in, planes), Error);
  std::vector<uint8_t> ok(visibility_planes_size(desc));
  EXPECT_THROW(visibility_to_planes({PassKind::Ao, 4, 4, 1, 255}, in, ok), Error);
  EXPECT_THROW(parse_visibility_layout("rows"), Error);
}

// ---------------------------------------------------------------- conformance, every codec

class CodecConformance : public ::testing::TestWithParam<Variant> {};

// Pass layouts and sizes from 1x1 up: bit-exact from a lossless codec, right-sized and in range
// from a lossy one; a refused layout must make encode() throw.
TEST_P(CodecConformance, RoundTripAtOddSizes) {
  const Variant& v = GetParam();
  auto codec = v.create();
  if (auto it = lossless_params().find(v.name); it != lossless_params().end() && it->second == v.params) {
    ASSERT_TRUE(codec->lossless()) << v.label() << " is listed as a lossless configuration";
  }
  int refused = 0, total = 0;
  for (auto [w, h] : {std::pair{1, 1}, {17, 13}})
    for (const Case& c : cases_at(w, h)) {
      bool r = false;
      expect_round_trip(*codec, v.label(), c, r);
      refused += r;
      ++total;
    }
  std::printf("%-45s %-8s %d of %d small cases refused\n", v.label().c_str(), codec->lossless() ? "lossless" : "lossy",
              refused, total);
}

TEST_P(CodecConformance, RoundTripAtFullHdPlusOne) {
  // One big odd-sized AO and one bitmask per codec configuration (kept few: ASan is slow),
  // made once for every configuration (making them costs more than coding them).
  static const std::vector<Case> big = [] {
    const SyntheticView view{1281, 721, 0.0, 0.0, 0, 7};
    return std::vector<Case>{{"noisy_ao_8", test::make_noisy_ao(view, 8)},
                             {"hard_vis_4", test::make_hard_visibility(view, 4)}};
  }();
  const Variant& v = GetParam();
  auto codec = v.create();
  for (const Case& c : big) {
    bool refused = false;
    expect_round_trip(*codec, v.label(), c, refused);
  }
}

TEST_P(CodecConformance, EmptyBuffersRoundTripOrAreRefused) {
  const Variant& v = GetParam();
  auto codec = v.create();
  for (const PassDesc& desc : {PassDesc{PassKind::Ao, 0, 0, 1, 255}, PassDesc{PassKind::Visibility, 0, 5, 4, 255},
                               PassDesc{PassKind::Colour, 7, 0, 3, 255}}) {
    bool refused = false;
    expect_round_trip(*codec, v.label(), {"empty", test::make_constant(desc, 0)}, refused);
    if (refused)
      std::printf("%-45s refuses %dx%d %s: %s\n", v.label().c_str(), desc.width, desc.height, pass_kind_name(desc.kind),
                  codec->refuses(desc).c_str());
  }
}

TEST_P(CodecConformance, BadInputReturnsFalseAndNeverCrashes) {
  const Variant& v = GetParam();
  const Exemption ex = exemption(v.name);
  const PassBuffer ao = test::make_smooth_ao({17, 13});
  auto codec = v.create();
  if (!codec->refuses(ao.desc).empty()) GTEST_SKIP() << v.label() << " refuses AO: " << codec->refuses(ao.desc);
  std::vector<uint8_t> bytes;
  codec->encode(ao, {}, bytes);
  ASSERT_FALSE(bytes.empty()) << v.label();
  auto rejects = [&](std::span<const uint8_t> in, const PassDesc& desc, const char* what) {
    PassBuffer out;
    std::string error;
    const bool ok = codec->decode(in, desc, out, error);
    EXPECT_FALSE(ok) << v.label() << ": " << what << " accepted";
    if (!ok) {
      EXPECT_FALSE(error.empty()) << v.label() << ": " << what << " rejected without a message";
    }
  };
  rejects({}, ao.desc, "empty input");
  rejects(std::span(bytes).first(1), ao.desc, "first byte only");
  if (!ex.half_frame_decodes) rejects(std::span(bytes).first(bytes.size() / 2), ao.desc, "first half");
  std::vector<uint8_t> longer = bytes;
  longer.push_back(0);
  if (!ex.loose_framing) rejects(longer, ao.desc, "a trailing zero byte");
  longer.back() = 0x5A;
  if (!ex.loose_framing) rejects(longer, ao.desc, "a trailing byte");
  const PassBuffer noise = test::make_random({PassKind::Ao, 1000, 1, 1, 255}, 99);
  rejects(noise.bytes, ao.desc, "random bytes");
  const std::string text = "this is not a frame of any codec";
  rejects(std::span(reinterpret_cast<const uint8_t*>(text.data()), text.size()), ao.desc, "text");
  PassDesc wider = ao.desc;
  wider.width += 2;
  rejects(bytes, wider, "a wrong buffer size");
  PassDesc invalid = ao.desc;
  invalid.channels = 0;
  rejects(bytes, invalid, "an invalid description");
  // Every prefix: truncation must never crash (and for exactly framed codecs never succeed).
  for (size_t n = 0; n < bytes.size(); n += std::max<size_t>(1, bytes.size() / 40)) {
    PassBuffer out;
    std::string error;
    const bool ok = codec->decode(std::span(bytes).first(n), ao.desc, out, error);
    if (!ex.loose_framing) {
      EXPECT_FALSE(ok) << v.label() << ": prefix of " << n << " bytes accepted";
    }
    if (ok) {
      EXPECT_EQ(out.bytes.size(), ao.desc.byte_size());
    }
  }
}

// A valid frame of every other codec of the same registry is foreign input too.
TEST_P(CodecConformance, ForeignFramesAreRejected) {
  const Variant& v = GetParam();
  if (exemption(v.name).accepts_any_bytes) GTEST_SKIP() << v.name << ": " << exemption(v.name).why;
  const PassBuffer ao = test::make_smooth_ao({17, 13});
  for (const Variant& other : default_variants(*v.registry)) {
    if (other.name == v.name || exemption(other.name).accepts_any_bytes) continue;
    // A codec that wraps this one (its default `inner` names it: delta_video around h264) puts
    // this codec's own stream behind a header; a stream format that skips leading bytes (Annex
    // B: loose framing, no checksum) cannot tell that from its own frames.
    if (exemption(v.name).loose_framing && inner_default(*v.registry, other.name) == v.name) continue;
    auto enc = other.create();
    auto dec = v.create();
    if (!enc->refuses(ao.desc).empty() || !dec->refuses(ao.desc).empty()) continue;
    std::vector<uint8_t> bytes;
    enc->encode(ao, {}, bytes);
    PassBuffer out;
    std::string error;
    const bool ok = dec->decode(bytes, ao.desc, out, error);
    // Accepting is only tolerable when the decoder produced the right bytes anyway.
    if (ok) {
      EXPECT_TRUE(out.bytes == ao.bytes) << v.label() << " decoded a " << other.name << " frame into wrong bytes";
    }
  }
}

// Single bit flips: a corrupt frame must be rejected or decode into what the intact frame
// decodes into (without checksums, flips can decode without error into wrong bytes). Codecs
// exempted above (no checksum) are only held to never crashing and right-sized output.
TEST_P(CodecConformance, BitFlipsAreDetectedOrHarmless) {
  const Variant& v = GetParam();
  const Exemption ex = exemption(v.name);
  const SyntheticView view{33, 21};
  auto codec = v.create();
  for (const Case& c :
       {Case{"smooth_ao", test::make_smooth_ao(view)}, Case{"hard_vis_4", test::make_hard_visibility(view, 4)},
        Case{"noisy_ao_8", test::make_noisy_ao(view, 8)}}) {
    const PassBuffer& in = c.buffer;
    if (!codec->refuses(in.desc).empty()) continue;
    codec->reset();
    std::vector<uint8_t> bytes;
    codec->encode(in, {}, bytes);  // the first frame after a reset: a keyframe
    PassBuffer want;
    std::string error;
    codec->reset();
    ASSERT_TRUE(codec->decode(bytes, in.desc, want, error)) << v.label() << ": " << error;
    int detected = 0, harmless = 0, wrong = 0;
    for (uint32_t i = 0; i < 300; ++i) {
      const uint64_t r = rng_bits({2024, i, 0, 0, 0});
      std::vector<uint8_t> flipped = bytes;
      flipped[size_t(r % flipped.size())] ^= uint8_t(1u << ((r >> 32) % 8));
      if (codec->stateful()) codec->reset();  // a fresh keyframe decoder each time
      PassBuffer out;
      if (!codec->decode(flipped, in.desc, out, error)) {
        ++detected;
        continue;
      }
      ASSERT_EQ(out.bytes.size(), in.desc.byte_size()) << v.label();
      if (out.bytes == want.bytes)
        ++harmless;
      else
        ++wrong;
    }
    std::printf("%-45s %-10s 300 bit flips: %3d detected, %3d harmless, %3d wrong%s\n", v.label().c_str(),
                c.name.c_str(), detected, harmless, wrong, ex.no_checksum ? " (no checksum)" : "");
    if (ex.no_checksum) continue;
    EXPECT_EQ(wrong, 0) << v.label() << " " << c.name << ": " << wrong << " of 300 bit flips decoded into wrong bytes";
    EXPECT_GT(detected, 250) << v.label() << " " << c.name;
  }
}

// A frame lost on the link, handled as the frame loop does (core/pipeline/pass_receiver.cpp): a
// stateless codec decodes every later frame as if nothing happened, and every frame on a
// fresh decoder too; a stateful one, reset at the gap, may fail (never with wrong bytes)
// until the keyframe its receiver asked for, which decodes on a fresh decoder and from which
// on every frame is right again. Right: bit-exact when lossless, above the PSNR floor if not.
TEST_P(CodecConformance, LostFrameRecoversThroughAKeyframe) {
  const Variant& v = GetParam();
  auto enc = v.create();
  auto dec = v.create();
  const bool stateful = enc->stateful();
  auto frame = [&](int f, PassKind kind) {
    const SyntheticView view{64, 40, 1.5 * f, 0.5 * f, uint32_t(f)};
    return kind == PassKind::Ao               ? test::make_smooth_ao(view)
           : kind == PassKind::Colour         ? test::make_colour(view)
           : kind == PassKind::SoftVisibility ? test::make_soft_visibility(view, 3)
                                              : test::make_hard_visibility(view, 4);
  };
  std::optional<PassKind> kind;  // the first kind of smooth content the codec accepts
  for (PassKind k : {PassKind::Ao, PassKind::Colour, PassKind::SoftVisibility, PassKind::Visibility})
    if (!kind && enc->refuses(frame(0, k).desc).empty()) kind = k;
  ASSERT_TRUE(kind.has_value()) << v.label() << " refuses every pass kind";
  constexpr int kLost = 2, kKeyframe = 4;  // the request takes a round trip to reach the sender
  int failed_before_keyframe = 0;
  for (int f = 0; f < 8; ++f) {
    const PassBuffer in = frame(f, *kind);
    const std::string where = v.label() + " " + pass_kind_name(*kind) + " frame " + std::to_string(f);
    EncodeOptions options;
    options.force_keyframe = stateful && f == kKeyframe;
    std::vector<uint8_t> bytes;
    enc->encode(in, options, bytes);
    if (f == kLost) continue;
    if (stateful && f == kLost + 1) dec->reset();  // the receiver saw the gap
    PassBuffer out;
    std::string error;
    const bool ok = dec->decode(bytes, in.desc, out, error);
    if (stateful && f > kLost && f < kKeyframe) {
      if (ok) {
        expect_decoded(*dec, where + " (before the keyframe)", in, out, true);
      } else {
        EXPECT_FALSE(error.empty()) << where;
        dec->reset();  // and asks for a keyframe again
        ++failed_before_keyframe;
      }
      continue;
    }
    ASSERT_TRUE(ok) << where << ": " << error;
    expect_decoded(*dec, where, in, out, true);
    if (!stateful || f == kKeyframe) {
      auto fresh = v.create();
      PassBuffer alone;
      ASSERT_TRUE(fresh->decode(bytes, in.desc, alone, error)) << where << " on a fresh decoder: " << error;
      expect_decoded(*fresh, where + " on a fresh decoder", in, alone, true);
    }
  }
  if (stateful) {
    std::printf("%-45s stateful: %d of %d frames between the loss and the keyframe failed to decode\n",
                v.label().c_str(), failed_before_keyframe, kKeyframe - kLost - 1);
  } else {
    std::printf("%-45s stateless: every frame after the loss decoded, and on a fresh decoder\n", v.label().c_str());
  }
}

// A failed decode must leave the codec usable: after a truncated frame, an empty buffer and a
// normal one still round-trip (found by fuzz_decoders: liblz4's context reset kept the
// unfinished frame's remaining size, so the next empty frame failed).
TEST_P(CodecConformance, DecoderRecoversAfterAFailedDecode) {
  const Variant& v = GetParam();
  const SyntheticView view{33, 21};
  const PassBuffer normal = test::make_smooth_ao(view);
  PassBuffer empty = normal;
  empty.desc.width = 0;
  empty.bytes.clear();
  auto codec = v.create();
  if (!codec->refuses(normal.desc).empty() || !codec->refuses(empty.desc).empty())
    GTEST_SKIP() << v.label() << " refuses an AO or an empty buffer";
  std::vector<uint8_t> bytes;
  codec->encode(normal, {}, bytes);
  bytes.resize(bytes.size() / 2);
  PassBuffer out;
  std::string error;
  codec->reset();
  EXPECT_FALSE(codec->decode(bytes, normal.desc, out, error)) << v.label() << " accepted half a frame";
  for (const PassBuffer* in : std::initializer_list<const PassBuffer*>{&empty, &normal}) {
    codec->reset();
    std::vector<uint8_t> encoded;
    codec->encode(*in, EncodeOptions::keyframe(), encoded);
    codec->reset();
    error.clear();
    ASSERT_TRUE(codec->decode(encoded, in->desc, out, error))
        << v.label() << " " << in->desc.width << "x" << in->desc.height << " after a failed decode: " << error;
    if (codec->lossless()) {
      EXPECT_TRUE(out.bytes == in->bytes) << v.label();
    }
  }
}

TEST_P(CodecConformance, SameInputGivesSameBytes) {
  const Variant& v = GetParam();
  const SyntheticView view{33, 21};
  auto a = v.create();
  auto b = v.create();
  for (uint32_t f = 0; f < 3; ++f) {
    SyntheticView moved = view;
    moved.shift_x_px = 2.0 * f;
    moved.frame = f;
    for (const PassBuffer& in : {test::make_smooth_ao(moved), test::make_colour(moved)}) {
      if (!a->refuses(in.desc).empty()) continue;
      std::vector<uint8_t> x, y;
      a->encode(in, {}, x);
      b->encode(in, {}, y);
      EXPECT_TRUE(x == y) << v.label() << " frame " << f << " " << pass_kind_name(in.desc.kind);
    }
  }
}

TEST_P(CodecConformance, InvalidInputBufferThrowsOnEncode) {
  const Variant& v = GetParam();
  if (exemption(v.name).accepts_any_bytes) GTEST_SKIP() << v.name << ": " << exemption(v.name).why;
  auto codec = v.create();
  PassBuffer bad = test::make_smooth_ao({8, 8});
  bad.bytes.pop_back();
  std::vector<uint8_t> out;
  EXPECT_THROW(codec->encode(bad, {}, out), Error) << v.label();
}

// Every registered codec at its defaults; the further configurations; the throwaway codec.
INSTANTIATE_TEST_SUITE_P(Defaults, CodecConformance, ::testing::ValuesIn(default_variants(registries().codecs)),
                         variant_test_name);
INSTANTIATE_TEST_SUITE_P(Configurations, CodecConformance,
                         ::testing::ValuesIn(configured_variants(registries().codecs)), variant_test_name);
INSTANTIATE_TEST_SUITE_P(Throwaway, CodecConformance,
                         ::testing::ValuesIn(default_variants(throwaway_registries().codecs)), variant_test_name);

// The loops take whatever a registry holds: a codec added to a local Registries beside every
// built-in one is listed after them, and the suite above has a test of it by name.
TEST(CodecRegistryLoop, PicksUpACodecRegisteredInALocalRegistry) {
  Registries local;
  register_all_backends(local);
  local.codecs.add(make_crc_copy_codec());
  std::vector<std::string> want, got;
  for (const auto& e : registries().codecs.entries()) want.push_back(e.name);
  want.push_back("crc_copy");
  for (const Variant& v : default_variants(local.codecs)) got.push_back(v.name);
  EXPECT_EQ(got, want);

  // Every codec of both registries has its tests in the suite, named after it.
  std::set<std::string> tested;
  const ::testing::UnitTest& unit = *::testing::UnitTest::GetInstance();
  for (int i = 0; i < unit.total_test_suite_count(); ++i) {
    const ::testing::TestSuite& suite = *unit.GetTestSuite(i);
    const std::string prefix = std::string(suite.name()).substr(0, std::string(suite.name()).find('/'));
    if (prefix != "Defaults" && prefix != "Throwaway") continue;
    for (int k = 0; k < suite.total_test_count(); ++k) {
      const std::string name = suite.GetTestInfo(k)->name();
      tested.insert(name.substr(name.rfind('/') + 1));
    }
  }
  for (const std::string& name : want) EXPECT_TRUE(tested.count(name)) << "no conformance test named after " << name;
}

TEST(CodecRegistryLoop, ExemptionsAndConfigurationsNameRegisteredCodecs) {
  // A stale entry (a renamed codec) would silently test less.
  for (const auto& [name, ex] : exemptions()) EXPECT_TRUE(has_codec(name.c_str())) << name << ": " << ex.why;
  for (const auto& [name, params] : lossless_params()) EXPECT_TRUE(has_codec(name.c_str())) << name;
  for (const auto& [name, params] : extra_params()) EXPECT_TRUE(has_codec(name.c_str())) << name;
}

// ---------------------------------------------------------------- lz4 / zstd specifics

TEST(Lz4Zstd, FramesAreStandardAndHoldThePlanes) {
  const PassBuffer vis = test::make_hard_visibility({40, 24}, 4);
  std::vector<uint8_t> planes(visibility_planes_size(vis.desc));
  visibility_to_planes(vis.desc, vis.bytes, planes);
  for (const char* name : {"lz4", "zstd"}) {
    if (!has_codec(name)) continue;
    for (const char* layout : {"planes", "interleaved"}) {
      auto codec = registries().codecs.create(name, {{"layout", layout}});
      std::vector<uint8_t> bytes;
      codec->encode(vis, {}, bytes);
      // The same bytes decoded as a plain AO-like byte buffer of the coded size: a codec that
      // writes a standard frame of the (planar) bytes accepts it.
      const std::vector<uint8_t>& want = std::string(layout) == "planes" ? planes : vis.bytes;
      const PassDesc as_bytes{PassKind::Ao, int(want.size()), 1, 1, 255};
      PassBuffer out;
      std::string error;
      ASSERT_TRUE(codec->decode(bytes, as_bytes, out, error)) << name << " " << layout << ": " << error;
      EXPECT_EQ(out.bytes, want) << name << " " << layout;
    }
  }
}

TEST(Lz4Zstd, PlanesAreSmallerThanInterleavedOnBitmasks) {
  const PassBuffer vis = test::make_hard_visibility({320, 180}, 4);
  for (const char* name : {"lz4", "zstd"}) {
    if (!has_codec(name)) continue;
    std::vector<uint8_t> planar, interleaved;
    registries().codecs.create(name, {{"layout", "planes"}})->encode(vis, {}, planar);
    registries().codecs.create(name, {{"layout", "interleaved"}})->encode(vis, {}, interleaved);
    EXPECT_LT(planar.size(), interleaved.size()) << name;
    std::printf("%s 4-light bitmask 320x180: planes %zu bytes, interleaved %zu bytes\n", name, planar.size(),
                interleaved.size());
  }
}

TEST(Lz4Zstd, UnusedBitmaskBitsAreBadInput) {
  PassBuffer vis = test::make_hard_visibility({9, 5}, 3);
  vis.bytes[7] |= 0x80;
  for (const char* name : {"lz4", "zstd"}) {
    if (!has_codec(name)) continue;
    std::vector<uint8_t> bytes;
    EXPECT_THROW(registries().codecs.create(name, json::object())->encode(vis, {}, bytes), Error) << name;
    // The interleaved layout carries the bytes as they are.
    auto raw_layout = registries().codecs.create(name, {{"layout", "interleaved"}});
    raw_layout->encode(vis, {}, bytes);
    PassBuffer out;
    std::string error;
    EXPECT_TRUE(raw_layout->decode(bytes, vis.desc, out, error)) << error;
    EXPECT_EQ(out.bytes, vis.bytes);
  }
}

// ---------------------------------------------------------------- h264 specifics

std::unique_ptr<Codec> h264(json params = json::object()) { return registries().codecs.create("h264", params); }

// Decodes one access unit with a fresh, plain libavcodec H.264 decoder (not the codec object).
// Returns the luma plane cropped to w x h, or nothing when no picture came out.
std::optional<std::vector<uint8_t>> plain_decode_luma(const std::vector<uint8_t>& bytes, int w, int h,
                                                      bool* keyframe = nullptr) {
  const AVCodec* dec = avcodec_find_decoder(AV_CODEC_ID_H264);
  AVCodecContext* ctx = avcodec_alloc_context3(dec);
  ctx->thread_count = 1;
  std::optional<std::vector<uint8_t>> luma;
  if (avcodec_open2(ctx, dec, nullptr) == 0) {
    AVPacket* pkt = av_packet_alloc();
    AVFrame* frame = av_frame_alloc();
    if (av_new_packet(pkt, int(bytes.size())) == 0) {
      std::memcpy(pkt->data, bytes.data(), bytes.size());
      if (avcodec_send_packet(ctx, pkt) >= 0) {
        avcodec_send_packet(ctx, nullptr);  // flush: a plain decoder may hold the picture back
        if (avcodec_receive_frame(ctx, frame) == 0 && frame->width >= w && frame->height >= h) {
          luma.emplace(size_t(w) * size_t(h));
          for (int y = 0; y < h; ++y)
            std::memcpy(luma->data() + size_t(y) * w, frame->data[0] + ptrdiff_t(y) * frame->linesize[0], size_t(w));
          if (keyframe) *keyframe = frame->key_frame != 0;
        }
      }
    }
    av_frame_free(&frame);
    av_packet_free(&pkt);
  }
  avcodec_free_context(&ctx);
  return luma;
}

// Sizes of the NAL units of an Annex-B byte stream (start codes excluded) and their types.
std::vector<std::pair<size_t, int>> nal_units(const std::vector<uint8_t>& b) {
  std::vector<size_t> starts;
  for (size_t i = 0; i + 2 < b.size(); ++i)
    if (b[i] == 0 && b[i + 1] == 0 && b[i + 2] == 1) {
      starts.push_back(i + 3);
      i += 2;
    }
  std::vector<std::pair<size_t, int>> units;
  for (size_t k = 0; k < starts.size(); ++k) {
    size_t end = k + 1 < starts.size() ? starts[k + 1] - 3 : b.size();
    while (end > starts[k] && b[end - 1] == 0) --end;  // a 4-byte start code's leading zero
    units.push_back({end - starts[k], b[starts[k]] & 0x1F});
  }
  return units;
}

PassBuffer decode_or_fail(Codec& codec, const std::vector<uint8_t>& bytes, const PassDesc& desc) {
  PassBuffer out;
  std::string error;
  EXPECT_TRUE(codec.decode(bytes, desc, out, error)) << error;
  return out;
}

// ---------------------------------------------------------------- video codecs: full-range mapping

// The registered codecs with a lossless configuration above and a lossy default (h264, hevc, av1).
std::vector<std::string> lossy_video_codecs() {
  std::vector<std::string> names;
  for (const auto& [name, params] : lossless_params())
    if (has_codec(name.c_str()) && !registries().codecs.create(name, json::object())->lossless()) names.push_back(name);
  return names;
}

// A smooth plane (AO, or 2 soft-visibility lights) of frame f of a pan, requantised to 0..range.
PassBuffer count_plane(PassKind kind, int range, int f) {
  const SyntheticView view{128, 72, 1.5 * f, 0.5 * f, uint32_t(f)};
  PassBuffer b = kind == PassKind::Ao ? test::make_smooth_ao(view) : test::make_soft_visibility(view, 2);
  for (uint8_t& v : b.bytes) v = uint8_t((v * range + 127) / 255);
  b.desc.full_scale = range;
  return b;
}

// PSNR of a pass's values relative to its full scale, over several frames.
double range_psnr_db(double squared_error, size_t values, int full_scale) {
  if (squared_error == 0) return std::numeric_limits<double>::infinity();
  return 10 * std::log10(double(full_scale) * full_scale / (squared_error / double(values)));
}

// Lossy codecs code count planes (soft visibility 0..samples, AO 0..rays) mapped to 0..255
// (backends/codec/av_video.h), so the error relative to the range does not grow when the range
// shrinks much. Measured (128x72, 3 frames, defaults): mapped, 0..8 and 0..64 planes lose at
// most 2.4 dB against 0..255 (the 0..8 picture's steps of 32 cost bits); unmapped they lost
// 5-10 dB at 0..64 and 15-19 dB at 0..8 (a quantiser step as large as the signal).
TEST(VideoCodecs, CountPlaneKeepsItsPsnrWhenTheRangeChanges) {
  const std::vector<std::string> names = lossy_video_codecs();
  ASSERT_FALSE(names.empty()) << "no lossy video codec registered";
  for (const std::string& name : names)
    for (PassKind kind : {PassKind::Ao, PassKind::SoftVisibility}) {
      std::map<int, double> db;
      for (int range : {255, 64, 8}) {
        auto codec = registries().codecs.create(name, json::object());
        double squared_error = 0;
        size_t values = 0;
        for (int f = 0; f < 3; ++f) {
          const PassBuffer in = count_plane(kind, range, f);
          std::vector<uint8_t> bytes;
          codec->encode(in, {}, bytes);
          const PassBuffer out = decode_or_fail(*codec, bytes, in.desc);
          ASSERT_EQ(out.bytes.size(), in.bytes.size());
          for (size_t i = 0; i < in.bytes.size(); ++i) {
            ASSERT_LE(out.bytes[i], range) << name;
            const double d = double(in.bytes[i]) - double(out.bytes[i]);
            squared_error += d * d;
          }
          values += in.bytes.size();
        }
        db[range] = range_psnr_db(squared_error, values, range);
      }
      std::printf("%-5s %-15s PSNR relative to the range: 0..255 %.2f dB, 0..64 %.2f dB, 0..8 %.2f dB\n", name.c_str(),
                  pass_kind_name(kind), db[255], db[64], db[8]);
      EXPECT_GE(db[255], kLossyFloorDb) << name;
      for (int range : {64, 8})
        EXPECT_GE(db[range], db[255] - 3.0) << name << " " << pass_kind_name(kind) << " 0.." << range;
    }
}

// chroma "444" keeps full-resolution chroma: on alternating red and blue columns (same luma
// band, chroma changing every pixel) 4:2:0 averages each pair of columns to purple while 4:4:4
// returns the colours. Each video codec, CRF 10, one keyframe of 64x48.
TEST(VideoCodecs, Chroma444KeepsOnePixelColourDetail) {
  const std::vector<std::string> names = lossy_video_codecs();
  ASSERT_FALSE(names.empty()) << "no lossy video codec registered";
  PassBuffer in;
  in.desc = PassDesc{PassKind::Colour, 64, 48, 3, 255};
  in.bytes.resize(in.desc.byte_size());
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      uint8_t* p = &in.bytes[(size_t(y) * 64 + size_t(x)) * 3];
      p[0] = x % 2 ? 40 : 200;
      p[1] = 60;
      p[2] = x % 2 ? 200 : 40;
    }
  for (const std::string& name : names) {
    double db[2] = {0, 0};
    for (int i = 0; i < 2; ++i) {
      auto codec = registries().codecs.create(name, {{"crf", 10}, {"chroma", i == 0 ? "420" : "444"}});
      std::vector<uint8_t> bytes;
      codec->encode(in, {}, bytes);
      db[i] = test::buffer_psnr_db(in, decode_or_fail(*codec, bytes, in.desc));
    }
    std::printf("%-5s red/blue columns at crf 10: 4:2:0 %.2f dB, 4:4:4 %.2f dB\n", name.c_str(), db[0], db[1]);
    EXPECT_LT(db[0], 25.0) << name << ": 4:2:0 cannot hold one-pixel chroma";
    EXPECT_GT(db[1], db[0] + 10.0) << name;
  }
}

// Rate control that streaming uses: in bitrate mode a VBV of about one frame interval bounds the
// keyframe that a 1 s buffer lets pass the per-frame budget many times over; in crf mode
// max_kbps caps the rate (x264/x265: VBV; libaom: constrained quality). 64x48 colour pan, 20
// frames at 60 Hz, a keyframe first.
TEST(VideoCodecs, VbvBoundsFrameSizesAndMaxKbpsCapsCrf) {
  const std::vector<std::string> names = lossy_video_codecs();
  ASSERT_FALSE(names.empty()) << "no lossy video codec registered";
  auto stream = [](Codec& codec) {
    std::vector<size_t> sizes;
    for (int f = 0; f < 20; ++f) {
      const SyntheticView view{128, 96, 3.0 * f, 2.0 * f, uint32_t(f)};
      std::vector<uint8_t> bytes;
      codec.encode(test::make_colour(view), {}, bytes);
      sizes.push_back(bytes.size());
    }
    return sizes;
  };
  for (const std::string& name : names) {
    const double budget = 300.0 * 1000 / 8 / 60;  // bytes per frame at 300 kbit/s and 60 Hz
    auto loose = registries().codecs.create(name, {{"rate_control", "bitrate"}, {"bitrate_kbps", 300}});
    auto tight =
        registries().codecs.create(name, {{"rate_control", "bitrate"}, {"bitrate_kbps", 300}, {"vbv_buffer_ms", 17}});
    const std::vector<size_t> a = stream(*loose), b = stream(*tight);
    const size_t max_a = *std::max_element(a.begin(), a.end()), max_b = *std::max_element(b.begin(), b.end());
    std::printf("%-5s bitrate 300 kbit/s: largest frame %zu B with a 1 s VBV, %zu B with 17 ms (budget %.0f B)\n",
                name.c_str(), max_a, max_b, budget);
    EXPECT_LT(max_b, max_a) << name;
    auto uncapped = registries().codecs.create(name, {{"crf", 12}});
    auto capped = registries().codecs.create(name, {{"crf", 12}, {"max_kbps", 300}, {"vbv_buffer_ms", 100}});
    const std::vector<size_t> u = stream(*uncapped), c = stream(*capped);
    const double mean_u = double(std::accumulate(u.begin(), u.end(), size_t(0))) / double(u.size());
    const double mean_c = double(std::accumulate(c.begin(), c.end(), size_t(0))) / double(c.size());
    std::printf("%-5s crf 12: mean frame %.0f B uncapped, %.0f B with max_kbps 300\n", name.c_str(), mean_u, mean_c);
    EXPECT_LT(mean_c, 0.7 * mean_u) << name;
  }
}

// hevc and av1 promise bytes independent of their thread count (x265: one frame thread, a
// pool of `threads`; libaom: row-mt off). h264 does not (x264's frame threads change the bytes).
TEST(VideoCodecs, HevcAndAv1BytesDoNotDependOnThreads) {
  for (const char* name : {"hevc", "av1"}) {
    if (!has_codec(name)) continue;
    for (PassKind kind : {PassKind::Ao, PassKind::Colour}) {
      std::vector<uint8_t> stream[2];
      for (int t = 0; t < 2; ++t) {
        auto codec = registries().codecs.create(name, {{"threads", t == 0 ? 1 : 4}});
        for (int f = 0; f < 4; ++f) {
          const SyntheticView view{320, 184, 2.0 * f, 1.0 * f, uint32_t(f)};
          const PassBuffer in = kind == PassKind::Ao ? test::make_smooth_ao(view) : test::make_colour(view);
          std::vector<uint8_t> bytes;
          codec->encode(in, {}, bytes);
          stream[t].insert(stream[t].end(), bytes.begin(), bytes.end());
        }
      }
      EXPECT_TRUE(stream[0] == stream[1]) << name << " " << pass_kind_name(kind) << ": " << stream[0].size()
                                          << " bytes with 1 thread, " << stream[1].size() << " with 4";
    }
  }
}

// --dump-streams writes a video pass with core/base/stream_dump.h; the ffmpeg command-line tool must
// decode such a file to the pictures our decoder gives: gray AO (values as coded: full scale
// 255, so no mapping) over 8 frames of a pan with a forced keyframe, bit for bit.
// Periodic intra refresh (h264): no keyframe after the first; a decoder that missed a frame goes
// on (heals_after_loss: the receiver asks for nothing) and, by the end of the first refresh sweep
// (gop frames) that starts after the loss, decodes exactly what a decoder that lost nothing
// decodes. Measured (160x96 AO pan, gop 8, frame 5 lost): PSNR to the clean decode 21.7 dB at
// frame 6 rising to 45.2 at 14, identical from 15. (x265 3.5's intra-refresh=1 was tried for
// hevc and did not heal: 8-11 dB to the clean decode 18 frames after the loss.)
TEST(VideoCodecs, IntraRefreshHealsALossWithoutAKeyframe) {
  constexpr int kGop = 8, kLost = 5, kFrames = 24;
  for (const char* name : {"h264"}) {
    if (!has_codec(name)) continue;
    const json params = {{"intra_refresh", true}, {"gop", kGop}, {"preset", "fast"}};
    auto enc = registries().codecs.create(name, params);
    auto lossy_dec = registries().codecs.create(name, params);
    auto clean_dec = registries().codecs.create(name, params);
    EXPECT_TRUE(lossy_dec->heals_after_loss()) << name;
    EXPECT_FALSE(registries().codecs.create(name, json::object())->heals_after_loss()) << name;
    int differing_after_loss = 0, healed_from = -1;
    size_t first_bytes = 0, largest_later = 0;
    for (int f = 0; f < kFrames; ++f) {
      const SyntheticView view{160, 96, 2.0 * f, 0.75 * f, uint32_t(f)};
      const PassBuffer in = test::make_smooth_ao(view);
      std::vector<uint8_t> bytes;
      enc->encode(in, {}, bytes);
      (f == 0 ? first_bytes : largest_later) = std::max(f == 0 ? first_bytes : largest_later, bytes.size());
      const PassBuffer clean = decode_or_fail(*clean_dec, bytes, in.desc);
      if (f == kLost) continue;
      PassBuffer out;
      std::string error;
      ASSERT_TRUE(lossy_dec->decode(bytes, in.desc, out, error))
          << name << " frame " << f << " after the loss: " << error;
      if (f < kLost) {
        EXPECT_EQ(out.bytes, clean.bytes) << name << " frame " << f;
      } else if (out.bytes != clean.bytes) {
        ++differing_after_loss;
        healed_from = -1;
      } else if (healed_from < 0) {
        healed_from = f;
      }
    }
    std::printf(
        "%s intra refresh (gop %d): first frame %zu bytes, largest later %zu; after losing frame %d, %d "
        "frames differed, identical from frame %d\n",
        name, kGop, first_bytes, largest_later, kLost, differing_after_loss, healed_from);
    EXPECT_GT(differing_after_loss, 0) << name << ": losing a frame changed nothing (was it lost?)";
    ASSERT_GE(healed_from, 0) << name << ": never healed";
    EXPECT_LE(healed_from, (kLost / kGop + 2) * kGop - 1) << name << ": not healed by the end of the next sweep";
    // No keyframe after the first: every later frame is smaller than a keyframe would be.
    EXPECT_LT(largest_later, first_bytes) << name;
  }
}

TEST(VideoCodecs, DumpedStreamsDecodeWithFfmpegToOurPictures) {
  if (std::system("command -v ffmpeg >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "the ffmpeg command-line tool is not installed (scripts/setup.sh installs it)";
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / "dhr_dump_streams_test";
  fs::remove_all(dir);
  fs::create_directories(dir);
  constexpr int kW = 64, kH = 40, kFrames = 8;
  for (const std::string& name : lossy_video_codecs()) {
    auto codec = registries().codecs.create(name, json::object());
    const std::string format = codec->stream_format();
    ASSERT_FALSE(format.empty()) << name << " names no stream format";
    const fs::path file = dir / ("ao." + format);
    std::vector<uint8_t> ours;  // our decoder's pictures, one after the other
    {
      StreamDump dump(file.string(), format, kW, kH, 60);
      auto decoder = registries().codecs.create(name, json::object());
      for (int f = 0; f < kFrames; ++f) {
        const PassBuffer in = test::make_smooth_ao({kW, kH, 1.5 * f, 0.5 * f, uint32_t(f)});
        std::vector<uint8_t> bytes;
        codec->encode(in, EncodeOptions::keyframe(f == 5), bytes);
        dump.append(bytes, uint64_t(f));
        const PassBuffer out = decode_or_fail(*decoder, bytes, in.desc);
        ours.insert(ours.end(), out.bytes.begin(), out.bytes.end());
      }
    }
    const fs::path raw = dir / (name + ".gray");
    const std::string cmd = "ffmpeg -nostdin -v error -y -i " + file.string() +
                            " -fps_mode passthrough -f rawvideo -pix_fmt gray " + raw.string() + " 2>" +
                            (dir / (name + ".log")).string();
    ASSERT_EQ(std::system(cmd.c_str()), 0) << name << ": " << cmd;
    std::ifstream in(raw, std::ios::binary);
    const std::vector<uint8_t> theirs((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    ASSERT_EQ(theirs.size(), ours.size())
        << name << ": ffmpeg decoded " << theirs.size() / (kW * kH) << " frames of " << kFrames;
    EXPECT_TRUE(theirs == ours) << name << ": ffmpeg's pictures differ from ours";
  }
  fs::remove_all(dir);
}

TEST(H264, LossyQualityOnSmoothAoAndColour) {
  if (!has_codec("h264")) GTEST_SKIP() << "no h264 codec registered";
  // Measured at 256x144 (Release, keyframe): smooth AO 46.4 dB, colour 38.3 dB at crf 23.
  const SyntheticView view{256, 144};
  for (auto [buffer, min_db] : {std::pair{test::make_smooth_ao(view), 44.0}, {test::make_colour(view), 36.0}}) {
    auto codec = h264({{"crf", 23}});
    std::vector<uint8_t> bytes;
    codec->encode(buffer, {}, bytes);
    const PassBuffer out = decode_or_fail(*codec, bytes, buffer.desc);
    const double db = test::buffer_psnr_db(buffer, out);
    std::printf("h264 crf 23 %s 256x144: %zu bytes, PSNR %.2f dB\n", pass_kind_name(buffer.desc.kind), bytes.size(),
                db);
    EXPECT_GE(db, min_db) << pass_kind_name(buffer.desc.kind);
  }
}

TEST(H264, KeyframeIsAStandardBitstream) {
  if (!has_codec("h264")) GTEST_SKIP() << "no h264 codec registered";
  for (const json& params : {json::object(), json{{"rate_control", "lossless"}}}) {
    const PassBuffer ao = test::make_smooth_ao({34, 20});
    auto codec = h264(params);
    std::vector<uint8_t> bytes;
    codec->encode(ao, {}, bytes);
    bool key = false;
    const auto luma = plain_decode_luma(bytes, 34, 20, &key);
    ASSERT_TRUE(luma.has_value()) << params.dump() << ": a plain H.264 decoder cannot decode the first frame";
    EXPECT_TRUE(key);
    EXPECT_EQ(*luma, decode_or_fail(*codec, bytes, ao.desc).bytes) << params.dump();
    if (params.contains("rate_control")) {
      EXPECT_EQ(*luma, ao.bytes) << "lossless";
    }
  }
  // Colour: the plain decoder sees a 4:2:0 picture of the padded size.
  const PassBuffer colour = test::make_colour({33, 21});
  auto codec = h264();
  std::vector<uint8_t> bytes;
  codec->encode(colour, {}, bytes);
  EXPECT_TRUE(plain_decode_luma(bytes, 34, 22).has_value());
}

TEST(H264, ForcedKeyframeMidStreamAndGop) {
  if (!has_codec("h264")) GTEST_SKIP() << "no h264 codec registered";
  auto codec = h264({{"gop", 5}});
  for (int f = 0; f < 8; ++f) {
    const PassBuffer ao = test::make_smooth_ao({48, 32, 2.0 * f, 0.0, uint32_t(f)});
    EncodeOptions options;
    options.force_keyframe = f == 3;
    std::vector<uint8_t> bytes;
    codec->encode(ao, options, bytes);
    // A keyframe decodes alone; x264 restarts the interval at a forced IDR: 0, 3, (8).
    const bool expect_key = f == 0 || f == 3;
    EXPECT_EQ(plain_decode_luma(bytes, 48, 32).has_value(), expect_key) << "frame " << f;
    decode_or_fail(*codec, bytes, ao.desc);
  }
}

TEST(H264, ResetStartsANewStream) {
  if (!has_codec("h264")) GTEST_SKIP() << "no h264 codec registered";
  auto codec = h264();
  std::vector<uint8_t> bytes;
  for (int f = 0; f < 3; ++f) {
    const PassBuffer ao = test::make_smooth_ao({32, 16, double(f), 0.0});
    codec->encode(ao, {}, bytes);
    decode_or_fail(*codec, bytes, ao.desc);
  }
  EXPECT_FALSE(plain_decode_luma(bytes, 32, 16).has_value()) << "frame 2 should be a P-frame";
  codec->reset();
  const PassBuffer ao = test::make_smooth_ao({32, 16, 3.0, 0.0});
  codec->encode(ao, {}, bytes);
  EXPECT_TRUE(plain_decode_luma(bytes, 32, 16).has_value()) << "the first frame after reset is a keyframe";
  const PassBuffer out = decode_or_fail(*codec, bytes, ao.desc);
  EXPECT_GE(test::buffer_psnr_db(ao, out), 35.0);
}

TEST(H264, PFrameSequenceRoundTrips) {
  if (!has_codec("h264")) GTEST_SKIP() << "no h264 codec registered";
  for (const json& params : {json::object(), json{{"rate_control", "lossless"}}}) {
    const bool lossless = params.contains("rate_control");
    auto codec = h264(params);
    size_t key_bytes = 0, p_bytes = 0;
    for (int f = 0; f < 10; ++f) {
      const SyntheticView view{64, 40, 1.5 * f, 0.5 * f, uint32_t(f)};
      for (const PassBuffer& in : {test::make_smooth_ao(view)}) {
        std::vector<uint8_t> bytes;
        codec->encode(in, {}, bytes);
        (f == 0 ? key_bytes : p_bytes) += bytes.size();
        const PassBuffer out = decode_or_fail(*codec, bytes, in.desc);
        if (lossless) {
          EXPECT_EQ(out.bytes, in.bytes) << "frame " << f;
        } else {
          EXPECT_GE(test::buffer_psnr_db(in, out), 32.0) << "frame " << f;  // measured 34.2-35.1 (64x40)
        }
      }
    }
    EXPECT_LT(p_bytes / 9, key_bytes) << params.dump() << ": P-frames are not smaller than the keyframe";
  }
  // Colour and soft visibility through the same stateful object, changing size mid-stream.
  auto codec = h264();
  for (int f = 0; f < 10; ++f) {
    const SyntheticView view{f < 5 ? 48 : 31, f < 5 ? 32 : 17, 2.0 * f, 0.0, uint32_t(f)};
    for (const PassBuffer& in : {test::make_colour(view)}) {
      std::vector<uint8_t> bytes;
      codec->encode(in, {}, bytes);
      const PassBuffer out = decode_or_fail(*codec, bytes, in.desc);
      EXPECT_EQ(out.bytes.size(), in.bytes.size());
      EXPECT_GE(test::buffer_psnr_db(in, out), 28.0) << "frame " << f;
    }
  }
}

TEST(H264, SlicesFitThePacketPayload) {
  if (!has_codec("h264")) GTEST_SKIP() << "no h264 codec registered";
  const PassBuffer noisy = test::make_noisy_ao({160, 96}, 8);
  for (int limit : {1100, 500}) {
    auto codec = h264({{"slice_max_size_bytes", limit}, {"crf", 10}});
    std::vector<uint8_t> bytes;
    codec->encode(noisy, {}, bytes);
    int slices = 0;
    for (auto [size, type] : nal_units(bytes))
      if (type == 1 || type == 5) {
        ++slices;
        EXPECT_LE(size, size_t(limit)) << "slice NAL of " << size << " bytes";
      }
    EXPECT_GT(slices, 1) << "the picture should need several slices";
    decode_or_fail(*codec, bytes, noisy.desc);
  }
}

TEST(H264, RefusesBitmasksAndEmptyPictures) {
  if (!has_codec("h264")) GTEST_SKIP() << "no h264 codec registered";
  auto codec = h264();
  EXPECT_FALSE(codec->lossless());
  EXPECT_TRUE(h264({{"rate_control", "lossless"}})->lossless());
  EXPECT_NE(codec->refuses({PassKind::Visibility, 16, 16, 4, 255}), "");
  EXPECT_NE(codec->refuses({PassKind::Ao, 0, 0, 1, 255}), "");
  EXPECT_EQ(codec->refuses({PassKind::SoftVisibility, 17, 13, 3, 255}), "");
  EXPECT_EQ(codec->refuses({PassKind::Colour, 1, 1, 3, 255}), "");
  std::vector<uint8_t> bytes;
  EXPECT_THROW(codec->encode(test::make_hard_visibility({16, 16}, 4), {}, bytes), Error);
}

TEST(H264, TinyAndOddPicturesWork) {
  if (!has_codec("h264")) GTEST_SKIP() << "no h264 codec registered";
  auto codec = h264();
  for (auto [w, h] : {std::pair{1, 1}, {17, 13}, {2, 1}, {1, 3}}) {
    const SyntheticView view{w, h};
    for (const PassBuffer& in : {test::make_smooth_ao(view), test::make_colour(view),
                                 test::make_soft_visibility(view, 3), test::make_noisy_ao(view, 8)}) {
      std::vector<uint8_t> bytes;
      codec->encode(in, {}, bytes);
      const PassBuffer out = decode_or_fail(*codec, bytes, in.desc);
      EXPECT_EQ(out.bytes.size(), in.bytes.size());
      if (in.desc.kind != PassKind::Colour) {
        for (uint8_t v : out.bytes) ASSERT_LE(v, in.desc.full_scale);
      }
    }
  }
}

// ---------------------------------------------------------------- delta specifics

// Mean coded bytes per frame of `frames` through a fresh codec, and a bit-exact check.
double mean_bytes(const char* name, const json& params, const std::vector<PassBuffer>& frames) {
  auto codec = registries().codecs.create(name, params);
  size_t total = 0;
  for (const PassBuffer& in : frames) {
    std::vector<uint8_t> bytes;
    codec->encode(in, {}, bytes);
    total += bytes.size();
    EXPECT_EQ(decode_or_fail(*codec, bytes, in.desc).bytes, in.bytes) << name;
  }
  return double(total) / double(frames.size());
}

TEST(Delta, SavesOnAStaticCameraAndReportsAMovingOne) {
  if (!has_codec("delta")) GTEST_SKIP() << "no delta codec registered";
  for (double shift_px : {0.0, 1.0, 4.0}) {
    std::vector<PassBuffer> ao, vis, noisy;
    for (int f = 0; f < 6; ++f) {
      const SyntheticView view{160, 90, shift_px * f, 0.0, uint32_t(f)};
      ao.push_back(test::make_smooth_ao(view));
      vis.push_back(test::make_hard_visibility(view, 4));
      noisy.push_back(test::make_noisy_ao(view, 8));
    }
    for (auto& [label, frames] : {std::pair<const char*, std::vector<PassBuffer>&>{"smooth_ao", ao},
                                  {"hard_vis_4", vis},
                                  {"noisy_ao_8", noisy}}) {
      const double plain = mean_bytes("zstd", json::object(), frames);
      const double delta = mean_bytes("delta", json::object(), frames);
      std::printf("160x90 %-10s pan %.0f px/frame: zstd %.0f B/frame, delta+zstd %.0f B/frame (%.0f%%)\n", label,
                  shift_px, plain, delta, 100.0 * delta / plain);
      if (shift_px == 0 && std::string(label) != "noisy_ao_8") {
        EXPECT_LT(delta, 0.5 * plain) << label << ": a static view should cost little after the keyframe";
      }
    }
  }
}

TEST(Delta, LostFrameFailsUntilTheNextKeyframe) {
  if (!has_codec("delta")) GTEST_SKIP() << "no delta codec registered";
  auto enc = registries().codecs.create("delta", {{"keyframe_interval", 4}});
  auto dec = registries().codecs.create("delta", {{"keyframe_interval", 4}});
  for (int f = 0; f < 9; ++f) {
    const PassBuffer in = test::make_hard_visibility({40, 24, double(f), 0.0}, 3);
    std::vector<uint8_t> bytes;
    enc->encode(in, {}, bytes);
    EXPECT_EQ(bytes[0], (f % 4 == 0) ? 'K' : 'D') << "frame " << f;
    if (f == 1) continue;  // lost on the link
    PassBuffer out;
    std::string error;
    const bool ok = dec->decode(bytes, in.desc, out, error);
    EXPECT_EQ(ok, f == 0 || f >= 4) << "frame " << f << ": " << error;
    if (ok) {
      EXPECT_EQ(out.bytes, in.bytes) << "frame " << f;
    }
  }
}

TEST(Delta, InnerLevelsAreValidated) {
  if (!has_codec("delta")) GTEST_SKIP() << "no delta codec registered";
  EXPECT_THROW(registries().codecs.create("delta", {{"inner", "lz4"}, {"level", 2}}), Error);
  EXPECT_THROW(registries().codecs.create("delta", {{"inner", "lz4"}, {"level", 13}}), Error);
  EXPECT_NO_THROW(registries().codecs.create("delta", {{"inner", "lz4"}, {"level", 12}}));
  EXPECT_NO_THROW(registries().codecs.create("delta", {{"inner", "zstd"}, {"level", 19}}));
}

}  // namespace
}  // namespace dhr
