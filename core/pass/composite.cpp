// The composite (see core/pass/composite.h): decoding of the passes, the shading kernel per pixel
// and sRGB tone mapping.
#include "core/pass/composite.h"

#include "core/base/avx512.h"
#include "core/base/error.h"
#include "core/base/vec8.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

namespace dhr {

namespace {

double srgb_to_linear(double v) { return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4); }

// Linear values at which the rounded 8-bit sRGB code steps from k-1 to k (k = 1..255): the
// code of a value is the number of boundaries <= it. The first boundary, 1.5e-4, lies above
// 2^-13 and the last, 0.99, below 1. The floats of [2^-13, 1) fall in 128 buckets per binade
// (their exponent and top 7 mantissa bits), and no bucket holds more than one boundary after
// its first float (checked when the table is built). Within a bucket every float shares its
// top 16 bits, so comparing the low 16 bits as integers compares the floats (all positive).
// A bucket's entry packs its first float's code (bits 17-24) and the low 16 bits of its
// boundary, or 0x10000, above any low bits, when it has none: one lookup and one integer
// comparison per value (srgb8_code; srgb8_x16 looks up only the values near a boundary).
constexpr int kBucketBits = 7;
constexpr int kLowBits = 23 - kBucketBits;
constexpr uint32_t kLowMask = (1u << kLowBits) - 1u;
constexpr uint32_t kFirstBucketExponent = 127 - 13;  // biased exponent of 2^-13
struct SrgbCodes {
  std::array<float, 255> boundary{};
  std::array<uint32_t, 13u << kBucketBits> bucket{};  // code << 17 | boundary's low bits (or 0x10000)
  alignas(64) std::array<float, 16> scale{};          // srgb8_x16's 255 * 1.055 * 2^(5 (k - 13) / 12)
};

const SrgbCodes& srgb_codes() {
  static const SrgbCodes table = [] {
    SrgbCodes t;
    for (int k = 1; k <= 255; ++k) t.boundary[size_t(k - 1)] = float(srgb_to_linear((k - 0.5) / 255.0));
    const auto codes = [&](float v) {
      return std::upper_bound(t.boundary.begin(), t.boundary.end(), v) - t.boundary.begin();
    };
    for (uint32_t i = 0; i < t.bucket.size(); ++i) {
      const uint32_t first = (i + (kFirstBucketExponent << kBucketBits)) << kLowBits;
      const float last = std::bit_cast<float>(first + kLowMask);
      const auto start = codes(std::bit_cast<float>(first)), inside = codes(last) - start;
      if (inside > 1)
        fail("composite: sRGB code bucket {} ([{}, {}]) holds {} boundaries, the lookup takes at most one", i,
             std::bit_cast<float>(first), last, inside);
      const uint32_t low = inside ? std::bit_cast<uint32_t>(t.boundary[size_t(start)]) & kLowMask : kLowMask + 1u;
      t.bucket[i] = uint32_t(start) << (kLowBits + 1) | low;
    }
    for (int k = 0; k < 16; ++k) t.scale[size_t(k)] = float(255.0 * 1.055 * std::exp2(5.0 * (k - 13) / 12.0));
    return t;
  }();
  return table;
}

// The 8-bit sRGB code of a linear value: the number of code boundaries <= linear (what
// std::upper_bound counts); 0 for linear <= 0 and NaN. The bucket's entry gives the count at
// the bucket's first float and its boundary, if any.
inline uint8_t srgb8_code(const SrgbCodes& t, float linear) {
  if (!(linear >= 0x1p-13f)) return 0;  // NaN, <= 0, or below the first boundary
  if (linear >= 1.0f) return 255;       // above the last
  const uint32_t bits = std::bit_cast<uint32_t>(linear);
  const uint32_t e = t.bucket[(bits >> kLowBits) - (kFirstBucketExponent << kBucketBits)];
  return uint8_t((e >> (kLowBits + 1)) + ((bits & kLowMask) >= (e & (2u * kLowMask + 1u)) ? 1u : 0u));
}

// The inputs of the shading, one slot per composited meaning. A new composite term is a slot
// here (and its case in place()), the row of values it reads in composite() and
// composite_fractions() below, its member of PixelTerms and its plane in RowPlanes, and its use
// in shade_row and in shade_lambert (core/pass/composite.h).
template <class T>
struct CompositeInputs {
  T visibility{};     // V_l per light
  T ao{};             // AO
  uint32_t seen = 0;  // bit m: a pass of meaning m was placed

  // Where the pass of `meaning` goes; dhr::Error for a meaning the composite does not shade or
  // a second pass of one meaning.
  void place(PassMeaning meaning, T value) {
    T* slot = nullptr;
    switch (meaning) {
      case PassMeaning::Visibility: slot = &visibility; break;
      case PassMeaning::Ao: slot = &ao; break;
      case PassMeaning::Colour:
      case PassMeaning::Depth: break;
    }
    if (!slot) fail("composite: a {} pass is displayed or read as it is, not composited", pass_meaning_name(meaning));
    const uint32_t bit = 1u << unsigned(meaning);
    if (seen & bit) fail("composite: two {} passes", pass_meaning_name(meaning));
    seen |= bit;
    *slot = value;
  }
};

// A composited pass must be of its slot's meaning, one channel per light for visibility, and
// match the G-buffer and its own description.
void check_pass(const PassBuffer& pb, const GBuffer& g, const Scene& scene, PassMeaning meaning) {
  const std::string problem = pb.desc.validate();
  if (!problem.empty()) fail("composite: {} pass: {}", pass_kind_name(pb.desc.kind), problem);
  const PassLayout layout = pb.desc.layout();
  if (pass_meaning(pb.desc.kind) != meaning || (layout != PassLayout::Bitmask && layout != PassLayout::Planes8))
    fail("composite: got a {} pass where a {} pass was expected", pass_kind_name(pb.desc.kind),
         pass_meaning_name(meaning));
  if (pb.desc.width != g.width() || pb.desc.height != g.height())
    fail("composite: {} pass is {}x{}, the G-buffer {}x{}", pass_kind_name(pb.desc.kind), pb.desc.width, pb.desc.height,
         g.width(), g.height());
  if (meaning == PassMeaning::Visibility && size_t(pb.desc.channels) != scene.lights.size())
    fail("composite: {} pass has {} channels, the scene {} lights", pass_kind_name(pb.desc.kind), pb.desc.channels,
         scene.lights.size());
  if (pb.bytes.size() != pb.desc.byte_size())
    fail("composite: {} pass has {} bytes, its description needs {}", pass_kind_name(pb.desc.kind), pb.bytes.size(),
         pb.desc.byte_size());
}

// ---- the shading, eight pixels at a time ----
// shade_lambert (core/pass/composite.h) over a row, written with GCC's vector extension: the same
// operations per pixel in the same order (every product, sum, square root and division rounded
// on its own; neither target has FMA instructions, so nothing is contracted), so the same bits
// as the scalar kernel on every pixel (Composite.RowKernelMatchesShadeLambert in
// tests/core/trace/test_trace.cpp). A light that the scalar kernel skips for a pixel (out of range, at its
// centre, facing away, invisible) leaves that lane's sum untouched. Vec8 and the AVX2/baseline
// clones: core/base/vec8.h.

// One light's constants, as the scalar kernel computes them per pixel.
struct LightTerm {
  const Light* light = nullptr;
  bool sphere = true;
  bool skip = false;    // a distant light without a direction: no term
  bool ranged = false;  // range_m > 0
  float range2 = 0.0f;  // range_m * range_m
  float radius2 = 0.0f;
  float length = 1.0f;  // |direction|
};

std::vector<LightTerm> light_terms(const Scene& scene) {
  std::vector<LightTerm> out;
  for (const Light& L : scene.lights) {
    LightTerm t;
    t.light = &L;
    t.sphere = L.type == LightType::Sphere;
    t.ranged = L.range_m > 0.0f;
    t.range2 = L.range_m * L.range_m;
    t.radius2 = L.radius_m * L.radius_m;
    if (!t.sphere) {
      t.length = glm::length(L.direction);
      t.skip = !(t.length > 0.0f);
    }
    out.push_back(t);
  }
  return out;
}

// The inputs of one row, planar, `stride` floats per plane (a multiple of 8).
struct RowPlanes {
  size_t stride = 0;
  std::vector<float> data;  // p.xyz, n.xyz, albedo.xyz, ao, then one plane of V per light
  float* plane(int i) { return data.data() + size_t(i) * stride; }
  const float* plane(int i) const { return data.data() + size_t(i) * stride; }
};
constexpr int kPlaneAo = 9, kPlaneVisibility = 10;

// linear[c][x] = exposure * albedo * (ambient * AO + sum_l V_l * ...), for x < count (a
// multiple of 8, at most in.stride); linear's planes are in.stride apart.
DHR_VEC8_TARGETS void shade_row(const RowPlanes& in, size_t count, const LightTerm* lights, int light_count,
                                glm::vec3 ambient, float exposure, float* linear) {
  constexpr float kMinDistance2 = 1e-6f;
  const size_t n = in.stride;
  for (size_t i = 0; i < count; i += 8) {
    const Vec8 px = load8(in.plane(0) + i), py = load8(in.plane(1) + i), pz = load8(in.plane(2) + i);
    const Vec8 nx = load8(in.plane(3) + i), ny = load8(in.plane(4) + i), nz = load8(in.plane(5) + i);
    const Vec8 ao = load8(in.plane(kPlaneAo) + i);
    Vec8 lx = ambient.x * ao, ly = ambient.y * ao, lz = ambient.z * ao;
    for (int l = 0; l < light_count; ++l) {
      const LightTerm& L = lights[l];
      if (L.skip) continue;
      const Light& light = *L.light;
      Mask8 ok = Mask8{} == 0;  // all lanes
      Vec8 n_dot_l, falloff;
      if (L.sphere) {
        const Vec8 tx = light.position.x - px, ty = light.position.y - py, tz = light.position.z - pz;
        const Vec8 d2 = tx * tx + ty * ty + tz * tz;
        if (L.ranged) ok &= !(d2 > L.range2);
        Vec8 d;
        for (int k = 0; k < 8; ++k) d[k] = std::sqrt(d2[k]);
        ok &= d > 0.0f;
        n_dot_l = (nx * tx + ny * ty + nz * tz) / d;
        Vec8 m = d2;  // std::max({d2, radius^2, kMinDistance2}): the first largest
        m = m < L.radius2 ? splat8(L.radius2) : m;
        m = m < kMinDistance2 ? splat8(kMinDistance2) : m;
        falloff = 1.0f / m;
      } else {
        n_dot_l = (nx * light.direction.x + ny * light.direction.y + nz * light.direction.z) / L.length;
        falloff = splat8(1.0f);
      }
      const Vec8 v = load8(in.plane(kPlaneVisibility + l) + i);
      ok &= n_dot_l > 0.0f;
      ok &= v > 0.0f;
      const Vec8 s = v * light.intensity * n_dot_l * falloff;
      lx = ok ? lx + s * light.colour.x : lx;
      ly = ok ? ly + s * light.colour.y : ly;
      lz = ok ? lz + s * light.colour.z : lz;
    }
    store8(linear + i, load8(in.plane(6) + i) * lx * exposure);
    store8(linear + n + i, load8(in.plane(7) + i) * ly * exposure);
    store8(linear + 2 * n + i, load8(in.plane(8) + i) * lz * exposure);
  }
}

// Row [first, first + n) of an 8-bit one-channel pass as fractions, min(1, byte / full_scale),
// or `absent` everywhere without the pass.
void fraction_row(const PassBuffer* pass, size_t first, size_t n, float absent, float* __restrict out) {
  if (!pass) return std::fill(out, out + n, absent);
  const float scale = 1.0f / float(pass->desc.full_scale);
  const uint8_t* __restrict in = pass->bytes.data() + first;
  for (size_t i = 0; i < n; ++i) out[i] = std::min(1.0f, float(in[i]) * scale);
}

// The same from per-pixel fractions (empty: absent).
void fraction_row(std::span<const float> values, size_t first, size_t n, float absent, float* out) {
  if (values.empty()) return std::fill(out, out + n, absent);
  std::copy_n(values.begin() + std::ptrdiff_t(first), n, out);
}

// A row's G-buffer values into the first nine planes (position, normal, albedo): the geometric
// normal where the shading normal is zero or NaN. Both normals are read and the choice is a
// select, so that the loop has no branch: built for AVX2 and the baseline, it is vectorized.
DHR_VEC8_TARGETS void gbuffer_row(const float* __restrict pos, const float* __restrict nrm, const float* __restrict geo,
                                  const float* __restrict alb, int w, float* const* planes) {
  float* __restrict px = planes[0];
  float* __restrict py = planes[1];
  float* __restrict pz = planes[2];
  float* __restrict nx = planes[3];
  float* __restrict ny = planes[4];
  float* __restrict nz = planes[5];
  float* __restrict ax = planes[6];
  float* __restrict ay = planes[7];
  float* __restrict az = planes[8];
  for (int x = 0; x < w; ++x) {
    const size_t i = 3 * size_t(x);
    const float sx = nrm[i], sy = nrm[i + 1], sz = nrm[i + 2];
    const bool fallback = !(sx * sx + sy * sy + sz * sz > 0.0f);  // glm::dot's sum, in its order
    px[x] = pos[i], py[x] = pos[i + 1], pz[x] = pos[i + 2];
    nx[x] = fallback ? geo[i] : sx, ny[x] = fallback ? geo[i + 1] : sy, nz[x] = fallback ? geo[i + 2] : sz;
    ax[x] = alb[i], ay[x] = alb[i + 1], az[x] = alb[i + 2];
  }
}

// What the 16-lane row kernel reads of the passes: composite() of pass buffers. (The float
// fractions of composite_fractions take the row path only.)
struct PassBytes {
  const uint8_t* ao = nullptr;   // null: AO = 1
  float ao_scale = 1.0f;         // 1 / full_scale
  const uint8_t* vis = nullptr;  // null: fully lit
  bool bitmask = false;
  size_t bpp = 0;          // bitmask: bytes per pixel
  size_t plane = 0;        // 8-bit planes: pixels per plane
  float vis_scale = 1.0f;  // 8-bit planes: 1 / full_scale
};

std::atomic<bool> g_row_path_only{false};

#if DHR_AVX512_KERNELS
// All lanes, for the zero-masked forms of the intrinsics whose plain forms GCC 12 warns about
// (an undefined source "used uninitialized").
constexpr __mmask16 kAll = 0xffff;

// pshufb masks that interleave 16 R, G and B bytes into 48: [output block][channel][byte].
struct RgbShuffles {
  int8_t m[3][3][16];
};
constexpr RgbShuffles make_rgb_shuffles() {
  RgbShuffles s{};
  for (int o = 0; o < 3; ++o)
    for (int c = 0; c < 3; ++c)
      for (int k = 0; k < 16; ++k) {
        const int j = 16 * o + k;
        s.m[o][c][k] = j % 3 == c ? int8_t(j / 3) : int8_t(-128);  // high bit: a zero byte
      }
  return s;
}
constexpr RgbShuffles kRgbShuffles = make_rgb_shuffles();

// fraction_row of 16 bytes: min(1, byte * scale), as std::min(1.0f, v) (v < 1 ? v : 1).
DHR_AVX512_TARGET inline __m512 fractions_x16(const uint8_t* bytes, float scale) {
  const __m128i b = _mm_loadu_si128(reinterpret_cast<const __m128i*>(bytes));
  const __m512 v =
      _mm512_mul_ps(_mm512_maskz_cvtepi32_ps(kAll, _mm512_maskz_cvtepu8_epi32(kAll, b)), _mm512_set1_ps(scale));
  return _mm512_maskz_min_ps(kAll, v, _mm512_set1_ps(1.0f));
}

// srgb8_code of the lanes of `mid`, whose values lie in [2^-13, 1) (the others 0): the bucket
// table's entries gathered and compared as srgb8_code compares them.
DHR_AVX512_TARGET inline __m512i srgb8_lookup_x16(const SrgbCodes& t, __m512 v, __mmask16 mid) {
  const __m512i bits = _mm512_castps_si512(v);
  const __m512i bucket = _mm512_sub_epi32(_mm512_maskz_srli_epi32(kAll, bits, kLowBits),
                                          _mm512_set1_epi32(int32_t(kFirstBucketExponent << kBucketBits)));
  const __m512i e = _mm512_mask_i32gather_epi32(_mm512_setzero_si512(), mid, bucket, t.bucket.data(), 4);
  const __mmask16 past = _mm512_cmpge_epu32_mask(_mm512_and_si512(bits, _mm512_set1_epi32(int32_t(kLowMask))),
                                                 _mm512_and_si512(e, _mm512_set1_epi32(int32_t(2u * kLowMask + 1u))));
  return _mm512_mask_add_epi32(_mm512_maskz_srli_epi32(mid, e, kLowBits + 1), mid & past,
                               _mm512_maskz_srli_epi32(mid, e, kLowBits + 1), _mm512_set1_epi32(1));
}

// srgb8_code of 16 values without a lookup where it can: y = 255 sRGB(v) + 0.5 evaluated in
// float, the code floor(y), except within kSlack of an integer, where a boundary may lie, and
// those lanes (a fraction of a percent) are looked up (srgb8_lookup_x16). Below the sRGB curve's
// linear end y = 255 * 12.92 v + 0.5; above it v^(5/12) = 2^(5e/12) m^(5/12) with v = 2^e m,
// m in [1, 2): the first factor from a table by e (SrgbCodes::scale), the second a degree-6 polynomial in m - 1.5
// (the Chebyshev interpolant on [1, 2] in the power basis, coefficients rounded to float; its
// relative error 6.3e-7, so y is within about 2e-4 of 255 sRGB(v) + 0.5). The FMAs round once
// where a product and a sum would round twice; nothing here needs the scalar code's roundings,
// only its codes. That every float gets srgb8_code's code is checked for every float of
// [2^-14, 2] and the special values (Composite.ToneMapManyMatchesOneAtATime,
// tests/core/trace/test_trace.cpp; it fails with kSlack = 1e-5 or a coefficient off by 5e-5).
DHR_AVX512_TARGET inline __m512i srgb8_x16(const SrgbCodes& t, __m512 v) {
  constexpr float kSlack = 1e-3f;
  const __mmask16 ge = _mm512_cmp_ps_mask(v, _mm512_set1_ps(0x1p-13f), _CMP_GE_OQ);  // false for NaN
  const __mmask16 top = _mm512_cmp_ps_mask(v, _mm512_set1_ps(1.0f), _CMP_GE_OQ);
  const __mmask16 mid = ge & __mmask16(~top);
  const __m512 e = _mm512_maskz_getexp_ps(kAll, v);
  const __m512 m =
      _mm512_sub_ps(_mm512_maskz_getmant_ps(kAll, v, _MM_MANT_NORM_1_2, _MM_MANT_SIGN_zero), _mm512_set1_ps(1.5f));
  __m512 p = _mm512_set1_ps(-2.716104267e-03f);
  p = _mm512_fmadd_ps(p, m, _mm512_set1_ps(5.186546128e-03f));
  p = _mm512_fmadd_ps(p, m, _mm512_set1_ps(-9.634766728e-03f));
  p = _mm512_fmadd_ps(p, m, _mm512_set1_ps(2.243675478e-02f));
  p = _mm512_fmadd_ps(p, m, _mm512_set1_ps(-6.395599246e-02f));
  p = _mm512_fmadd_ps(p, m, _mm512_set1_ps(3.289056122e-01f));
  p = _mm512_fmadd_ps(p, m, _mm512_set1_ps(1.184053659e+00f));
  const __m512i k = _mm512_add_epi32(_mm512_maskz_cvttps_epi32(kAll, e), _mm512_set1_epi32(13));
  const __m512 scale = _mm512_maskz_permutexvar_ps(kAll, k, _mm512_load_ps(t.scale.data()));
  const __m512 y_pow = _mm512_fmsub_ps(scale, p, _mm512_set1_ps(255.0f * 0.055f - 0.5f));
  const __m512 y_lin = _mm512_fmadd_ps(v, _mm512_set1_ps(255.0f * 12.92f), _mm512_set1_ps(0.5f));
  const __m512 y = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(v, _mm512_set1_ps(0.0031308f), _CMP_LT_OQ), y_pow, y_lin);
  const __m512 near =
      _mm512_sub_ps(y, _mm512_maskz_roundscale_ps(kAll, y, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
  const __mmask16 unsure = mid & _mm512_cmp_ps_mask(_mm512_abs_ps(near), _mm512_set1_ps(kSlack), _CMP_LT_OQ);
  __m512i code = _mm512_maskz_cvt_roundps_epi32(mid, y, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
  code = _mm512_mask_mov_epi32(code, top, _mm512_set1_epi32(255));
  if (unsure) code = _mm512_mask_mov_epi32(code, unsure, srgb8_lookup_x16(t, v, unsure));
  return code;
}

// Codes 0-255 of 16 pixels' three channels as 48 interleaved RGB bytes at out.
DHR_AVX512_TARGET inline void store_rgb8_x16(__m512i r, __m512i g, __m512i b, uint8_t* out) {
  const __m128i ch[3] = {_mm512_maskz_cvtepi32_epi8(kAll, r), _mm512_maskz_cvtepi32_epi8(kAll, g),
                         _mm512_maskz_cvtepi32_epi8(kAll, b)};
  for (int o = 0; o < 3; ++o) {
    __m128i v = _mm_setzero_si128();
    for (int c = 0; c < 3; ++c)
      v = _mm_or_si128(
          v, _mm_shuffle_epi8(ch[c], _mm_loadu_si128(reinterpret_cast<const __m128i*>(kRgbShuffles.m[o][c]))));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + 16 * o), v);
  }
}

// tonemap_srgb8 of values [0, n - n % 16), 16 at a time. Returns where it ended.
DHR_AVX512_TARGET size_t tonemap_x16(const SrgbCodes& t, const float* linear, size_t n, uint8_t* out) {
  size_t i = 0;
  for (; i + 16 <= n; i += 16)
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + i),
                     _mm512_maskz_cvtepi32_epi8(kAll, srgb8_x16(t, _mm512_loadu_ps(linear + i))));
  return i;
}

// Light l's visibility in the 16 pixels from pixel i on: the lanes where V_l > 0, and there
// V_l * intensity as the scalar kernel makes it (where V_l is 0 or 1, a bitmask or no pass, that
// product is intensity itself). `bits`: a one-byte-per-pixel bitmask's 16 bytes, widened once
// per block.
struct Visibility16 {
  __mmask16 on;
  __m512 v_intensity;
};
DHR_AVX512_TARGET inline Visibility16 visibility_x16(const PassBytes& pb, size_t l, size_t i, __m512i bits,
                                                     float intensity) {
  const __m512 full = _mm512_set1_ps(intensity);
  if (!pb.vis) return {0xffff, full};
  if (!pb.bitmask) {
    const __m512 v = fractions_x16(pb.vis + l * pb.plane + i, pb.vis_scale);
    return {_mm512_cmp_ps_mask(v, _mm512_setzero_ps(), _CMP_GT_OQ), _mm512_mul_ps(v, full)};
  }
  if (pb.bpp == 1) return {_mm512_test_epi32_mask(bits, _mm512_set1_epi32(int32_t(1u << (l & 7)))), full};
  __mmask16 on = 0;
  const uint8_t* src = pb.vis + i * pb.bpp + (l >> 3);
  for (unsigned k = 0; k < 16; ++k) on |= __mmask16(((src[k * pb.bpp] >> (l & 7)) & 1u) << k);
  return {on, full};
}

// What a light's term reads of 16 pixels: point, normal, the passes, the first pixel's index
// and a one-byte bitmask's bytes (visibility_x16).
struct LightLanes16 {
  const __m512* p;
  const __m512* n;
  const PassBytes& pb;
  size_t i;
  __m512i vis_bits;
};

// shade_row's term of a light it does not skip in 16 lanes, up to the visibility: the lanes it
// may light, and n . l and the falloff there.
struct LightGeometry16 {
  __mmask16 ok;
  __m512 n_dot_l, falloff;
};
DHR_AVX512_TARGET inline LightGeometry16 light_geometry_x16(const LightTerm& L, const LightLanes16& in) {
  constexpr float kMinDistance2 = 1e-6f;
  const __m512 zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.0f);
  const Light& light = *L.light;
  const __m512* p = in.p;
  const __m512* n = in.n;
  if (!L.sphere) {
    const __m512 dot = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(n[0], _mm512_set1_ps(light.direction.x)),
                                                   _mm512_mul_ps(n[1], _mm512_set1_ps(light.direction.y))),
                                     _mm512_mul_ps(n[2], _mm512_set1_ps(light.direction.z)));
    return {0xffff, _mm512_div_ps(dot, _mm512_set1_ps(L.length)), one};
  }
  const __m512 tx = _mm512_sub_ps(_mm512_set1_ps(light.position.x), p[0]);
  const __m512 ty = _mm512_sub_ps(_mm512_set1_ps(light.position.y), p[1]);
  const __m512 tz = _mm512_sub_ps(_mm512_set1_ps(light.position.z), p[2]);
  const __m512 d2 = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(tx, tx), _mm512_mul_ps(ty, ty)), _mm512_mul_ps(tz, tz));
  __mmask16 ok = 0xffff;
  if (L.ranged) ok &= _mm512_cmp_ps_mask(d2, _mm512_set1_ps(L.range2), _CMP_NGT_UQ);
  const __m512 d = _mm512_maskz_sqrt_ps(kAll, d2);
  ok &= _mm512_cmp_ps_mask(d, zero, _CMP_GT_OQ);
  const __m512 dot =
      _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(n[0], tx), _mm512_mul_ps(n[1], ty)), _mm512_mul_ps(n[2], tz));
  // std::max({d2, radius^2, kMinDistance2}), the first largest: max(b, m) is m unless b > m
  // (equal values have the same bits: none is -0; a NaN d2 stays NaN, and its lane fails d > 0).
  const __m512 m = _mm512_maskz_max_ps(kAll, _mm512_set1_ps(kMinDistance2),
                                       _mm512_maskz_max_ps(kAll, _mm512_set1_ps(L.radius2), d2));
  return {ok, _mm512_div_ps(dot, d), _mm512_div_ps(one, m)};
}

// Light l's term added to (lx, ly, lz), as shade_row adds it.
DHR_AVX512_TARGET inline void add_light_x16(const LightTerm& L, int l, const LightLanes16& in, __m512& lx, __m512& ly,
                                            __m512& lz) {
  if (L.skip) return;
  const Light& light = *L.light;
  const __m512 zero = _mm512_setzero_ps();
  const LightGeometry16 geo = light_geometry_x16(L, in);
  const Visibility16 vis = visibility_x16(in.pb, size_t(l), in.i, in.vis_bits, light.intensity);
  const __mmask16 ok = geo.ok & _mm512_cmp_ps_mask(geo.n_dot_l, zero, _CMP_GT_OQ) & vis.on;
  const __m512 s = _mm512_mul_ps(_mm512_mul_ps(vis.v_intensity, geo.n_dot_l), geo.falloff);
  lx = _mm512_mask_add_ps(lx, ok, lx, _mm512_mul_ps(s, _mm512_set1_ps(light.colour.x)));
  ly = _mm512_mask_add_ps(ly, ok, ly, _mm512_mul_ps(s, _mm512_set1_ps(light.colour.y)));
  lz = _mm512_mask_add_ps(lz, ok, lz, _mm512_mul_ps(s, _mm512_set1_ps(light.colour.z)));
}

// Pixels [0, w - w % 16) of row y of the composite, 16 at a time: gbuffer_row's, fraction_row's
// and shade_row's values by the same IEEE operations in the same order (no FMA:
// DHR_AVX512_TARGET), and srgb8_code's codes (srgb8_x16), so the same bits as the row path.
// Returns where it ended.
DHR_AVX512_TARGET int composite_row16(const GBuffer& g, int y, const PassBytes& pb, const LightTerm* lights, int nl,
                                      glm::vec3 ambient, float exposure, const SrgbCodes& t, Rgb8 background,
                                      Rgb8* out) {
  static_assert(sizeof(Rgb8) == 3 && sizeof(glm::vec3) == 3 * sizeof(float));
  const int w = g.width();
  const size_t first = size_t(y) * size_t(w);
  const float* pos = &g.position(0, y).x;
  const float* nrm = &g.normal(0, y).x;
  const float* geo = &g.geo_normal(0, y).x;
  const float* alb = &g.albedo(0, y).x;
  const uint32_t* id = &g.object_id(0, y);
  const __m512 zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.0f);
  const __m512i bg_r = _mm512_set1_epi32(background.r), bg_g = _mm512_set1_epi32(background.g),
                bg_b = _mm512_set1_epi32(background.b);
  int x = 0;
  for (; x + 16 <= w; x += 16) {
    const size_t i = first + size_t(x);
    const __mmask16 bg = _mm512_cmpeq_epi32_mask(_mm512_loadu_si512(id + x), _mm512_set1_epi32(int32_t(kBackgroundId)));
    if (bg == 0xFFFF) {  // nothing covered: the background only
      store_rgb8_x16(bg_r, bg_g, bg_b, reinterpret_cast<uint8_t*>(out + x));
      continue;
    }
    const Xyz16 pv = load_xyz16(pos + 3 * size_t(x)), nv = load_xyz16(nrm + 3 * size_t(x));
    const __m512 p[3] = {pv.x, pv.y, pv.z};
    __m512 n[3] = {nv.x, nv.y, nv.z};
    // The geometric normal where the shading normal is zero or NaN (glm::dot's sum, in its order).
    const __m512 nn =
        _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(n[0], n[0]), _mm512_mul_ps(n[1], n[1])), _mm512_mul_ps(n[2], n[2]));
    const __mmask16 fallback = _mm512_cmp_ps_mask(nn, zero, _CMP_NGT_UQ);
    if (fallback) {
      const Xyz16 gv = load_xyz16(geo + 3 * size_t(x));
      const __m512 gn[3] = {gv.x, gv.y, gv.z};
      for (int k = 0; k < 3; ++k) n[k] = _mm512_mask_blend_ps(fallback, n[k], gn[k]);
    }
    const Xyz16 av = load_xyz16(alb + 3 * size_t(x));
    const __m512 a[3] = {av.x, av.y, av.z};
    const __m512 ao = pb.ao ? fractions_x16(pb.ao + i, pb.ao_scale) : one;
    const __m512i vis_bits =
        pb.vis && pb.bitmask && pb.bpp == 1
            ? _mm512_maskz_cvtepu8_epi32(kAll, _mm_loadu_si128(reinterpret_cast<const __m128i*>(pb.vis + i)))
            : _mm512_setzero_si512();
    __m512 lx = _mm512_mul_ps(_mm512_set1_ps(ambient.x), ao);
    __m512 ly = _mm512_mul_ps(_mm512_set1_ps(ambient.y), ao);
    __m512 lz = _mm512_mul_ps(_mm512_set1_ps(ambient.z), ao);
    const LightLanes16 in{p, n, pb, i, vis_bits};
    for (int l = 0; l < nl; ++l) add_light_x16(lights[l], l, in, lx, ly, lz);
    const __m512 ex = _mm512_set1_ps(exposure);
    const __m512i r = _mm512_mask_mov_epi32(srgb8_x16(t, _mm512_mul_ps(_mm512_mul_ps(a[0], lx), ex)), bg, bg_r);
    const __m512i gg = _mm512_mask_mov_epi32(srgb8_x16(t, _mm512_mul_ps(_mm512_mul_ps(a[1], ly), ex)), bg, bg_g);
    const __m512i bb = _mm512_mask_mov_epi32(srgb8_x16(t, _mm512_mul_ps(_mm512_mul_ps(a[2], lz), ex)), bg, bg_b);
    store_rgb8_x16(r, gg, bb, reinterpret_cast<uint8_t*>(out + x));
  }
  return x;
}
#endif

// vis_row(l, first, n, out) writes V_l of the n pixels from pixel `first` on; terms_row(first,
// n, in) the planes of their PixelTerms (kPlaneAo, ...). A row's pass values are read plane by
// plane, in loops the compiler vectorizes. Uncovered pixels are shaded with whatever their
// inputs hold, and never shown (the background is).
// bytes: the passes as the 16-lane row kernel reads them (null: the row path only).
template <class VisRow, class TermsRow>
ImageRGB8 composite_impl(const GBuffer& g, const Scene& scene, const CompositeSettings& settings, VisRow&& vis_row,
                         TermsRow&& terms_row, const PassBytes* bytes) {
  if (!(settings.exposure > 0.0f) || !std::isfinite(settings.exposure))
    fail("composite: exposure {} must be finite and > 0", settings.exposure);
  const int w = g.width(), h = g.height();
  ImageRGB8 out;
  out.resize_for_overwrite(w, h);  // every pixel is written below
#if DHR_AVX512_KERNELS
  const bool wide = bytes && cpu_has_avx512dq() && !g_row_path_only.load(std::memory_order_relaxed);
#else
  (void)bytes;
#endif
  const Rgb8 background = tonemap_srgb8(scene.background * settings.exposure);
  const std::vector<LightTerm> lights = light_terms(scene);
  const int nl = int(lights.size());
  const size_t stride = (size_t(w) + 7) / 8 * 8;
  const SrgbCodes& b = srgb_codes();
  tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
    RowPlanes in;
    in.stride = stride;
    in.data.assign(stride * size_t(kPlaneVisibility + nl), 0.0f);
    std::vector<float> linear(3 * stride);
    float* planes[9];
    for (int k = 0; k < 9; ++k) planes[k] = in.plane(k);
    for (int y = rows.begin(); y < rows.end(); ++y) {
      const size_t first = size_t(y) * size_t(w);
      int x0 = 0;  // pixels [x0, w) take the row path
#if DHR_AVX512_KERNELS
      if (wide)
        x0 = composite_row16(g, y, *bytes, lights.data(), nl, scene.ambient, settings.exposure, b, background,
                             &out(0, y));
#endif
      if (x0 == w) continue;
      const size_t n = size_t(w - x0), start = first + size_t(x0);
      static_assert(sizeof(glm::vec3) == 3 * sizeof(float));
      gbuffer_row(&g.position(x0, y).x, &g.normal(x0, y).x, &g.geo_normal(x0, y).x, &g.albedo(x0, y).x, int(n), planes);
      terms_row(start, n, in);
      for (int l = 0; l < nl; ++l) vis_row(size_t(l), start, n, in.plane(kPlaneVisibility + l));
      shade_row(in, (n + 7) / 8 * 8, lights.data(), nl, scene.ambient, settings.exposure, linear.data());
      const uint32_t* id = &g.object_id(x0, y);
      for (size_t i = 0; i < n; ++i)
        out(x0 + int(i), y) = id[i] != kBackgroundId ? Rgb8{srgb8_code(b, linear[i]), srgb8_code(b, linear[stride + i]),
                                                            srgb8_code(b, linear[2 * stride + i])}
                                                     : background;
    }
  });
  return out;
}

}  // namespace

uint8_t tonemap_srgb8(float linear) { return srgb8_code(srgb_codes(), linear); }

void tonemap_srgb8(std::span<const float> linear, std::span<uint8_t> out) {
  if (out.size() != linear.size())
    fail("tonemap_srgb8: {} linear values but room for {} codes; out must hold one code per value", linear.size(),
         out.size());
  const SrgbCodes& t = srgb_codes();
  size_t i = 0;
#if DHR_AVX512_KERNELS
  if (cpu_has_avx512dq() && !g_row_path_only.load(std::memory_order_relaxed))
    i = tonemap_x16(t, linear.data(), linear.size(), out.data());
#endif
  for (; i < linear.size(); ++i) out[i] = srgb8_code(t, linear[i]);
}

Rgb8 tonemap_srgb8(const glm::vec3& linear) {
  return {tonemap_srgb8(linear.x), tonemap_srgb8(linear.y), tonemap_srgb8(linear.z)};
}

ImageRGB8 composite(const GBuffer& g, const Scene& scene, std::span<const CompositePass> passes,
                    const CompositeSettings& settings) {
  CompositeInputs<const PassBuffer*> in;
  for (const CompositePass& p : passes)
    if (p.buffer) {
      in.place(p.meaning, p.buffer);
      check_pass(*p.buffer, g, scene, p.meaning);
    }
  const PassBuffer* visibility = in.visibility;
  const PassBuffer* ao = in.ao;
  const size_t npx = size_t(g.width()) * size_t(g.height());
  auto terms_row = [&](size_t first, size_t n, RowPlanes& rp) { fraction_row(ao, first, n, 1.0f, rp.plane(kPlaneAo)); };
  PassBytes pb;
  if (ao) pb.ao = ao->bytes.data(), pb.ao_scale = 1.0f / float(ao->desc.full_scale);
  if (visibility) {
    pb.vis = visibility->bytes.data();
    pb.bitmask = visibility->desc.layout() == PassLayout::Bitmask;
    pb.bpp = size_t((visibility->desc.channels + 7) / 8);
    pb.plane = npx;
    pb.vis_scale = 1.0f / float(visibility->desc.full_scale);
  }
  if (pb.bitmask) {
    const uint8_t* bytes = pb.vis;
    const size_t bpp = pb.bpp;
    return composite_impl(
        g, scene, settings,
        [&](size_t l, size_t first, size_t n, float* __restrict out) {
          const uint8_t* __restrict src = bytes + first * bpp + (l >> 3);
          for (size_t i = 0; i < n; ++i) out[i] = float((src[i * bpp] >> (l & 7)) & 1u);
        },
        terms_row, &pb);
  }
  // 8-bit planes, one per light, or no pass (fully lit).
  return composite_impl(
      g, scene, settings,
      [&](size_t l, size_t first, size_t n, float* out) { fraction_row(visibility, l * npx + first, n, 1.0f, out); },
      terms_row, &pb);
}

ImageRGB8 composite(const GBuffer& g, const Scene& scene, const PassBuffer* visibility, const PassBuffer* ao,
                    const CompositeSettings& settings) {
  const CompositePass passes[] = {{PassMeaning::Visibility, visibility}, {PassMeaning::Ao, ao}};
  return composite(g, scene, passes, settings);
}

ImageRGB8 composite_fractions(const GBuffer& g, const Scene& scene, std::span<const CompositeFractions> passes,
                              const CompositeSettings& settings) {
  CompositeInputs<std::span<const float>> in;
  for (const CompositeFractions& p : passes)
    if (!p.values.empty()) in.place(p.meaning, p.values);
  const std::span<const float> visibility = in.visibility, ao = in.ao;
  const size_t npx = size_t(g.width()) * size_t(g.height());
  if (!visibility.empty() && visibility.size() != npx * scene.lights.size())
    fail("composite: {} visibility values for {} pixels x {} lights", visibility.size(), npx, scene.lights.size());
  if (!ao.empty() && ao.size() != npx) fail("composite: {} AO values for {} pixels", ao.size(), npx);
  return composite_impl(
      g, scene, settings,
      [&](size_t l, size_t first, size_t n, float* out) { fraction_row(visibility, l * npx + first, n, 1.0f, out); },
      [&](size_t first, size_t n, RowPlanes& rp) { fraction_row(ao, first, n, 1.0f, rp.plane(kPlaneAo)); }, nullptr);
}

void composite_row_path_only(bool on) { g_row_path_only.store(on, std::memory_order_relaxed); }

}  // namespace dhr
