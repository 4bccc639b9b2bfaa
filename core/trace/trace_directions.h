// The tracer's direction kernels (internal to core/trace/trace_rows.cpp): sines and cosines without
// libm, orthonormal bases, cone and cosine-weighted hemisphere directions, sphere shadow-ray
// ends and ray validity. Each scalar form is the reference; the SSE2 versions do the same IEEE
// operations in the same order 4 lanes at a time, so results are bit-identical to it (and
// core/trace/trace_avx512.cpp's 16-lane versions to both).
#pragma once

#include "core/trace/trace.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace dhr::trace_detail {

// (cos 2 pi u, sin 2 pi u) for u in [0, 1) without libm: the quadrant from 4u, then
// polynomials on [0, pi/2] (Taylor to degree 8/9; the truncation error is largest at pi/2:
// (pi/2)^10 / 10! = 2.5e-5 for the cosine, (pi/2)^11 / 11! = 3.6e-6 for the sine -- a
// direction off by at most 2.5e-5 rad, far below what a ray needs; c^2 + s^2 = 1 within 1e-5;
// tests/core/trace/test_trace.cpp pins directions to a double-precision reference within 3e-5). Deterministic: no
// library or ISA dependence. Branch-free (the quarter turn is a swap and two sign flips, not
// a table lookup) so that the loops below vectorize.
// The scalar form is what the SSE2 code below reproduces lane by lane; it runs where SSE2 is absent.
[[maybe_unused]] inline void sincos_2pi(float u, float& c, float& s) {
  const float x = 4.0f * u;
  const int q = std::min(3, int(x));
  const float a = (x - float(q)) * (std::numbers::pi_v<float> / 2.0f);  // [0, pi/2)
  const float a2 = a * a;
  const float sa = a * (1.0f + a2 * (-1.0f / 6 + a2 * (1.0f / 120 + a2 * (-1.0f / 5040 + a2 * (1.0f / 362880)))));
  const float ca = 1.0f + a2 * (-0.5f + a2 * (1.0f / 24 + a2 * (-1.0f / 720 + a2 * (1.0f / 40320))));
  // Rotate by q quarter turns: (c, s) = (ca, sa), (-sa, ca), (-ca, -sa), (sa, -ca).
  const bool odd = (q & 1) != 0;
  const float c0 = odd ? sa : ca;
  const float s0 = odd ? ca : sa;
  c = ((q + 1) & 2) != 0 ? -c0 : c0;
  s = (q & 2) != 0 ? -s0 : s0;
}

// Rays are generated in chunks of up to kChunk samples of one pixel (and light): the hashes,
// directions and validity of a chunk are computed in straight loops over arrays.
constexpr int kChunk = 8;

#if defined(__SSE2__)
// Four lanes of the scalar helpers above, with the same IEEE operations in the same order
// (bit-identical results): GCC does not vectorize std::sqrt while errno is on, so the hot
// ray-generation loops use these SSE2 versions.
struct Vec3x4 {
  __m128 x, y, z;
};

inline __m128 select_ps(__m128 mask, __m128 a, __m128 b) {  // mask ? a : b
  return _mm_or_ps(_mm_and_ps(mask, a), _mm_andnot_ps(mask, b));
}

inline void sincos_2pi_x4(__m128 u, __m128& c, __m128& s) {
  const __m128 one = _mm_set1_ps(1.0f);
  const __m128i three = _mm_set1_epi32(3), one_i = _mm_set1_epi32(1), two_i = _mm_set1_epi32(2);
  const __m128 sign = _mm_castsi128_ps(_mm_set1_epi32(int32_t(0x80000000u)));
  const __m128 x = _mm_mul_ps(_mm_set1_ps(4.0f), u);
  __m128i q = _mm_cvttps_epi32(x);
  const __m128i gt = _mm_cmpgt_epi32(q, three);
  q = _mm_or_si128(_mm_and_si128(gt, three), _mm_andnot_si128(gt, q));
  const __m128 a = _mm_mul_ps(_mm_sub_ps(x, _mm_cvtepi32_ps(q)), _mm_set1_ps(std::numbers::pi_v<float> / 2.0f));
  const __m128 a2 = _mm_mul_ps(a, a);
  __m128 sa = _mm_add_ps(_mm_set1_ps(-1.0f / 5040), _mm_mul_ps(a2, _mm_set1_ps(1.0f / 362880)));
  sa = _mm_add_ps(_mm_set1_ps(1.0f / 120), _mm_mul_ps(a2, sa));
  sa = _mm_add_ps(_mm_set1_ps(-1.0f / 6), _mm_mul_ps(a2, sa));
  sa = _mm_add_ps(one, _mm_mul_ps(a2, sa));
  sa = _mm_mul_ps(a, sa);
  __m128 ca = _mm_add_ps(_mm_set1_ps(-1.0f / 720), _mm_mul_ps(a2, _mm_set1_ps(1.0f / 40320)));
  ca = _mm_add_ps(_mm_set1_ps(1.0f / 24), _mm_mul_ps(a2, ca));
  ca = _mm_add_ps(_mm_set1_ps(-0.5f), _mm_mul_ps(a2, ca));
  ca = _mm_add_ps(one, _mm_mul_ps(a2, ca));
  const __m128 odd = _mm_castsi128_ps(_mm_cmpeq_epi32(_mm_and_si128(q, one_i), one_i));
  const __m128 c0 = select_ps(odd, sa, ca);
  const __m128 s0 = select_ps(odd, ca, sa);
  const __m128 neg_c = _mm_castsi128_ps(_mm_cmpeq_epi32(_mm_and_si128(_mm_add_epi32(q, one_i), two_i), two_i));
  const __m128 neg_s = _mm_castsi128_ps(_mm_cmpeq_epi32(_mm_and_si128(q, two_i), two_i));
  c = _mm_xor_ps(c0, _mm_and_ps(neg_c, sign));
  s = _mm_xor_ps(s0, _mm_and_ps(neg_s, sign));
}

// orthonormal_basis (Duff et al., Listing 3), four normals at once.
inline void orthonormal_basis_x4(const Vec3x4& n, Vec3x4& t, Vec3x4& b) {
  const __m128 signbit = _mm_castsi128_ps(_mm_set1_epi32(int32_t(0x80000000u)));
  const __m128 sign = _mm_or_ps(_mm_and_ps(n.z, signbit), _mm_set1_ps(1.0f));  // copysign(1, n.z)
  const __m128 neg_sign = _mm_xor_ps(sign, signbit);
  const __m128 a = _mm_div_ps(_mm_set1_ps(-1.0f), _mm_add_ps(sign, n.z));
  const __m128 c = _mm_mul_ps(_mm_mul_ps(n.x, n.y), a);
  t.x = _mm_add_ps(_mm_set1_ps(1.0f), _mm_mul_ps(_mm_mul_ps(_mm_mul_ps(sign, n.x), n.x), a));
  t.y = _mm_mul_ps(sign, c);
  t.z = _mm_mul_ps(neg_sign, n.x);
  b.x = c;
  b.y = _mm_add_ps(sign, _mm_mul_ps(_mm_mul_ps(n.y, n.y), a));
  b.z = _mm_xor_ps(n.y, signbit);
}

// sample_cone's direction, four at once: normalize(t * (c sin) + b * (s sin) + w * cos).
inline Vec3x4 cone_x4(const Vec3x4& t, const Vec3x4& b, const Vec3x4& w, __m128 omc_max, __m128 u0, __m128 u1) {
  const __m128 omc = _mm_mul_ps(u0, omc_max);
  const __m128 cos_t = _mm_sub_ps(_mm_set1_ps(1.0f), omc);
  const __m128 sin_t = _mm_sqrt_ps(_mm_max_ps(_mm_mul_ps(omc, _mm_sub_ps(_mm_set1_ps(2.0f), omc)), _mm_setzero_ps()));
  __m128 c, s;
  sincos_2pi_x4(u1, c, s);
  const __m128 cs = _mm_mul_ps(c, sin_t), ss = _mm_mul_ps(s, sin_t);
  const __m128 vx = _mm_add_ps(_mm_add_ps(_mm_mul_ps(t.x, cs), _mm_mul_ps(b.x, ss)), _mm_mul_ps(w.x, cos_t));
  const __m128 vy = _mm_add_ps(_mm_add_ps(_mm_mul_ps(t.y, cs), _mm_mul_ps(b.y, ss)), _mm_mul_ps(w.y, cos_t));
  const __m128 vz = _mm_add_ps(_mm_add_ps(_mm_mul_ps(t.z, cs), _mm_mul_ps(b.z, ss)), _mm_mul_ps(w.z, cos_t));
  const __m128 dot = _mm_add_ps(_mm_add_ps(_mm_mul_ps(vx, vx), _mm_mul_ps(vy, vy)), _mm_mul_ps(vz, vz));
  const __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), _mm_sqrt_ps(dot));
  return {_mm_mul_ps(vx, inv), _mm_mul_ps(vy, inv), _mm_mul_ps(vz, inv)};
}

// The sphere shadow ray's tfar (see the scalar code in visibility_rows): nearest root of the
// sphere along d, or the closest approach when rounding leaves none; times kShadowTfarScale.
inline __m128 sphere_tfar_x4(const Vec3x4& d, const Vec3x4& oc, __m128 r2) {
  const __m128 b = _mm_add_ps(_mm_add_ps(_mm_mul_ps(d.x, oc.x), _mm_mul_ps(d.y, oc.y)), _mm_mul_ps(d.z, oc.z));
  const __m128 qx = _mm_sub_ps(oc.x, _mm_mul_ps(b, d.x));
  const __m128 qy = _mm_sub_ps(oc.y, _mm_mul_ps(b, d.y));
  const __m128 qz = _mm_sub_ps(oc.z, _mm_mul_ps(b, d.z));
  const __m128 disc =
      _mm_sub_ps(r2, _mm_add_ps(_mm_add_ps(_mm_mul_ps(qx, qx), _mm_mul_ps(qy, qy)), _mm_mul_ps(qz, qz)));
  const __m128 t_hit = select_ps(_mm_cmpgt_ps(disc, _mm_setzero_ps()), _mm_sub_ps(b, _mm_sqrt_ps(disc)), b);
  return _mm_max_ps(_mm_mul_ps(t_hit, _mm_set1_ps(kShadowTfarScale)), _mm_setzero_ps());
}
#endif

// Cosine-weighted hemisphere directions around the basis (t, b, n) for kChunk uniforms
// (Malley's method: the cosine of Eq. 1 is in the density, so O = N_unoccluded / N, Eq. 2-3):
// dir = t * (r c) + b * (r s) + n * z with r = sqrt(u0), z = sqrt(1 - u0), (c, s) =
// sincos_2pi(u1). The SSE2 version does the same IEEE operations in the same order four lanes
// at a time (bit-identical to the scalar one); it exists because GCC does not vectorize
// std::sqrt while errno is on.
inline void cosine_dirs_chunk(const glm::vec3& t, const glm::vec3& b, const glm::vec3& n, const float* u0,
                              const float* u1, float* dx, float* dy, float* dz) {
#if defined(__SSE2__)
  static_assert(kChunk % 4 == 0);
  const __m128 one = _mm_set1_ps(1.0f);
  for (int j = 0; j < kChunk; j += 4) {
    const __m128 v0 = _mm_load_ps(u0 + j), v1 = _mm_load_ps(u1 + j);
    const __m128 r = _mm_sqrt_ps(v0);
    const __m128 z = _mm_sqrt_ps(_mm_sub_ps(one, v0));
    __m128 c, s;
    sincos_2pi_x4(v1, c, s);
    const __m128 rc = _mm_mul_ps(r, c), rs = _mm_mul_ps(r, s);
    auto comp = [&](float tk, float bk, float nk) {
      return _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_set1_ps(tk), rc), _mm_mul_ps(_mm_set1_ps(bk), rs)),
                        _mm_mul_ps(_mm_set1_ps(nk), z));
    };
    _mm_store_ps(dx + j, comp(t.x, b.x, n.x));
    _mm_store_ps(dy + j, comp(t.y, b.y, n.y));
    _mm_store_ps(dz + j, comp(t.z, b.z, n.z));
  }
#else
  for (int j = 0; j < kChunk; ++j) {
    float c, sn;
    const float r = std::sqrt(u0[j]);
    const float z = std::sqrt(1.0f - u0[j]);  // u0 < 1
    sincos_2pi(u1[j], c, sn);
    const float rc = r * c, rs = r * sn;
    dx[j] = t.x * rc + b.x * rs + n.x * z;
    dy[j] = t.y * rc + b.y * rs + n.y * z;
    dz[j] = t.z * rc + b.z * rs + n.z * z;
  }
#endif
}

// Ray validity (ray_is_valid in core/trace/rt_scene.h) for a direction and tfar, the origin being
// checked once per pixel: every component finite (|x| <= FLT_MAX is false for inf and NaN),
// not the zero vector, 0 <= tfar (false for NaN). Branch-free, to vectorize.
inline bool direction_valid(float dx, float dy, float dz, float tfar) {
  constexpr float kMax = std::numeric_limits<float>::max();
  // Branch-free on purpose: unsigned & keeps the three tests from short-circuiting.
  const bool finite =
      (unsigned(std::abs(dx) <= kMax) & unsigned(std::abs(dy) <= kMax) & unsigned(std::abs(dz) <= kMax)) != 0;
  const bool nonzero = (unsigned(dx != 0.0f) | unsigned(dy != 0.0f) | unsigned(dz != 0.0f)) != 0;
  return finite & nonzero & (tfar >= 0.0f);
}
inline bool origin_valid(const glm::vec3& o) {
  // !(|x| < max) also rejects NaN.
  return (unsigned(std::abs(o.x) < kMaxCoordinate) & unsigned(std::abs(o.y) < kMaxCoordinate) &
          unsigned(std::abs(o.z) < kMaxCoordinate)) != 0;
}

// Directions in the cone around unit w (basis t, b, w) with 1 - cos(half angle) = omc_max,
// uniform in solid angle (paper 3.1: "a circular cone distribution that covers the entire
// light"), for kChunk uniforms. Same arithmetic, in the same order, as
// glm::normalize(t * (c * sin_t) + b * (s * sin_t) + w * cos_t).
inline void sample_cone_chunk(const glm::vec3& t, const glm::vec3& b, const glm::vec3& w, float omc_max,
                              const float* u0, const float* u1, float* dx, float* dy, float* dz) {
#if defined(__SSE2__)
  const Vec3x4 tv{_mm_set1_ps(t.x), _mm_set1_ps(t.y), _mm_set1_ps(t.z)};
  const Vec3x4 bv{_mm_set1_ps(b.x), _mm_set1_ps(b.y), _mm_set1_ps(b.z)};
  const Vec3x4 wv{_mm_set1_ps(w.x), _mm_set1_ps(w.y), _mm_set1_ps(w.z)};
  for (int j = 0; j < kChunk; j += 4) {
    const Vec3x4 d = cone_x4(tv, bv, wv, _mm_set1_ps(omc_max), _mm_load_ps(u0 + j), _mm_load_ps(u1 + j));
    _mm_store_ps(dx + j, d.x);
    _mm_store_ps(dy + j, d.y);
    _mm_store_ps(dz + j, d.z);
  }
#else
  for (int j = 0; j < kChunk; ++j) {
    const float omc = u0[j] * omc_max;  // 1 - cos(theta), precise for small cones
    const float cos_t = 1.0f - omc;
    const float sin_t = std::sqrt(std::max(0.0f, omc * (2.0f - omc)));
    float c, s;
    sincos_2pi(u1[j], c, s);
    const float cs = c * sin_t, ss = s * sin_t;
    const float vx = t.x * cs + b.x * ss + w.x * cos_t;
    const float vy = t.y * cs + b.y * ss + w.y * cos_t;
    const float vz = t.z * cs + b.z * ss + w.z * cos_t;
    const float inv = 1.0f / std::sqrt(vx * vx + vy * vy + vz * vz);
    dx[j] = vx * inv;
    dy[j] = vy * inv;
    dz[j] = vz * inv;
  }
#endif
}

}  // namespace dhr::trace_detail
