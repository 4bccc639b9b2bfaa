#include "core/buffers/buffer_layout.h"

#include "core/base/error.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace dhr {
namespace {

static_assert(std::endian::native == std::endian::little, "the 8-byte loads below assume little-endian");

// Transposes an 8x8 bit matrix held in a uint64: bit 8r+c <-> bit 8c+r (Hacker's Delight,
// 2nd ed., figure 7-6, "transpose8rS64"). Byte r = pixel r of a group, bit c = light c, so
// the result's byte c holds light c for the 8 pixels. The transform is its own inverse.
constexpr uint64_t transpose8x8(uint64_t x) {
  uint64_t t = (x ^ (x >> 7)) & 0x00AA00AA00AA00AAull;
  x = x ^ t ^ (t << 7);
  t = (x ^ (x >> 14)) & 0x0000CCCC0000CCCCull;
  x = x ^ t ^ (t << 14);
  t = (x ^ (x >> 28)) & 0x00000000F0F0F0F0ull;
  return x ^ t ^ (t << 28);
}

// spread[b]: bit k of b moved to bit 0 of byte k (8 pixels of one light -> 8 pixel bytes).
constexpr std::array<uint64_t, 256> make_spread() {
  std::array<uint64_t, 256> t{};
  for (unsigned b = 0; b < 256; ++b)
    for (unsigned k = 0; k < 8; ++k)
      if (b >> k & 1u) t[b] |= uint64_t(1) << (8 * k);
  return t;
}
constexpr std::array<uint64_t, 256> kSpread = make_spread();

// Up to 8 lights (one byte per pixel), whole blocks of 16 pixels: bit j of 16 pixel bytes
// is moved to the sign bit and collected with one movemask. Returns the pixels done.
size_t to_planes_one_byte_fast(const uint8_t* in, size_t n, int lights, size_t plane, uint8_t* out, uint8_t& bad_bits) {
#if defined(__SSE2__)
  const size_t blocks = n / 16;
  __m128i any = _mm_setzero_si128();
  for (size_t b = 0; b < blocks; ++b) {
    const __m128i x = _mm_loadu_si128(reinterpret_cast<const __m128i*>(in + 16 * b));
    any = _mm_or_si128(any, x);
    for (int j = 0; j < lights; ++j) {
      // Shifting 64-bit lanes left by 7 - j puts bit j of every byte at bit 7 of that byte.
      const int mask = _mm_movemask_epi8(_mm_sll_epi64(x, _mm_cvtsi32_si128(7 - j)));
      const uint16_t bits = uint16_t(mask);
      std::memcpy(out + size_t(j) * plane + 2 * b, &bits, 2);
    }
  }
  alignas(16) uint8_t lanes[16];
  _mm_store_si128(reinterpret_cast<__m128i*>(lanes), any);
  for (uint8_t v : lanes) bad_bits |= v;
  return blocks * 16;
#else
  (void)in, (void)n, (void)lights, (void)plane, (void)out, (void)bad_bits;
  return 0;
#endif
}

void check_desc(const PassDesc& desc, const char* what) {
  if (desc.layout() != PassLayout::Bitmask)
    fail("{}: a {} buffer is not a visibility bitmask", what, pass_kind_name(desc.kind));
  if (std::string why = desc.validate(); !why.empty()) fail("{}: invalid visibility description: {}", what, why);
}

void check_size(const char* what, const char* name, size_t have, size_t want) {
  if (have != want) fail("{}: {} holds {} bytes, {} expected", what, name, have, want);
}

}  // namespace

size_t visibility_plane_bytes(int width, int height) {
  return (size_t(std::max(width, 0)) * size_t(std::max(height, 0)) + 7) / 8;
}

size_t visibility_planes_size(const PassDesc& desc) {
  return size_t(desc.channels) * visibility_plane_bytes(desc.width, desc.height);
}

bool visibility_unused_bits_clear(const PassDesc& desc, std::span<const uint8_t> interleaved) {
  const int lights = desc.channels;
  if (lights % 8 == 0) return true;
  const size_t bpp = size_t(lights + 7) / 8;
  const uint8_t unused = uint8_t(0xFFu << (lights % 8));
  uint8_t any = 0;
  for (size_t i = bpp - 1; i < interleaved.size(); i += bpp) any |= interleaved[i];
  return (any & unused) == 0;
}

void visibility_to_planes(const PassDesc& desc, std::span<const uint8_t> in, std::span<uint8_t> out) {
  constexpr const char* what = "visibility_to_planes";
  check_desc(desc, what);
  check_size(what, "the interleaved buffer", in.size(), desc.byte_size());
  check_size(what, "the planar buffer", out.size(), visibility_planes_size(desc));
  const int lights = desc.channels;
  const size_t n = size_t(desc.width) * size_t(desc.height);
  const size_t bpp = size_t(lights + 7) / 8;
  const size_t plane = visibility_plane_bytes(desc.width, desc.height);
  // Unused bits of the last byte of every pixel, replicated over the 8 pixels of a group.
  const uint64_t unused = (lights % 8 == 0) ? 0 : uint64_t(uint8_t(0xFFu << (lights % 8))) * 0x0101010101010101ull;
  uint64_t bad = 0;
  size_t first_group = 0;
  if (bpp == 1) {
    uint8_t bad_bits = 0;
    first_group = to_planes_one_byte_fast(in.data(), n, lights, plane, out.data(), bad_bits) / 8;
    bad |= bad_bits & unused;
  }
  for (size_t i = first_group; i < plane; ++i) {
    const size_t p0 = i * 8;
    const size_t count = std::min<size_t>(8, n - p0);
    for (size_t g = 0; g < bpp; ++g) {
      uint64_t x = 0;
      if (bpp == 1 && count == 8) {
        std::memcpy(&x, in.data() + p0, 8);
      } else {
        for (size_t p = 0; p < count; ++p) x |= uint64_t(in[(p0 + p) * bpp + g]) << (8 * p);
      }
      if (g == bpp - 1) bad |= x & unused;
      const uint64_t t = transpose8x8(x);
      const int in_group = std::min(8, lights - int(8 * g));
      for (int j = 0; j < in_group; ++j) out[(8 * g + size_t(j)) * plane + i] = uint8_t(t >> (8 * j));
    }
  }
  if (bad)
    fail("{}: a pixel of a {}-light bitmask has a bit >= {} set (unused bits must be zero)", what, lights, lights);
}

bool visibility_from_planes(const PassDesc& desc, std::span<const uint8_t> planes, std::span<uint8_t> out) {
  constexpr const char* what = "visibility_from_planes";
  check_desc(desc, what);
  check_size(what, "the planar buffer", planes.size(), visibility_planes_size(desc));
  check_size(what, "the interleaved buffer", out.size(), desc.byte_size());
  const int lights = desc.channels;
  const size_t n = size_t(desc.width) * size_t(desc.height);
  const size_t bpp = size_t(lights + 7) / 8;
  const size_t plane = visibility_plane_bytes(desc.width, desc.height);
  if (n % 8 != 0) {
    const uint8_t padding = uint8_t(0xFFu << (n % 8));
    for (int l = 0; l < lights; ++l)
      if (planes[size_t(l) * plane + plane - 1] & padding) return false;
  }
  size_t first_group = 0;
  if (bpp == 1) {
    // Up to 8 lights: each plane byte spreads into the 8 pixel bytes through a table.
    first_group = n / 8;
    for (size_t i = 0; i < first_group; ++i) {
      uint64_t x = 0;
      for (int j = 0; j < lights; ++j) x |= kSpread[planes[size_t(j) * plane + i]] << j;
      std::memcpy(out.data() + i * 8, &x, 8);
    }
  }
  for (size_t i = first_group; i < plane; ++i) {
    const size_t p0 = i * 8;
    const size_t count = std::min<size_t>(8, n - p0);
    for (size_t g = 0; g < bpp; ++g) {
      const int in_group = std::min(8, lights - int(8 * g));
      uint64_t x = 0;
      for (int j = 0; j < in_group; ++j) x |= uint64_t(planes[(8 * g + size_t(j)) * plane + i]) << (8 * j);
      const uint64_t t = transpose8x8(x);
      if (bpp == 1 && count == 8) {
        std::memcpy(out.data() + p0, &t, 8);
      } else {
        for (size_t p = 0; p < count; ++p) out[(p0 + p) * bpp + g] = uint8_t(t >> (8 * p));
      }
    }
  }
  return true;
}

VisibilityLayout parse_visibility_layout(const std::string& name) {
  if (name == "interleaved") return VisibilityLayout::Interleaved;
  if (name == "planes") return VisibilityLayout::Planes;
  fail("unknown visibility layout '{}' (valid: interleaved, planes)", name);
}

bool needs_layout_conversion(const PassDesc& desc, VisibilityLayout layout) {
  return desc.layout() == PassLayout::Bitmask && layout == VisibilityLayout::Planes;
}

size_t coded_size(const PassDesc& desc, VisibilityLayout layout) {
  return needs_layout_conversion(desc, layout) ? visibility_planes_size(desc) : desc.byte_size();
}

std::span<const uint8_t> to_coded_layout(const PassBuffer& in, VisibilityLayout layout, std::vector<uint8_t>& scratch) {
  if (std::string why = in.desc.validate(); !why.empty()) fail("invalid buffer description: {}", why);
  if (in.bytes.size() != in.desc.byte_size())
    fail("a {}x{} {} buffer holds {} bytes, {} expected", in.desc.width, in.desc.height, pass_kind_name(in.desc.kind),
         in.bytes.size(), in.desc.byte_size());
  if (!needs_layout_conversion(in.desc, layout)) return in.bytes;
  scratch.resize(visibility_planes_size(in.desc));
  visibility_to_planes(in.desc, in.bytes, scratch);
  return scratch;
}

bool from_coded_planes(const PassDesc& desc, std::span<const uint8_t> planes, std::vector<uint8_t>& out,
                       std::string& error) {
  out.resize(desc.byte_size());
  if (!visibility_from_planes(desc, planes, out)) {
    error = "padding bits of a bit-plane are set (corrupt data)";
    return false;
  }
  return true;
}

}  // namespace dhr
