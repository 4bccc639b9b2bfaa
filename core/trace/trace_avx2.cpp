// The tracer's AVX2 kernels, used where the CPU has AVX2 but Embree has no native 16-wide
// packets (no AVX-512; core/trace/trace.cpp and core/trace/trace_rows.cpp choose at run time), each the
// work of an AVX-512 kernel of core/trace/trace_avx512.cpp in 8 lanes:
// - ao_rays_x8 (paper section 3.2, Eq. 1-3): ao_rows_compacted<8> (core/trace/trace_rows.cpp) gathers
//   a row's tracing pixels; this makes 8 rays at a time (hashes, uniforms, cosine directions:
//   the scalar and SSE2 code's operations in the same order, see core/trace/trace_directions.h)
//   straight into an rtcOccluded8 packet and adds each pixel's unoccluded lanes by popcount;
// - the visibility pass (section 3.1): surfaces_x8 (stage 1), trace_pairs_x8 (stage 3 where
//   every light takes one ray per pixel) and soft_pair_rays_x8 (the cone loop of S > 1 rays per
//   light, which has no AVX-512 kernel); the light classification keeps the baseline kernels.
// The rays and results are the baseline kernels' bit for bit (tests/core/trace/test_trace.cpp:
// TraceAo.WideKernelsGiveTheSameBits, TraceShadows.WideKernelsGiveTheSameBitsWithManySamples;
// tests/core/trace/test_trace_bits.cpp). docs/performance.md has the measurements.
//
// AVX2 has no 64-bit vector multiply: SplitMix64's products are built from three 32x32->64-bit
// ones (mul64_x4). The target is "avx2" without "fma", so no product and sum is fused: every
// operation rounds as the SSE2 code's does. Only the functions marked DHR_TRACE_TARGET_AVX2 are
// compiled for AVX2; no lambdas inside them (a lambda does not inherit the target attribute).
#include "core/base/cpu_isa.h"
#include "core/trace/trace_kernels.h"

#if DHR_TRACE_X86_KERNELS
#include <immintrin.h>

#include <algorithm>
#include <limits>
#include <numbers>

#define DHR_TRACE_TARGET_AVX2 __attribute__((target("avx2")))

namespace dhr::trace_detail {

bool cpu_has_avx2() {  // and $DHR_MAX_ISA allows it (core/base/cpu_isa.h)
  static const bool has = __builtin_cpu_supports("avx2") && kernels_may_use(Isa::kAvx2);
  return has;
}

namespace {

// z * c modulo 2^64 on 4 lanes: zl cl + 2^32 (zh cl + zl ch), from 32x32->64-bit products.
DHR_TRACE_TARGET_AVX2 inline __m256i mul64_x4(__m256i z, uint64_t c) {
  const __m256i cl = _mm256_set1_epi64x(int64_t(c & 0xffffffffull)), ch = _mm256_set1_epi64x(int64_t(c >> 32));
  const __m256i cross = _mm256_add_epi64(_mm256_mul_epu32(_mm256_srli_epi64(z, 32), cl), _mm256_mul_epu32(z, ch));
  return _mm256_add_epi64(_mm256_mul_epu32(z, cl), _mm256_slli_epi64(cross, 32));
}

DHR_TRACE_TARGET_AVX2 inline __m256i mix64_x4(__m256i z) {  // core/base/rng.h's mix64, 4 lanes
  z = _mm256_add_epi64(z, _mm256_set1_epi64x(int64_t(0x9E3779B97F4A7C15ull)));
  z = mul64_x4(_mm256_xor_si256(z, _mm256_srli_epi64(z, 30)), 0xBF58476D1CE4E5B9ull);
  z = mul64_x4(_mm256_xor_si256(z, _mm256_srli_epi64(z, 27)), 0x94D049BB133111EBull);
  return _mm256_xor_si256(z, _mm256_srli_epi64(z, 31));
}

// float(bits >> 40) / 2^24 for 8 keys given as two halves of 4 (exact: the values fit 24 bits).
DHR_TRACE_TARGET_AVX2 inline __m256 uniform_x8(__m256i lo, __m256i hi) {
  // The low 32 bits of each 64-bit lane: lo0 lo1 hi0 hi1 | lo2 lo3 hi2 hi3, then in lane order.
  const __m256 packed = _mm256_shuffle_ps(_mm256_castsi256_ps(_mm256_srli_epi64(lo, 40)),
                                          _mm256_castsi256_ps(_mm256_srli_epi64(hi, 40)), _MM_SHUFFLE(2, 0, 2, 0));
  const __m256i v = _mm256_permute4x64_epi64(_mm256_castps_si256(packed), _MM_SHUFFLE(3, 1, 2, 0));
  return _mm256_mul_ps(_mm256_cvtepi32_ps(v), _mm256_set1_ps(1.0f / 16777216.0f));
}

// lattice_uniform (core/trace/trace.h) on 8 lanes: the top 24 bits of sample a + shift (mod 2^32).
DHR_TRACE_TARGET_AVX2 inline __m256 lattice_x8(__m256i sample, uint32_t a, __m256i shift) {
  const __m256i v = _mm256_add_epi32(_mm256_mullo_epi32(sample, _mm256_set1_epi32(int32_t(a))), shift);
  return _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_srli_epi32(v, 8)), _mm256_set1_ps(1.0f / 16777216.0f));
}

// sincos_2pi_x4 on 8 lanes: the same IEEE operations in the same order.
DHR_TRACE_TARGET_AVX2 inline void sincos_2pi_x8(__m256 u, __m256& c, __m256& s) {
  const __m256 one = _mm256_set1_ps(1.0f);
  const __m256 sign = _mm256_castsi256_ps(_mm256_set1_epi32(int32_t(0x80000000u)));
  const __m256 x = _mm256_mul_ps(_mm256_set1_ps(4.0f), u);
  const __m256i q = _mm256_min_epi32(_mm256_cvttps_epi32(x), _mm256_set1_epi32(3));
  const __m256 a =
      _mm256_mul_ps(_mm256_sub_ps(x, _mm256_cvtepi32_ps(q)), _mm256_set1_ps(std::numbers::pi_v<float> / 2.0f));
  const __m256 a2 = _mm256_mul_ps(a, a);
  __m256 sa = _mm256_add_ps(_mm256_set1_ps(-1.0f / 5040), _mm256_mul_ps(a2, _mm256_set1_ps(1.0f / 362880)));
  sa = _mm256_add_ps(_mm256_set1_ps(1.0f / 120), _mm256_mul_ps(a2, sa));
  sa = _mm256_add_ps(_mm256_set1_ps(-1.0f / 6), _mm256_mul_ps(a2, sa));
  sa = _mm256_add_ps(one, _mm256_mul_ps(a2, sa));
  sa = _mm256_mul_ps(a, sa);
  __m256 ca = _mm256_add_ps(_mm256_set1_ps(-1.0f / 720), _mm256_mul_ps(a2, _mm256_set1_ps(1.0f / 40320)));
  ca = _mm256_add_ps(_mm256_set1_ps(1.0f / 24), _mm256_mul_ps(a2, ca));
  ca = _mm256_add_ps(_mm256_set1_ps(-0.5f), _mm256_mul_ps(a2, ca));
  ca = _mm256_add_ps(one, _mm256_mul_ps(a2, ca));
  const __m256i one_i = _mm256_set1_epi32(1), two_i = _mm256_set1_epi32(2);
  const __m256 odd = _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(q, one_i), one_i));
  const __m256 c0 = _mm256_blendv_ps(ca, sa, odd);  // odd ? sa : ca
  const __m256 s0 = _mm256_blendv_ps(sa, ca, odd);
  const __m256 neg_c =
      _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(_mm256_add_epi32(q, one_i), two_i), two_i));
  const __m256 neg_s = _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(q, two_i), two_i));
  c = _mm256_xor_ps(c0, _mm256_and_ps(neg_c, sign));
  s = _mm256_xor_ps(s0, _mm256_and_ps(neg_s, sign));
}

// Component comp of each lane's pixel: lane l reads pixel p0 + pick[l] (pick[l] < 8).
DHR_TRACE_TARGET_AVX2 inline __m256 lane_values(const AoPixels& px, int comp, int p0, __m256i pick) {
  return _mm256_permutevar8x32_ps(_mm256_loadu_ps(px.c[size_t(comp)].data() + p0), pick);
}

// One component of cosine_dirs_chunk's direction, t * (r c) + b * (r s) + n * z, for the
// axis whose t component is comp_t (b's and n's follow at +3 and +6).
DHR_TRACE_TARGET_AVX2 inline __m256 cosine_dir_x8(const AoPixels& px, int comp_t, int p0, __m256i pick, __m256 rc,
                                                  __m256 rs, __m256 z) {
  const __m256 t = lane_values(px, comp_t, p0, pick), b = lane_values(px, comp_t + 3, p0, pick);
  const __m256 n = lane_values(px, comp_t + 6, p0, pick);
  return _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(t, rc), _mm256_mul_ps(b, rs)), _mm256_mul_ps(n, z));
}

// cone_x4 (core/trace/trace_directions.h) on 8 lanes, around one pair's basis (t, b, w):
// normalize(t * (c sin) + b * (s sin) + w * cos), the same operations in the same order.
DHR_TRACE_TARGET_AVX2 inline void cone_x8(const __m256 t[3], const __m256 b[3], const __m256 w[3], __m256 omc_max,
                                          __m256 u0, __m256 u1, __m256 d[3]) {
  const __m256 omc = _mm256_mul_ps(u0, omc_max);
  const __m256 cos_t = _mm256_sub_ps(_mm256_set1_ps(1.0f), omc);
  const __m256 sin_t =
      _mm256_sqrt_ps(_mm256_max_ps(_mm256_mul_ps(omc, _mm256_sub_ps(_mm256_set1_ps(2.0f), omc)), _mm256_setzero_ps()));
  __m256 c, s;
  sincos_2pi_x8(u1, c, s);
  const __m256 cs = _mm256_mul_ps(c, sin_t), ss = _mm256_mul_ps(s, sin_t);
  __m256 v[3];
  for (int k = 0; k < 3; ++k)
    v[k] = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(t[k], cs), _mm256_mul_ps(b[k], ss)), _mm256_mul_ps(w[k], cos_t));
  const __m256 dot =
      _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(v[0], v[0]), _mm256_mul_ps(v[1], v[1])), _mm256_mul_ps(v[2], v[2]));
  const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), _mm256_sqrt_ps(dot));
  for (int k = 0; k < 3; ++k) d[k] = _mm256_mul_ps(v[k], inv);
}

// sphere_tfar_x4 (core/trace/trace_directions.h) on 8 lanes: the scalar cone loop's tfar.
DHR_TRACE_TARGET_AVX2 inline __m256 sphere_tfar_x8(const __m256 d[3], const __m256 oc[3], __m256 r2) {
  const __m256 b =
      _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(d[0], oc[0]), _mm256_mul_ps(d[1], oc[1])), _mm256_mul_ps(d[2], oc[2]));
  const __m256 qx = _mm256_sub_ps(oc[0], _mm256_mul_ps(b, d[0]));
  const __m256 qy = _mm256_sub_ps(oc[1], _mm256_mul_ps(b, d[1]));
  const __m256 qz = _mm256_sub_ps(oc[2], _mm256_mul_ps(b, d[2]));
  const __m256 disc = _mm256_sub_ps(
      r2, _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(qx, qx), _mm256_mul_ps(qy, qy)), _mm256_mul_ps(qz, qz)));
  const __m256 pos = _mm256_cmp_ps(disc, _mm256_setzero_ps(), _CMP_GT_OQ);
  const __m256 t_hit = _mm256_blendv_ps(b, _mm256_sub_ps(b, _mm256_sqrt_ps(disc)), pos);  // pos ? b - sqrt : b
  return _mm256_max_ps(_mm256_mul_ps(t_hit, _mm256_set1_ps(kShadowTfarScale)), _mm256_setzero_ps());
}

// direction_valid (core/trace/trace_directions.h) on 8 lanes, as a lane mask.
DHR_TRACE_TARGET_AVX2 inline uint32_t directions_valid_x8(const __m256 d[3], __m256 tfar) {
  const __m256 zero = _mm256_setzero_ps(), fmax = _mm256_set1_ps(std::numeric_limits<float>::max());
  const __m256 abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
  __m256 finite = _mm256_cmp_ps(_mm256_and_ps(d[0], abs_mask), fmax, _CMP_LE_OQ);
  finite = _mm256_and_ps(finite, _mm256_cmp_ps(_mm256_and_ps(d[1], abs_mask), fmax, _CMP_LE_OQ));
  finite = _mm256_and_ps(finite, _mm256_cmp_ps(_mm256_and_ps(d[2], abs_mask), fmax, _CMP_LE_OQ));
  __m256 nonzero = _mm256_cmp_ps(d[0], zero, _CMP_NEQ_UQ);
  nonzero = _mm256_or_ps(nonzero, _mm256_cmp_ps(d[1], zero, _CMP_NEQ_UQ));
  nonzero = _mm256_or_ps(nonzero, _mm256_cmp_ps(d[2], zero, _CMP_NEQ_UQ));
  const __m256 reach = _mm256_cmp_ps(tfar, zero, _CMP_GE_OQ);
  return uint32_t(_mm256_movemask_ps(_mm256_and_ps(_mm256_and_ps(finite, nonzero), reach)));
}

// Lane l of the result is all ones where bit l of bits is set (8 lanes of 32 bits).
DHR_TRACE_TARGET_AVX2 inline __m256i lanes_of(uint32_t bits) {
  const __m256i lane_bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
  return _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(int32_t(bits)), lane_bits), lane_bits);
}

// The same for 4 lanes of 64 bits (bits 0-3).
DHR_TRACE_TARGET_AVX2 inline __m256i lanes64_of(uint32_t bits) {
  const __m256i lane_bits = _mm256_setr_epi64x(1, 2, 4, 8);
  return _mm256_cmpeq_epi64(_mm256_and_si256(_mm256_set1_epi64x(int64_t(bits)), lane_bits), lane_bits);
}

DHR_TRACE_TARGET_AVX2 inline __m256 join(__m128 lo, __m128 hi) {
  return _mm256_insertf128_ps(_mm256_castps128_ps256(lo), hi, 1);
}

// The 13 values (v0, v1, v2, n, offset_m) of the row triangles of 4 pixels, value k of lane l in
// c[k][l] (surfaces_x8). AVX2's gathers are slow on the CPUs at hand, so: one broadcast per
// value where the 4 pixels share a triangle (most of a row), else the 4 triangles' values read
// in blocks of 4 and transposed. A lane outside live reads the first live lane's triangle.
DHR_TRACE_TARGET_AVX2 inline void row_triangles_x4(const double* tri, const int* tri_of, uint32_t live, __m256d c[13]) {
  if (live == 0) {
    for (int k = 0; k < 13; ++k) c[k] = _mm256_setzero_pd();
    return;
  }
  const int first = tri_of[__builtin_ctz(live)];
  int t[4];
  for (int l = 0; l < 4; ++l) t[l] = (live >> l) & 1u ? tri_of[l] : first;
  if (t[0] == t[1] && t[1] == t[2] && t[2] == t[3]) {
    const double* q = tri + 14 * size_t(t[0]);
    for (int k = 0; k < 13; ++k) c[k] = _mm256_broadcast_sd(q + k);
    return;
  }
  const double* q[4] = {tri + 14 * size_t(t[0]), tri + 14 * size_t(t[1]), tri + 14 * size_t(t[2]),
                        tri + 14 * size_t(t[3])};
  for (int kb : {0, 4, 8, 10}) {  // the last block (values 10-13) overlaps the one before
    const __m256d r0 = _mm256_loadu_pd(q[0] + kb), r1 = _mm256_loadu_pd(q[1] + kb);
    const __m256d r2 = _mm256_loadu_pd(q[2] + kb), r3 = _mm256_loadu_pd(q[3] + kb);
    const __m256d lo01 = _mm256_unpacklo_pd(r0, r1), hi01 = _mm256_unpackhi_pd(r0, r1);
    const __m256d lo23 = _mm256_unpacklo_pd(r2, r3), hi23 = _mm256_unpackhi_pd(r2, r3);
    c[kb] = _mm256_permute2f128_pd(lo01, lo23, 0x20);
    c[kb + 1] = _mm256_permute2f128_pd(hi01, hi23, 0x20);
    c[kb + 2] = _mm256_permute2f128_pd(lo01, lo23, 0x31);
    if (kb + 3 < 13) c[kb + 3] = _mm256_permute2f128_pd(hi01, hi23, 0x31);
  }
}

}  // namespace

// Every ray of the row's compacted pixels, in pixel then sample order, 8 rays per packet (a
// packet may hold the end of one pixel's rays and the start of the next ones): lane l of the
// packet starting at ray r0 = p0 rays + s0 is pixel p0 + (s0 + l) / rays, sample
// (s0 + l) % rays, as in ao_rays_x16.
DHR_TRACE_TARGET_AVX2 void ao_rays_x8(const AoPixels& px, int rays, float radius_m, Batch<8>& batch) {
  const int total = px.n * rays;
  const __m256i iota = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i rays_i = _mm256_set1_epi32(rays);
  const __m256 rays_f = _mm256_set1_ps(float(rays));
  const __m256i stream = _mm256_set1_epi64x(kStreamAo);
  const __m256i dim1 = _mm256_set1_epi64x(1);
  const __m256 one = _mm256_set1_ps(1.0f);
  auto& pk = batch.packet;
  alignas(32) int valid[8];
  for (int r0 = 0; r0 < total; r0 += 8) {
    const int p0 = r0 / rays, s0 = r0 % rays;
    const int live = std::min(8, total - r0);
    // (s0 + l) / rays by float division: exact here (s0 + l < 2^17, quotient <= 8: the
    // rounding error stays far below the 1 / rays that separates a quotient from the next).
    const __m256i v = _mm256_add_epi32(_mm256_set1_epi32(s0), iota);
    const __m256i pick = _mm256_cvttps_epi32(_mm256_div_ps(_mm256_cvtepi32_ps(v), rays_f));
    const __m256i sample = _mm256_sub_epi32(v, _mm256_mullo_epi32(pick, rays_i));
    __m256 u0, u1;
    if (px.lattice) {  // each lane's pixel's shift from the 8-pixel window
      const auto* s0p = reinterpret_cast<const __m256i*>(px.shift0.data() + p0);
      const auto* s1p = reinterpret_cast<const __m256i*>(px.shift1.data() + p0);
      u0 = lattice_x8(sample, kLatticeA0, _mm256_permutevar8x32_epi32(_mm256_loadu_si256(s0p), pick));
      u1 = lattice_x8(sample, kLatticeA1, _mm256_permutevar8x32_epi32(_mm256_loadu_si256(s1p), pick));
    } else {
      const __m128i pick_lo = _mm256_castsi256_si128(pick), pick_hi = _mm256_extracti128_si256(pick, 1);
      // key = (sample << 32) | stream, as PixelRng::uniform2
      const __m256i key_lo =
          _mm256_or_si256(_mm256_slli_epi64(_mm256_cvtepu32_epi64(_mm256_castsi256_si128(sample)), 32), stream);
      const __m256i key_hi =
          _mm256_or_si256(_mm256_slli_epi64(_mm256_cvtepu32_epi64(_mm256_extracti128_si256(sample, 1)), 32), stream);
      const auto* h = reinterpret_cast<const long long*>(px.h.data() + p0);
      const __m256i k_lo = mix64_x4(_mm256_xor_si256(_mm256_i32gather_epi64(h, pick_lo, 8), key_lo));
      const __m256i k_hi = mix64_x4(_mm256_xor_si256(_mm256_i32gather_epi64(h, pick_hi, 8), key_hi));
      u0 = uniform_x8(mix64_x4(k_lo), mix64_x4(k_hi));
      u1 = uniform_x8(mix64_x4(_mm256_xor_si256(k_lo, dim1)), mix64_x4(_mm256_xor_si256(k_hi, dim1)));
    }
    const __m256 r = _mm256_sqrt_ps(u0);
    const __m256 z = _mm256_sqrt_ps(_mm256_sub_ps(one, u0));
    __m256 c, s;
    sincos_2pi_x8(u1, c, s);
    const __m256 rc = _mm256_mul_ps(r, c), rs = _mm256_mul_ps(r, s);
    _mm256_store_ps(pk.org_x, lane_values(px, AoPixels::kOx, p0, pick));
    _mm256_store_ps(pk.org_y, lane_values(px, AoPixels::kOy, p0, pick));
    _mm256_store_ps(pk.org_z, lane_values(px, AoPixels::kOz, p0, pick));
    _mm256_store_ps(pk.dir_x, cosine_dir_x8(px, AoPixels::kTx, p0, pick, rc, rs, z));
    _mm256_store_ps(pk.dir_y, cosine_dir_x8(px, AoPixels::kTy, p0, pick, rc, rs, z));
    _mm256_store_ps(pk.dir_z, cosine_dir_x8(px, AoPixels::kTz, p0, pick, rc, rs, z));
    _mm256_store_ps(pk.tfar, _mm256_set1_ps(radius_m));  // tfar = r: never trace further
    if (batch.record) {                                  // collect_ao_rays: push() keeps the rays, traces nothing
      for (int l = 0; l < live; ++l)
        batch.push(glm::vec3(pk.org_x[l], pk.org_y[l], pk.org_z[l]), pk.dir_x[l], pk.dir_y[l], pk.dir_z[l], radius_m,
                   nullptr);
      continue;
    }
    for (int l = 0; l < 8; ++l) valid[l] = l < live ? -1 : 0;
    rtcOccluded8(valid, batch.scene, &batch.ctx, &pk);
    // Embree sets tfar = -inf on an occluded ray; anything else reached (as Batch::flush).
    const uint32_t live_mask = (1u << live) - 1u;
    const uint32_t reached =
        uint32_t(_mm256_movemask_ps(_mm256_cmp_ps(_mm256_load_ps(pk.tfar), _mm256_setzero_ps(), _CMP_NLT_UQ))) &
        live_mask;
    const int last = (s0 + live - 1) / rays;  // the packet's last pixel, relative to p0
    for (int g = 0; g <= last; ++g) {
      const uint32_t lanes =
          uint32_t(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(pick, _mm256_set1_epi32(g)))));
      uint16_t* count = px.count[size_t(p0 + g)];
      *count = uint16_t(*count + popcount16(reached & lanes));  // the target has no POPCNT either
    }
    batch.traced += uint64_t(live);
  }
}

// The S rays of one (pixel, light) pair of a soft light with S > 1 samples (the cone loop of
// visibility_rows), 8 samples at a time: uniforms_chunk's hashes, sample_cone_chunk's
// directions and the loop's tfar and validity, the same operations in the same order. The
// valid rays of 8 samples are traced as one packet of their own (not Batch's: it may hold
// other pairs' rays), each unoccluded ray adding one to the pair's counter; an invalid ray
// counts as unoccluded without a trace, as there. With batch.record, the valid rays are kept
// in sample order instead (Batch::push).
DHR_TRACE_TARGET_AVX2 void soft_pair_rays_x8(const SoftPair& p, Batch<8>& batch, uint64_t& invalid) {
  const __m256i stream = _mm256_set1_epi64x(int64_t(p.stream));
  const __m256i dim1 = _mm256_set1_epi64x(1);
  const __m256i h = _mm256_set1_epi64x(int64_t(p.h));
  const __m256i iota_lo = _mm256_setr_epi64x(0, 1, 2, 3), iota_hi = _mm256_setr_epi64x(4, 5, 6, 7);
  const __m256 t[3] = {_mm256_set1_ps(p.t.x), _mm256_set1_ps(p.t.y), _mm256_set1_ps(p.t.z)};
  const __m256 b[3] = {_mm256_set1_ps(p.b.x), _mm256_set1_ps(p.b.y), _mm256_set1_ps(p.b.z)};
  const __m256 w[3] = {_mm256_set1_ps(p.w.x), _mm256_set1_ps(p.w.y), _mm256_set1_ps(p.w.z)};
  const __m256 oc[3] = {_mm256_set1_ps(p.oc.x), _mm256_set1_ps(p.oc.y), _mm256_set1_ps(p.oc.z)};
  const __m256 omc_max = _mm256_set1_ps(p.omc_max), r2 = _mm256_set1_ps(p.r2);
  alignas(32) RTCRay8 pk;
  alignas(32) int valid[8];
  for (int l = 0; l < 8; ++l) {
    pk.org_x[l] = p.origin.x, pk.org_y[l] = p.origin.y, pk.org_z[l] = p.origin.z;
    pk.tnear[l] = 0.0f;
    pk.time[l] = 0.0f;
    pk.mask[l] = batch.mask;
    pk.id[l] = unsigned(l);
    pk.flags[l] = 0;
  }
  for (int k0 = 0; k0 < p.samples; k0 += 8) {
    const int live = std::min(8, p.samples - k0);
    __m256 u0, u1;
    if (p.lattice) {
      const __m256i samples = _mm256_add_epi32(_mm256_set1_epi32(k0), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
      u0 = lattice_x8(samples, kLatticeA0, _mm256_set1_epi32(int32_t(p.shift0)));
      u1 = lattice_x8(samples, kLatticeA1, _mm256_set1_epi32(int32_t(p.shift1)));
    } else {
      // key = (sample << 32) | stream, as PixelRng::uniform2
      const __m256i first = _mm256_set1_epi64x(int64_t(k0));
      const __m256i key_lo = _mm256_or_si256(_mm256_slli_epi64(_mm256_add_epi64(first, iota_lo), 32), stream);
      const __m256i key_hi = _mm256_or_si256(_mm256_slli_epi64(_mm256_add_epi64(first, iota_hi), 32), stream);
      const __m256i k_lo = mix64_x4(_mm256_xor_si256(h, key_lo)), k_hi = mix64_x4(_mm256_xor_si256(h, key_hi));
      u0 = uniform_x8(mix64_x4(k_lo), mix64_x4(k_hi));
      u1 = uniform_x8(mix64_x4(_mm256_xor_si256(k_lo, dim1)), mix64_x4(_mm256_xor_si256(k_hi, dim1)));
    }
    __m256 d[3];
    cone_x8(t, b, w, omc_max, u0, u1, d);
    const __m256 tfar = p.sphere ? sphere_tfar_x8(d, oc, r2) : _mm256_set1_ps(std::numeric_limits<float>::infinity());
    const uint32_t live_mask = (1u << live) - 1u;
    const uint32_t ok = p.origin_ok ? directions_valid_x8(d, tfar) & live_mask : 0u;
    const int n_invalid = live - popcount16(ok);
    invalid += uint64_t(n_invalid);
    *p.count = uint16_t(*p.count + n_invalid);
    if (ok == 0) continue;
    if (batch.record) {
      alignas(32) float dx[8], dy[8], dz[8], tf[8];
      _mm256_store_ps(dx, d[0]);
      _mm256_store_ps(dy, d[1]);
      _mm256_store_ps(dz, d[2]);
      _mm256_store_ps(tf, tfar);
      for (int l = 0; l < live; ++l)
        if (ok >> l & 1u) batch.push(p.origin, dx[l], dy[l], dz[l], tf[l], nullptr);
      continue;
    }
    // Lanes that do not trace get a harmless ray (Embree validates every lane's values).
    const __m256i on = lanes_of(ok);
    const __m256 on_ps = _mm256_castsi256_ps(on);
    _mm256_store_ps(pk.dir_x, _mm256_blendv_ps(_mm256_set1_ps(1.0f), d[0], on_ps));
    _mm256_store_ps(pk.dir_y, _mm256_blendv_ps(_mm256_setzero_ps(), d[1], on_ps));
    _mm256_store_ps(pk.dir_z, _mm256_blendv_ps(_mm256_setzero_ps(), d[2], on_ps));
    _mm256_store_ps(pk.tfar, _mm256_blendv_ps(_mm256_setzero_ps(), tfar, on_ps));
    _mm256_store_si256(reinterpret_cast<__m256i*>(valid), on);
    rtcOccluded8(valid, batch.scene, &batch.ctx, &pk);
    // Embree sets tfar = -inf on an occluded ray; anything else reached (as Batch::flush).
    const uint32_t reached =
        uint32_t(_mm256_movemask_ps(_mm256_cmp_ps(_mm256_load_ps(pk.tfar), _mm256_setzero_ps(), _CMP_NLT_UQ))) & ok;
    *p.count = uint16_t(*p.count + popcount16(reached));
    batch.traced += uint64_t(popcount16(ok));
  }
}

// Stage 3 of the visibility pass where every light takes one ray per pixel (trace_pairs_x16 in
// 8 lanes): the n rays of r.pair_ray (pixel then light order) 8 at a time into the packet, traced,
// each unoccluded ray adding one to its counter; with batch.record, the rays are kept instead.
DHR_TRACE_TARGET_AVX2 void trace_pairs_x8(const VisibilityRow& r, int n, Batch<8>& batch) {
  auto& pk = batch.packet;
  alignas(32) int valid[8];
  const __m256 zero = _mm256_setzero_ps();
  const __m256i iota = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  for (int k0 = 0; k0 < n; k0 += 8) {
    const int live = std::min(8, n - k0);
    const __m256i lm = _mm256_cmpgt_epi32(_mm256_set1_epi32(live), iota);
    float* const to[7] = {pk.org_x, pk.org_y, pk.org_z, pk.dir_x, pk.dir_y, pk.dir_z, pk.tfar};
    for (int c = 0; c < 7; ++c) _mm256_store_ps(to[c], _mm256_maskload_ps(r.pair_ray[c].data() + k0, lm));
    if (batch.record) {  // collect_visibility_rays: push() keeps the rays, traces nothing
      for (int l = 0; l < live; ++l)
        batch.push(glm::vec3(pk.org_x[l], pk.org_y[l], pk.org_z[l]), pk.dir_x[l], pk.dir_y[l], pk.dir_z[l], pk.tfar[l],
                   nullptr);
      continue;
    }
    _mm256_store_si256(reinterpret_cast<__m256i*>(valid), lm);
    rtcOccluded8(valid, batch.scene, &batch.ctx, &pk);
    // Embree sets tfar = -inf on an occluded ray; anything else reached (as Batch::flush).
    uint32_t reached =
        uint32_t(_mm256_movemask_ps(_mm256_cmp_ps(_mm256_load_ps(pk.tfar), zero, _CMP_NLT_UQ))) & ((1u << live) - 1u);
    while (reached != 0) {
      uint16_t* count = r.pair_count[size_t(k0 + __builtin_ctz(reached))];
      *count = uint16_t(*count + 1);
      reached &= reached - 1u;
    }
    batch.traced += uint64_t(live);
  }
}

// Stage 1 of the visibility pass for the pixels of kind 1 (surfaces_x16 in 8 lanes, doubles 4
// at a time): the point on the row triangle from the barycentrics, the normal oriented like the
// G-buffer's, the origin float(p + n offset_m) and its validity; pixels whose orientation needs the
// camera become kind 3. With hashes, every pixel's PixelRng hash. The same operations in the
// same order as surface_at and surfaces_x16: the same bits.
DHR_TRACE_TARGET_AVX2 void surfaces_x8(VisibilityRow& r, const TraceSettings& settings, size_t row_start, bool hashes) {
  const int w = r.w;
  const double* tri = r.tris.data();
  const __m256d zero_d = _mm256_setzero_pd(), one_d = _mm256_set1_pd(1.0);
  const __m256 abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
  const __m256d abs_mask_d = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffffll));
  const __m256i iota64 = _mm256_setr_epi64x(0, 1, 2, 3);
  const __m256i seed = _mm256_set1_epi64x(int64_t(mix64(settings.seed)));
  const __m256i frame = _mm256_set1_epi64x(int64_t(settings.frame));
  const __m256d dsign = _mm256_castsi256_pd(_mm256_set1_epi64x(int64_t(0x8000000000000000ull)));
  for (int x = 0; x < w; x += 8) {
    const int n = std::min(8, w - x);
    const uint32_t live = (1u << n) - 1u;
    if (hashes) {  // PixelRng(seed, pixel, frame).h, pixel as uint32
      for (int half = 0; half < 2; ++half) {
        const __m256i pixel =
            _mm256_and_si256(_mm256_add_epi64(_mm256_set1_epi64x(int64_t(row_start + size_t(x + 4 * half))), iota64),
                             _mm256_set1_epi64x(0xffffffffll));
        const __m256i key = _mm256_or_si256(_mm256_slli_epi64(pixel, 32), frame);
        _mm256_maskstore_epi64(reinterpret_cast<long long*>(&r.h[size_t(x + 4 * half)]), lanes64_of(live >> (4 * half)),
                               mix64_x4(_mm256_xor_si256(seed, key)));
      }
    }
    const __m256i kind = _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(&r.kind[size_t(x)])));
    const uint32_t vec =
        uint32_t(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(kind, _mm256_set1_epi32(1))))) & live;
    if (vec == 0) continue;
    __m128 ph[2][3], nh[2][3], oh[2][3];
    uint32_t degenerate = 0;
    for (int half = 0; half < 2; ++half) {
      const size_t xh = size_t(x + 4 * half);
      __m256d c[13];
      row_triangles_x4(tri, &r.tri_of[xh], (vec >> (4 * half)) & 0xfu, c);
      // p = (1 - b1 - b2) v0 + b1 v1 + b2 v2
      const __m256d b1 = _mm256_cvtps_pd(_mm_loadu_ps(&r.b1[xh])), b2 = _mm256_cvtps_pd(_mm_loadu_ps(&r.b2[xh]));
      const __m256d a = _mm256_sub_pd(_mm256_sub_pd(one_d, b1), b2);
      __m256d pd[3];
      for (int k = 0; k < 3; ++k) {
        pd[k] = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(a, c[k]), _mm256_mul_pd(b1, c[3 + k])),
                              _mm256_mul_pd(b2, c[6 + k]));
        ph[half][k] = _mm256_cvtpd_ps(pd[k]);
      }
      // Oriented like the G-buffer's geometric normal: side = n . gn.
      const __m256d side = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(c[9], _mm256_cvtps_pd(_mm_loadu_ps(&r.gx[xh]))),
                                                       _mm256_mul_pd(c[10], _mm256_cvtps_pd(_mm_loadu_ps(&r.gy[xh])))),
                                         _mm256_mul_pd(c[11], _mm256_cvtps_pd(_mm_loadu_ps(&r.gz[xh]))));
      const uint32_t not_positive =
          uint32_t(_mm256_movemask_pd(_mm256_cmp_pd(_mm256_and_pd(side, abs_mask_d), zero_d, _CMP_NGT_UQ)));
      degenerate |= (not_positive & (vec >> (4 * half)) & 0xfu) << (4 * half);
      const __m256d flip = _mm256_and_pd(_mm256_cmp_pd(side, zero_d, _CMP_LT_OQ), dsign);
      for (int k = 0; k < 3; ++k) {
        const __m256d nk = _mm256_xor_pd(c[9 + k], flip);
        nh[half][k] = _mm256_cvtpd_ps(nk);
        // offset_ray_origin (core/trace/trace.h): float(p + n offset_m), in double.
        oh[half][k] = _mm256_cvtpd_ps(_mm256_add_pd(pd[k], _mm256_mul_pd(nk, c[12])));
      }
    }
    __m256 pf[3], nf[3], of[3];
    __m256 origin_ok = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
    for (int k = 0; k < 3; ++k) {
      pf[k] = join(ph[0][k], ph[1][k]);
      nf[k] = join(nh[0][k], nh[1][k]);
      of[k] = join(oh[0][k], oh[1][k]);
      origin_ok = _mm256_and_ps(
          origin_ok, _mm256_cmp_ps(_mm256_and_ps(of[k], abs_mask), _mm256_set1_ps(kMaxCoordinate), _CMP_LT_OQ));
    }
    const uint32_t done = vec & ~degenerate;
    const uint32_t ok_bits = uint32_t(_mm256_movemask_ps(origin_ok));
    const __m256i dm = lanes_of(done);
    _mm256_maskstore_ps(&r.px[size_t(x)], dm, pf[0]);
    _mm256_maskstore_ps(&r.py[size_t(x)], dm, pf[1]);
    _mm256_maskstore_ps(&r.pz[size_t(x)], dm, pf[2]);
    _mm256_maskstore_ps(&r.nx[size_t(x)], dm, nf[0]);
    _mm256_maskstore_ps(&r.ny[size_t(x)], dm, nf[1]);
    _mm256_maskstore_ps(&r.nz[size_t(x)], dm, nf[2]);
    _mm256_maskstore_ps(&r.ox[size_t(x)], dm, of[0]);
    _mm256_maskstore_ps(&r.oy[size_t(x)], dm, of[1]);
    _mm256_maskstore_ps(&r.oz[size_t(x)], dm, of[2]);
    for (int k = 0; k < n; ++k) {
      const size_t i = size_t(x + k);
      if ((done >> k) & 1u) {
        r.covered[i] = 1;
        r.origin_ok[i] = uint8_t((ok_bits >> k) & 1u);
      } else if ((degenerate >> k) & 1u) {
        r.kind[i] = 3;
      }
    }
  }
}

}  // namespace dhr::trace_detail
#endif  // DHR_TRACE_X86_KERNELS
