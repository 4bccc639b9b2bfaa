// The AO pass's AVX-512 kernel (paper section 3.2, Eq. 1-3), used where the CPU has AVX-512F/DQ
// and Embree has native 16-wide packets (core/trace/trace.cpp chooses at run time): a row's tracing
// pixels are gathered first, then ao_rays_x16 makes 16 rays at a time (hashes, uniforms,
// cosine directions: the scalar and SSE2 code's operations in the same order, see
// core/trace/trace_directions.h) straight into the packet and adds each pixel's unoccluded lanes by
// popcount. bench_trace: 0.95-1.01 of the ceiling (0.85 on living-room, where Embree's
// incoherent streams beat its packets). The rays and results are the baseline kernel's bit for
// bit (tests/core/trace/test_trace.cpp: TraceAo.WideKernelsGiveTheSameBits).
//
// The visibility pass's AVX-512 kernels (same choice at run time, TraceSettings::wide_kernels):
// stage 1 (surface_inputs_x16: the G-buffer's ids, barycentrics and normals of a row into the
// per-row triangle table's terms, 16 pixels at a time; surfaces_x16: surface points,
// orientation and origins from that table), stage 2 (sphere_light_row_x16: classification,
// compaction and the hard or single jittered ray; distant_light_row_x16), stage 3
// (list_pairs_x16: the pairs that trace, their rays copied in list order; trace_pairs_x16:
// loaded into packets) and soft_pair_rays_x16 (the cone loop of a soft light with S > 1
// samples per pixel, as the ground truth traces). Compressed lanes are stored from a register:
// AVX-512's compressing store to memory is microcoded on AMD's Zen 4 (a store from a register
// makes temple's hard pass about 8 % faster). Same rays and counts as core/trace/trace_rows.cpp's
// kernels, bit for bit (tests/core/trace/test_trace_bits.cpp pins them by hash on every scene with lights).
// docs/performance.md has the measurements.
//
// Only the functions marked DHR_AVX512_TARGET are compiled for AVX-512 (core/base/avx512.h).
#include "core/base/avx512.h"
#include "core/trace/trace_kernels.h"

#include <algorithm>
#include <limits>
#include <numbers>

#if DHR_TRACE_X86_KERNELS

namespace dhr::trace_detail {

namespace {

// The first `count` of 16 lanes (none for count <= 0, all for count >= 16).
inline __mmask16 lanes_below(int count) {
  return __mmask16(count <= 0 ? 0u : count >= 16 ? 0xffffu : (1u << count) - 1u);
}

// The bytes of v in the lanes of m, p's own bytes elsewhere (AVX-512F has no byte-masked store;
// lanes outside m, such as a row's padding, are written back unchanged).
DHR_AVX512_TARGET inline void store_bytes_x16(uint8_t* p, __m128i v, __mmask16 m) {
  if (!m) return;
  __m128i* q = reinterpret_cast<__m128i*>(p);
  if (m != 0xffff) v = _mm_blendv_epi8(_mm_loadu_si128(q), v, _mm512_cvtepi32_epi8(_mm512_maskz_set1_epi32(m, -1)));
  _mm_storeu_si128(q, v);
}

DHR_AVX512_TARGET inline __m512i mix64_x8(__m512i z) {  // core/base/rng.h's mix64, 8 lanes
  z = _mm512_add_epi64(z, _mm512_set1_epi64(int64_t(0x9E3779B97F4A7C15ull)));
  z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64(z, 30)),
                         _mm512_set1_epi64(int64_t(0xBF58476D1CE4E5B9ull)));
  z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64(z, 27)),
                         _mm512_set1_epi64(int64_t(0x94D049BB133111EBull)));
  return _mm512_xor_si512(z, _mm512_srli_epi64(z, 31));
}

// float(bits >> 40) / 2^24 for 16 keys given as two halves of 8 (exact: the values fit 24 bits).
DHR_AVX512_TARGET inline __m512 uniform_x16(__m512i lo, __m512i hi) {
  const __m256 a = _mm512_cvtepi64_ps(_mm512_srli_epi64(lo, 40));
  const __m256 b = _mm512_cvtepi64_ps(_mm512_srli_epi64(hi, 40));
  return _mm512_mul_ps(_mm512_insertf32x8(_mm512_castps256_ps512(a), b, 1), _mm512_set1_ps(1.0f / 16777216.0f));
}

// lattice_uniform (core/trace/trace.h) on 16 lanes: the top 24 bits of sample a + shift (mod 2^32).
DHR_AVX512_TARGET inline __m512 lattice_x16(__m512i sample, uint32_t a, __m512i shift) {
  const __m512i v = _mm512_add_epi32(_mm512_mullo_epi32(sample, _mm512_set1_epi32(int32_t(a))), shift);
  return _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_srli_epi32(v, 8)), _mm512_set1_ps(1.0f / 16777216.0f));
}

// sincos_2pi_x4 on 16 lanes: the same IEEE operations in the same order.
DHR_AVX512_TARGET inline void sincos_2pi_x16(__m512 u, __m512& c, __m512& s) {
  const __m512 one = _mm512_set1_ps(1.0f);
  const __m512 sign = _mm512_castsi512_ps(_mm512_set1_epi32(int32_t(0x80000000u)));
  const __m512 x = _mm512_mul_ps(_mm512_set1_ps(4.0f), u);
  const __m512i q = _mm512_min_epi32(_mm512_cvttps_epi32(x), _mm512_set1_epi32(3));
  const __m512 a =
      _mm512_mul_ps(_mm512_sub_ps(x, _mm512_cvtepi32_ps(q)), _mm512_set1_ps(std::numbers::pi_v<float> / 2.0f));
  const __m512 a2 = _mm512_mul_ps(a, a);
  __m512 sa = _mm512_add_ps(_mm512_set1_ps(-1.0f / 5040), _mm512_mul_ps(a2, _mm512_set1_ps(1.0f / 362880)));
  sa = _mm512_add_ps(_mm512_set1_ps(1.0f / 120), _mm512_mul_ps(a2, sa));
  sa = _mm512_add_ps(_mm512_set1_ps(-1.0f / 6), _mm512_mul_ps(a2, sa));
  sa = _mm512_add_ps(one, _mm512_mul_ps(a2, sa));
  sa = _mm512_mul_ps(a, sa);
  __m512 ca = _mm512_add_ps(_mm512_set1_ps(-1.0f / 720), _mm512_mul_ps(a2, _mm512_set1_ps(1.0f / 40320)));
  ca = _mm512_add_ps(_mm512_set1_ps(1.0f / 24), _mm512_mul_ps(a2, ca));
  ca = _mm512_add_ps(_mm512_set1_ps(-0.5f), _mm512_mul_ps(a2, ca));
  ca = _mm512_add_ps(one, _mm512_mul_ps(a2, ca));
  const __m512i one_i = _mm512_set1_epi32(1), two_i = _mm512_set1_epi32(2);
  const __mmask16 odd = _mm512_test_epi32_mask(q, one_i);
  const __m512 c0 = _mm512_mask_blend_ps(odd, ca, sa);  // odd ? sa : ca
  const __m512 s0 = _mm512_mask_blend_ps(odd, sa, ca);
  const __mmask16 neg_c = _mm512_test_epi32_mask(_mm512_add_epi32(q, one_i), two_i);
  const __mmask16 neg_s = _mm512_test_epi32_mask(q, two_i);
  c = _mm512_mask_xor_ps(c0, neg_c, c0, sign);
  s = _mm512_mask_xor_ps(s0, neg_s, s0, sign);
}

// Component comp of each lane's pixel: lane l reads pixel p0 + pick[l].
DHR_AVX512_TARGET inline __m512 lane_values(const AoPixels& px, int comp, int p0, __m512i pick) {
  return _mm512_permutexvar_ps(pick, _mm512_loadu_ps(px.c[size_t(comp)].data() + p0));
}

// One component of cosine_dirs_chunk's direction, t * (r c) + b * (r s) + n * z, for the
// axis whose t component is comp_t (b's and n's follow at +3 and +6).
DHR_AVX512_TARGET inline __m512 cosine_dir_x16(const AoPixels& px, int comp_t, int p0, __m512i pick, __m512 rc,
                                               __m512 rs, __m512 z) {
  const __m512 t = lane_values(px, comp_t, p0, pick), b = lane_values(px, comp_t + 3, p0, pick);
  const __m512 n = lane_values(px, comp_t + 6, p0, pick);
  return _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(t, rc), _mm512_mul_ps(b, rs)), _mm512_mul_ps(n, z));
}

}  // namespace

// Stage 2 of the AO rows on AVX-512 (ao_rows_compacted<16> gathers the row's pixels): every
// ray of the row's compacted pixels, in pixel then sample order, 16 rays per packet (a packet
// may hold the end of one pixel's rays and the start of the next ones). Lane l of the packet
// starting at ray r0 = p0 rays + s0 is ray s0 + l of the window starting at pixel p0: pixel
// p0 + (s0 + l) / rays, sample (s0 + l) % rays. Per lane the pixel's values are picked from a
// 16-pixel window; hashes, uniforms and cosine directions are uniforms_chunk's and
// cosine_dirs_chunk's operations in the same order (bit-identical rays), computed 16 at a time
// and stored straight into the packet. Each pixel's unoccluded lanes are added with one
// popcount.
DHR_AVX512_TARGET void ao_rays_x16(const AoPixels& px, int rays, float radius_m, Batch<16>& batch) {
  const int total = px.n * rays;
  const __m512i iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512i rays_i = _mm512_set1_epi32(rays);
  const __m512 rays_f = _mm512_set1_ps(float(rays));
  const __m512i stream = _mm512_set1_epi64(kStreamAo);
  const __m512 one = _mm512_set1_ps(1.0f);
  auto& pk = batch.packet;
  alignas(64) int valid[16];
  for (int r0 = 0; r0 < total; r0 += 16) {
    const int p0 = r0 / rays, s0 = r0 % rays;
    const int live = std::min(16, total - r0);
    // (s0 + l) / rays by float division: exact here (s0 + l < 2^17, quotient <= 16: the
    // rounding error stays far below the 1 / rays that separates a quotient from the next).
    const __m512i v = _mm512_add_epi32(_mm512_set1_epi32(s0), iota);
    const __m512i pick = _mm512_cvttps_epi32(_mm512_div_ps(_mm512_cvtepi32_ps(v), rays_f));
    const __m512i sample = _mm512_sub_epi32(v, _mm512_mullo_epi32(pick, rays_i));
    __m512 u0, u1;
    if (px.lattice) {  // each lane's pixel's shift from the 16-pixel window, as lane_values
      u0 = lattice_x16(sample, kLatticeA0, _mm512_permutexvar_epi32(pick, _mm512_loadu_si512(px.shift0.data() + p0)));
      u1 = lattice_x16(sample, kLatticeA1, _mm512_permutexvar_epi32(pick, _mm512_loadu_si512(px.shift1.data() + p0)));
    } else {
      const __m512i pick_lo = _mm512_cvtepi32_epi64(_mm512_castsi512_si256(pick));
      const __m512i pick_hi = _mm512_cvtepi32_epi64(_mm512_extracti64x4_epi64(pick, 1));
      // key = (sample << 32) | stream, as PixelRng::uniform2
      const __m512i key_lo =
          _mm512_or_si512(_mm512_slli_epi64(_mm512_cvtepu32_epi64(_mm512_castsi512_si256(sample)), 32), stream);
      const __m512i key_hi =
          _mm512_or_si512(_mm512_slli_epi64(_mm512_cvtepu32_epi64(_mm512_extracti64x4_epi64(sample, 1)), 32), stream);
      const __m512i h0 = _mm512_loadu_si512(px.h.data() + p0), h1 = _mm512_loadu_si512(px.h.data() + p0 + 8);
      const __m512i k_lo = mix64_x8(_mm512_xor_si512(_mm512_permutex2var_epi64(h0, pick_lo, h1), key_lo));
      const __m512i k_hi = mix64_x8(_mm512_xor_si512(_mm512_permutex2var_epi64(h0, pick_hi, h1), key_hi));
      const __m512i dim1 = _mm512_set1_epi64(1);
      u0 = uniform_x16(mix64_x8(k_lo), mix64_x8(k_hi));
      u1 = uniform_x16(mix64_x8(_mm512_xor_si512(k_lo, dim1)), mix64_x8(_mm512_xor_si512(k_hi, dim1)));
    }
    const __m512 r = _mm512_sqrt_ps(u0);
    const __m512 z = _mm512_sqrt_ps(_mm512_sub_ps(one, u0));
    __m512 c, s;
    sincos_2pi_x16(u1, c, s);
    const __m512 rc = _mm512_mul_ps(r, c), rs = _mm512_mul_ps(r, s);
    _mm512_store_ps(pk.org_x, lane_values(px, AoPixels::kOx, p0, pick));
    _mm512_store_ps(pk.org_y, lane_values(px, AoPixels::kOy, p0, pick));
    _mm512_store_ps(pk.org_z, lane_values(px, AoPixels::kOz, p0, pick));
    _mm512_store_ps(pk.dir_x, cosine_dir_x16(px, AoPixels::kTx, p0, pick, rc, rs, z));
    _mm512_store_ps(pk.dir_y, cosine_dir_x16(px, AoPixels::kTy, p0, pick, rc, rs, z));
    _mm512_store_ps(pk.dir_z, cosine_dir_x16(px, AoPixels::kTz, p0, pick, rc, rs, z));
    _mm512_store_ps(pk.tfar, _mm512_set1_ps(radius_m));  // tfar = r: never trace further
    if (batch.record) {                                  // collect_ao_rays: push() keeps the rays, traces nothing
      for (int l = 0; l < live; ++l)
        batch.push(glm::vec3(pk.org_x[l], pk.org_y[l], pk.org_z[l]), pk.dir_x[l], pk.dir_y[l], pk.dir_z[l], radius_m,
                   nullptr);
      continue;
    }
    for (int l = 0; l < 16; ++l) valid[l] = l < live ? -1 : 0;
    rtcOccluded16(valid, batch.scene, &batch.ctx, &pk);
    // Embree sets tfar = -inf on an occluded ray; anything else reached (as Batch::flush).
    const uint32_t live_mask = (1u << live) - 1u;
    const uint32_t reached = _mm512_cmp_ps_mask(_mm512_load_ps(pk.tfar), _mm512_setzero_ps(), _CMP_NLT_UQ) & live_mask;
    const int last = (s0 + live - 1) / rays;  // the packet's last pixel, relative to p0
    for (int g = 0; g <= last; ++g) {
      const uint32_t lanes = _mm512_cmpeq_epi32_mask(pick, _mm512_set1_epi32(g));
      uint16_t* count = px.count[size_t(p0 + g)];
      *count = uint16_t(*count + popcount16(reached & lanes));  // the target has no POPCNT either
    }
    batch.traced += uint64_t(live);
  }
}

namespace {

// The low 8 lanes of lo, then the low 8 of hi.
DHR_AVX512_TARGET inline __m512 join(__m512 lo, __m512 hi) {
  return _mm512_insertf32x8(lo, _mm512_castps512_ps256(hi), 1);
}

// orthonormal_basis_x4 (core/trace/trace_directions.h) on 16 lanes: the same operations.
DHR_AVX512_TARGET inline void orthonormal_basis_x16(__m512 nx, __m512 ny, __m512 nz, __m512 t[3], __m512 b[3]) {
  const __m512 signbit = _mm512_castsi512_ps(_mm512_set1_epi32(int32_t(0x80000000u)));
  const __m512 sign = _mm512_or_ps(_mm512_and_ps(nz, signbit), _mm512_set1_ps(1.0f));  // copysign(1, n.z)
  const __m512 neg_sign = _mm512_xor_ps(sign, signbit);
  const __m512 a = _mm512_div_ps(_mm512_set1_ps(-1.0f), _mm512_add_ps(sign, nz));
  const __m512 c = _mm512_mul_ps(_mm512_mul_ps(nx, ny), a);
  t[0] = _mm512_add_ps(_mm512_set1_ps(1.0f), _mm512_mul_ps(_mm512_mul_ps(_mm512_mul_ps(sign, nx), nx), a));
  t[1] = _mm512_mul_ps(sign, c);
  t[2] = _mm512_mul_ps(neg_sign, nx);
  b[0] = c;
  b[1] = _mm512_add_ps(sign, _mm512_mul_ps(_mm512_mul_ps(ny, ny), a));
  b[2] = _mm512_xor_ps(ny, signbit);
}

// cone_x4 (core/trace/trace_directions.h) on 16 lanes: normalize(t * (c sin) + b * (s sin) + w * cos).
DHR_AVX512_TARGET inline void cone_x16(const __m512 t[3], const __m512 b[3], const __m512 w[3], __m512 omc_max,
                                       __m512 u0, __m512 u1, __m512 d[3]) {
  const __m512 omc = _mm512_mul_ps(u0, omc_max);
  const __m512 cos_t = _mm512_sub_ps(_mm512_set1_ps(1.0f), omc);
  const __m512 sin_t =
      _mm512_sqrt_ps(_mm512_max_ps(_mm512_mul_ps(omc, _mm512_sub_ps(_mm512_set1_ps(2.0f), omc)), _mm512_setzero_ps()));
  __m512 c, s;
  sincos_2pi_x16(u1, c, s);
  const __m512 cs = _mm512_mul_ps(c, sin_t), ss = _mm512_mul_ps(s, sin_t);
  __m512 v[3];
  for (int k = 0; k < 3; ++k)
    v[k] = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(t[k], cs), _mm512_mul_ps(b[k], ss)), _mm512_mul_ps(w[k], cos_t));
  const __m512 dot =
      _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(v[0], v[0]), _mm512_mul_ps(v[1], v[1])), _mm512_mul_ps(v[2], v[2]));
  const __m512 inv = _mm512_div_ps(_mm512_set1_ps(1.0f), _mm512_sqrt_ps(dot));
  for (int k = 0; k < 3; ++k) d[k] = _mm512_mul_ps(v[k], inv);
}

// sphere_tfar_x4 (core/trace/trace_directions.h) on 16 lanes.
DHR_AVX512_TARGET inline __m512 sphere_tfar_x16(const __m512 d[3], const __m512 oc[3], __m512 r2) {
  const __m512 b =
      _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(d[0], oc[0]), _mm512_mul_ps(d[1], oc[1])), _mm512_mul_ps(d[2], oc[2]));
  const __m512 qx = _mm512_sub_ps(oc[0], _mm512_mul_ps(b, d[0]));
  const __m512 qy = _mm512_sub_ps(oc[1], _mm512_mul_ps(b, d[1]));
  const __m512 qz = _mm512_sub_ps(oc[2], _mm512_mul_ps(b, d[2]));
  const __m512 disc = _mm512_sub_ps(
      r2, _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(qx, qx), _mm512_mul_ps(qy, qy)), _mm512_mul_ps(qz, qz)));
  const __mmask16 pos = _mm512_cmp_ps_mask(disc, _mm512_setzero_ps(), _CMP_GT_OQ);
  const __m512 t_hit = _mm512_mask_blend_ps(pos, b, _mm512_sub_ps(b, _mm512_sqrt_ps(disc)));  // pos ? b - sqrt : b
  return _mm512_max_ps(_mm512_mul_ps(t_hit, _mm512_set1_ps(kShadowTfarScale)), _mm512_setzero_ps());
}

// direction_valid (core/trace/trace_directions.h), 16 lanes.
DHR_AVX512_TARGET inline __mmask16 directions_valid_x16(const __m512 d[3], __m512 tfar) {
  const __m512 zero = _mm512_setzero_ps(), fmax = _mm512_set1_ps(std::numeric_limits<float>::max());
  const __mmask16 finite = _mm512_cmp_ps_mask(_mm512_abs_ps(d[0]), fmax, _CMP_LE_OQ) &
                           _mm512_cmp_ps_mask(_mm512_abs_ps(d[1]), fmax, _CMP_LE_OQ) &
                           _mm512_cmp_ps_mask(_mm512_abs_ps(d[2]), fmax, _CMP_LE_OQ);
  const __mmask16 nonzero = _mm512_cmp_ps_mask(d[0], zero, _CMP_NEQ_UQ) | _mm512_cmp_ps_mask(d[1], zero, _CMP_NEQ_UQ) |
                            _mm512_cmp_ps_mask(d[2], zero, _CMP_NEQ_UQ);
  return finite & nonzero & _mm512_cmp_ps_mask(tfar, zero, _CMP_GE_OQ);
}

// directions_valid_x16 and the origin's validity (bytes 0/1).
DHR_AVX512_TARGET inline __mmask16 rays_valid_x16(const __m512 d[3], __m512 tfar, const uint8_t* origin_ok) {
  const __m512i ook = _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(origin_ok)));
  return directions_valid_x16(d, tfar) & _mm512_test_epi32_mask(ook, ook);
}

}  // namespace

DHR_AVX512_TARGET int sphere_light_row_x16(VisibilityRow& r, const LightInfo& li, size_t base, bool one_sample) {
  const int w = r.w;
  const __m512d cx = _mm512_set1_pd(li.centre_d.x), cy = _mm512_set1_pd(li.centre_d.y),
                cz = _mm512_set1_pd(li.centre_d.z);
  const __m512d range = _mm512_set1_pd(double(li.range)), radius = _mm512_set1_pd(double(li.radius));
  const __m512d facing_at = li.soft ? _mm512_set1_pd(-double(li.radius)) : _mm512_setzero_pd();
  const __m512d rr = _mm512_set1_pd(double(li.radius) * li.radius), one_d = _mm512_set1_pd(1.0);
  const __mmask8 has_range = li.range > 0.0f ? 0xff : 0;
  const __m512 lc[3] = {_mm512_set1_ps(li.centre.x), _mm512_set1_ps(li.centre.y), _mm512_set1_ps(li.centre.z)};
  const __m512 lradius = _mm512_set1_ps(li.radius), tfar_scale = _mm512_set1_ps(kShadowTfarScale);
  const __m512 r2 = _mm512_set1_ps(li.radius * li.radius);
  const __m512 zero = _mm512_setzero_ps();
  const __m512i iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const bool rays = !li.soft || one_sample;  // else the caller makes the cones (S > 1)
  int* idx = r.idx.data();
  int m = 0;
  for (int x = 0; x < w; x += 16) {
    const int n = std::min(16, w - x);
    const __mmask16 live = __mmask16((1u << n) - 1u);
    // Classification in double: d = |c - p|, n . (c - p) (the scalar code's order of sums).
    __mmask16 oor = 0, inside = 0, facing = 0;
    __m512d t[2][3], d[2];
    for (int half = 0; half < 2; ++half) {
      const size_t xh = size_t(x + 8 * half);
      __m512d* th = t[half];
      th[0] = _mm512_sub_pd(cx, _mm512_cvtps_pd(_mm256_loadu_ps(&r.px[xh])));
      th[1] = _mm512_sub_pd(cy, _mm512_cvtps_pd(_mm256_loadu_ps(&r.py[xh])));
      th[2] = _mm512_sub_pd(cz, _mm512_cvtps_pd(_mm256_loadu_ps(&r.pz[xh])));
      d[half] = _mm512_sqrt_pd(_mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(th[0], th[0]), _mm512_mul_pd(th[1], th[1])),
                                             _mm512_mul_pd(th[2], th[2])));
      const __m512d n_dot =
          _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(_mm512_cvtps_pd(_mm256_loadu_ps(&r.nx[xh])), th[0]),
                                      _mm512_mul_pd(_mm512_cvtps_pd(_mm256_loadu_ps(&r.ny[xh])), th[1])),
                        _mm512_mul_pd(_mm512_cvtps_pd(_mm256_loadu_ps(&r.nz[xh])), th[2]));
      const int sh = 8 * half;
      oor |= __mmask16(__mmask16(_mm512_mask_cmp_pd_mask(has_range, d[half], range, _CMP_GT_OQ)) << sh);
      inside |= __mmask16(__mmask16(_mm512_cmp_pd_mask(d[half], radius, _CMP_LE_OQ)) << sh);  // !(d > R) && d == d
      facing |= __mmask16(__mmask16(_mm512_cmp_pd_mask(n_dot, facing_at, _CMP_LE_OQ)) << sh);
    }
    // code = out_of_range ? range : inside ? inside : facing ? facing : rays
    __m512i code = _mm512_setzero_si512();
    code = _mm512_mask_mov_epi32(code, facing, _mm512_set1_epi32(kPairFacing));
    code = _mm512_mask_mov_epi32(code, inside, _mm512_set1_epi32(kPairInside));
    code = _mm512_mask_mov_epi32(code, oor, _mm512_set1_epi32(kPairRange));
    alignas(16) uint8_t bytes[16];
    _mm_store_si128(reinterpret_cast<__m128i*>(bytes), _mm512_cvtepi32_epi8(code));
    std::copy(bytes, bytes + n, &r.code[base + size_t(x)]);
    const __m512i covered =
        _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(&r.covered[size_t(x)])));
    const __mmask16 traced = __mmask16(~(oor | inside | facing)) & _mm512_test_epi32_mask(covered, covered) & live;
    // Compressed in a register and stored whole (see list_pairs_x16); r.idx has kRowPad entries
    // of padding past the row (m + 16 <= x + 16).
    _mm512_storeu_si512(idx + m, _mm512_maskz_compress_epi32(traced, _mm512_add_epi32(_mm512_set1_epi32(x), iota)));
    m += popcount16(traced);
    if (!rays || traced == 0) continue;
    // The ray of every pixel of the block (stored for the traced pairs only), in float from
    // the offset origin: oc = centre - origin.
    const __m512 oc[3] = {_mm512_sub_ps(lc[0], _mm512_loadu_ps(&r.ox[size_t(x)])),
                          _mm512_sub_ps(lc[1], _mm512_loadu_ps(&r.oy[size_t(x)])),
                          _mm512_sub_ps(lc[2], _mm512_loadu_ps(&r.oz[size_t(x)]))};
    __m512 dir[3], tfar;
    if (!li.soft) {
      // Hard: towards the centre, ending kShadowTfarScale short of the sphere.
      const __m512 dist_o = _mm512_sqrt_ps(_mm512_add_ps(
          _mm512_add_ps(_mm512_mul_ps(oc[0], oc[0]), _mm512_mul_ps(oc[1], oc[1])), _mm512_mul_ps(oc[2], oc[2])));
      for (int k = 0; k < 3; ++k) dir[k] = _mm512_div_ps(oc[k], dist_o);
      // std::max(0.0f, v): v where 0 < v, else 0 (NaN and -0 give +0), as max_ps(v, 0).
      tfar = _mm512_max_ps(_mm512_mul_ps(_mm512_sub_ps(dist_o, lradius), tfar_scale), zero);
    } else {
      // One jittered ray in the cone the sphere subtends from p: 1 - cos = s2 / (1 + sqrt(1 -
      // s2)), s2 = R^2 / d^2, axis (c - p) / d, all in double, then rounded to float.
      __m512 omc_h[2], wv_h[2][3];
      for (int half = 0; half < 2; ++half) {
        const __m512d s2 = _mm512_div_pd(rr, _mm512_mul_pd(d[half], d[half]));
        omc_h[half] = _mm512_castps256_ps512(
            _mm512_cvtpd_ps(_mm512_div_pd(s2, _mm512_add_pd(one_d, _mm512_sqrt_pd(_mm512_sub_pd(one_d, s2))))));
        for (int k = 0; k < 3; ++k)
          wv_h[half][k] = _mm512_castps256_ps512(_mm512_cvtpd_ps(_mm512_div_pd(t[half][k], d[half])));
      }
      const __m512 omc = join(omc_h[0], omc_h[1]);
      const __m512 wv[3] = {join(wv_h[0][0], wv_h[1][0]), join(wv_h[0][1], wv_h[1][1]), join(wv_h[0][2], wv_h[1][2])};
      __m512 tb[3], bb[3];
      orthonormal_basis_x16(wv[0], wv[1], wv[2], tb, bb);
      cone_x16(tb, bb, wv, omc, _mm512_loadu_ps(&r.u0[size_t(x)]), _mm512_loadu_ps(&r.u1[size_t(x)]), dir);
      tfar = sphere_tfar_x16(dir, oc, r2);
    }
    const __mmask16 ok = rays_valid_x16(dir, tfar, &r.origin_ok[size_t(x)]);
    const size_t i = base + size_t(x);
    _mm512_mask_storeu_ps(&r.dx[i], traced, dir[0]);
    _mm512_mask_storeu_ps(&r.dy[i], traced, dir[1]);
    _mm512_mask_storeu_ps(&r.dz[i], traced, dir[2]);
    _mm512_mask_storeu_ps(&r.tfar[i], traced, tfar);
    _mm_store_si128(reinterpret_cast<__m128i*>(bytes),
                    _mm512_cvtepi32_epi8(_mm512_maskz_mov_epi32(ok, _mm512_set1_epi32(1))));
    for (int k = 0; k < n; ++k)
      if ((traced >> k) & 1u) r.ok[i + size_t(k)] = bytes[k];
  }
  return m;
}

DHR_AVX512_TARGET void surfaces_x16(VisibilityRow& r, const TraceSettings& settings, size_t row_start, bool hashes) {
  const int w = r.w;
  const double* tri = r.tris.data();
  const __m512d zero_d = _mm512_setzero_pd(), one_d = _mm512_set1_pd(1.0);
  const __m512i iota64 = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
  const __m512i seed = _mm512_set1_epi64(int64_t(mix64(settings.seed)));
  const __m512i frame = _mm512_set1_epi64(int64_t(settings.frame));
  const __m512i dsign = _mm512_set1_epi64(int64_t(0x8000000000000000ull));
  for (int x = 0; x < w; x += 16) {
    const int n = std::min(16, w - x);
    const __mmask16 live = __mmask16((1u << n) - 1u);
    if (hashes) {  // PixelRng(seed, pixel, frame).h, pixel as uint32
      for (int half = 0; half < 2; ++half) {
        const __m512i pixel =
            _mm512_and_si512(_mm512_add_epi64(_mm512_set1_epi64(int64_t(row_start + size_t(x + 8 * half))), iota64),
                             _mm512_set1_epi64(0xffffffffll));
        const __m512i key = _mm512_or_si512(_mm512_slli_epi64(pixel, 32), frame);
        _mm512_mask_storeu_epi64(&r.h[size_t(x + 8 * half)], __mmask8(live >> (8 * half)),
                                 mix64_x8(_mm512_xor_si512(seed, key)));
      }
    }
    const __m512i kind = _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(&r.kind[size_t(x)])));
    const __mmask16 vec = _mm512_cmpeq_epi32_mask(kind, _mm512_set1_epi32(1)) & live;
    if (vec == 0) continue;
    __m512 pf[3], nf[3];
    __m256 ph[2][3], nh[2][3], oh[2][3];
    __mmask16 degenerate = 0;
    for (int half = 0; half < 2; ++half) {
      const size_t xh = size_t(x + 8 * half);
      const __mmask8 m8 = __mmask8(vec >> (8 * half));
      // The row triangle's 13 values per lane. The 8 pixels mostly lie on one to three
      // triangles: each one's values are broadcast to its lanes; beyond that the rest are
      // gathered lane by lane (the same values either way).
      const __m256i tri_of = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(&r.tri_of[xh]));
      __m512d c[13];
      for (int k = 0; k < 13; ++k) c[k] = zero_d;
      __mmask8 left = m8;
      for (int distinct = 0; left && distinct < 3; ++distinct) {
        const int t = r.tri_of[xh + size_t(__builtin_ctz(left))];
        const __mmask8 same =
            __mmask8(_mm512_mask_cmpeq_epi32_mask(left, _mm512_castsi256_si512(tri_of), _mm512_set1_epi32(t)));
        const double* v = tri + 14 * size_t(t);
        for (int k = 0; k < 13; ++k) c[k] = _mm512_mask_mov_pd(c[k], same, _mm512_set1_pd(v[k]));
        left = __mmask8(left & ~same);
      }
      if (left) {
        const __m256i base = _mm256_mullo_epi32(tri_of, _mm256_set1_epi32(14));
        for (int k = 0; k < 13; ++k)
          c[k] = _mm512_mask_i32gather_pd(c[k], left, _mm256_add_epi32(base, _mm256_set1_epi32(k)), tri, 8);
      }
      // p = (1 - b1 - b2) v0 + b1 v1 + b2 v2
      const __m512d b1 = _mm512_cvtps_pd(_mm256_loadu_ps(&r.b1[xh])), b2 = _mm512_cvtps_pd(_mm256_loadu_ps(&r.b2[xh]));
      const __m512d a = _mm512_sub_pd(_mm512_sub_pd(one_d, b1), b2);
      __m512d pd[3];
      for (int k = 0; k < 3; ++k) {
        pd[k] = _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(a, c[k]), _mm512_mul_pd(b1, c[3 + k])),
                              _mm512_mul_pd(b2, c[6 + k]));
        ph[half][k] = _mm512_cvtpd_ps(pd[k]);
      }
      // Oriented like the G-buffer's geometric normal: side = n . gn.
      const __m512d side =
          _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(c[9], _mm512_cvtps_pd(_mm256_loadu_ps(&r.gx[xh]))),
                                      _mm512_mul_pd(c[10], _mm512_cvtps_pd(_mm256_loadu_ps(&r.gy[xh])))),
                        _mm512_mul_pd(c[11], _mm512_cvtps_pd(_mm256_loadu_ps(&r.gz[xh]))));
      degenerate |=
          __mmask16(__mmask16(_mm512_cmp_pd_mask(_mm512_abs_pd(side), zero_d, _CMP_NGT_UQ) & m8) << (8 * half));
      const __mmask8 flip = _mm512_cmp_pd_mask(side, zero_d, _CMP_LT_OQ);
      for (int k = 0; k < 3; ++k) {
        const __m512d nk = _mm512_castsi512_pd(
            _mm512_mask_xor_epi64(_mm512_castpd_si512(c[9 + k]), flip, _mm512_castpd_si512(c[9 + k]), dsign));
        nh[half][k] = _mm512_cvtpd_ps(nk);
        // offset_ray_origin (core/trace/trace.h): float(p + n offset_m), in double.
        oh[half][k] = _mm512_cvtpd_ps(_mm512_add_pd(pd[k], _mm512_mul_pd(nk, c[12])));
      }
    }
    for (int k = 0; k < 3; ++k) {
      pf[k] = _mm512_insertf32x8(_mm512_castps256_ps512(ph[0][k]), ph[1][k], 1);
      nf[k] = _mm512_insertf32x8(_mm512_castps256_ps512(nh[0][k]), nh[1][k], 1);
    }
    __m512 of[3];
    __mmask16 origin_ok = 0xffff;
    for (int k = 0; k < 3; ++k) {
      of[k] = _mm512_insertf32x8(_mm512_castps256_ps512(oh[0][k]), oh[1][k], 1);
      origin_ok &= _mm512_cmp_ps_mask(_mm512_abs_ps(of[k]), _mm512_set1_ps(kMaxCoordinate), _CMP_LT_OQ);
    }
    const __mmask16 done = vec & __mmask16(~degenerate);
    _mm512_mask_storeu_ps(&r.px[size_t(x)], done, pf[0]);
    _mm512_mask_storeu_ps(&r.py[size_t(x)], done, pf[1]);
    _mm512_mask_storeu_ps(&r.pz[size_t(x)], done, pf[2]);
    _mm512_mask_storeu_ps(&r.nx[size_t(x)], done, nf[0]);
    _mm512_mask_storeu_ps(&r.ny[size_t(x)], done, nf[1]);
    _mm512_mask_storeu_ps(&r.nz[size_t(x)], done, nf[2]);
    _mm512_mask_storeu_ps(&r.ox[size_t(x)], done, of[0]);
    _mm512_mask_storeu_ps(&r.oy[size_t(x)], done, of[1]);
    _mm512_mask_storeu_ps(&r.oz[size_t(x)], done, of[2]);
    store_bytes_x16(&r.covered[size_t(x)], _mm_set1_epi8(1), done);
    store_bytes_x16(&r.origin_ok[size_t(x)], _mm512_cvtepi32_epi8(_mm512_maskz_set1_epi32(origin_ok, 1)), done);
    store_bytes_x16(&r.kind[size_t(x)], _mm_set1_epi8(3), degenerate);
  }
}

// The lanes of `left` whose (id, prim) is (id, prim).
DHR_AVX512_TARGET inline __mmask16 on_triangle_x16(__mmask16 left, __m512i ids, __m512i prims, uint32_t id,
                                                   uint32_t prim) {
  return _mm512_mask_cmpeq_epi32_mask(left, ids, _mm512_set1_epi32(int(id))) &
         _mm512_mask_cmpeq_epi32_mask(left, prims, _mm512_set1_epi32(int(prim)));
}

DHR_AVX512_TARGET int surface_inputs_x16(const SurfaceInputs& io, int x, int w, RowTriangles& t, uint64_t& cov) {
  // Element i of 16 interleaved vec2: x from float 2i, y from 2i + 1 (of two 16-float loads).
  const __m512i even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
  const __m512i odd = _mm512_add_epi32(even, _mm512_set1_epi32(1));
  const __m512i background = _mm512_set1_epi32(int(kBackgroundId));
  const __m512 zero = _mm512_setzero_ps();
  for (; x < w; x += 16) {
    const int n = std::min(16, w - x);
    const __mmask16 live = lanes_below(n);
    const __m512i ids = _mm512_maskz_loadu_epi32(live, io.ids + x);
    const __mmask16 on = _mm512_mask_cmpneq_epi32_mask(live, ids, background);
    // Each covered pixel's row triangle: the pixels on one triangle at a time, taking the
    // triangles in the order their first pixels come (as the loop would select them).
    __m512i rows = _mm512_setzero_si512();
    if (on) {
      const __m512i prims = _mm512_maskz_loadu_epi32(on, io.prims + x);
      __mmask16 left = on;
      if (t.tc && t.tc->resolved && t.cur >= 0) {
        const __mmask16 same = on_triangle_x16(left, ids, prims, t.tc->id, t.tc->prim);
        rows = _mm512_mask_mov_epi32(rows, same, _mm512_set1_epi32(t.cur));
        left = __mmask16(left & ~same);
      }
      while (left) {
        const int k = __builtin_ctz(left);
        const uint32_t id = io.ids[x + k], prim = io.prims[x + k];
        select_triangle(t, id, prim);
        if (!t.tc->resolved) return x;  // the loop does this block (its state is one it can be in)
        add_row_triangle(t);
        const __mmask16 same = on_triangle_x16(left, ids, prims, id, prim);
        rows = _mm512_mask_mov_epi32(rows, same, _mm512_set1_epi32(t.cur));
        left = __mmask16(left & ~same);
      }
    }
    const __mmask16 off = live & __mmask16(~on);
    store_bytes_x16(io.kind + x, _mm512_cvtepi32_epi8(_mm512_maskz_set1_epi32(on, 1)), live);
    store_bytes_x16(io.covered + x, _mm_setzero_si128(), off);
    store_bytes_x16(io.origin_ok + x, _mm_set1_epi8(1), off);
    for (int k = 0; k < 9; ++k) _mm512_mask_storeu_ps(io.planes[k] + x, off, zero);
    if (!on) continue;
    cov += uint64_t(__builtin_popcount(on));
    _mm512_mask_storeu_epi32(io.tri_of + x, on, rows);
    // Masked loads: nothing is read past the row's last pixel.
    const float* b = &io.bary[x].x;
    const __m512 b_lo = _mm512_maskz_loadu_ps(lanes_below(2 * n), b),
                 b_hi = _mm512_maskz_loadu_ps(lanes_below(2 * n - 16), b + 16);
    _mm512_mask_storeu_ps(io.b1 + x, on, _mm512_permutex2var_ps(b_lo, even, b_hi));
    _mm512_mask_storeu_ps(io.b2 + x, on, _mm512_permutex2var_ps(b_lo, odd, b_hi));
    const float* gn = &io.gnorm[x].x;
    const __m512 a = _mm512_maskz_loadu_ps(lanes_below(3 * n), gn),
                 bb = _mm512_maskz_loadu_ps(lanes_below(3 * n - 16), gn + 16),
                 c = _mm512_maskz_loadu_ps(lanes_below(3 * n - 32), gn + 32);
    float* const g[3] = {io.gx, io.gy, io.gz};
    for (int k = 0; k < 3; ++k) {
      const __m512 ab = _mm512_permutex2var_ps(a, _mm512_load_si512(kDeinterleave3.first[k]), bb);
      _mm512_mask_storeu_ps(g[k] + x, on, _mm512_permutex2var_ps(ab, _mm512_load_si512(kDeinterleave3.second[k]), c));
    }
  }
  return w;
}

// Bit i of m at bit NL * i (i < 16): a light's pairs among a block's 16 * NL in pixel then
// light order (the constants spread the bits in halving steps).
template <int NL>
constexpr uint64_t spread_bits(uint64_t x) {
  x &= 0xffffu;
  if constexpr (NL == 2) {
    x = (x | x << 8) & 0x00ff00ffu;
    x = (x | x << 4) & 0x0f0f0f0fu;
    x = (x | x << 2) & 0x33333333u;
    x = (x | x << 1) & 0x55555555u;
  } else if constexpr (NL == 3) {
    x = (x | x << 16) & 0x0000ff0000ffull;
    x = (x | x << 8) & 0x00f00f00f00full;
    x = (x | x << 4) & 0x0c30c30c30c3ull;
    x = (x | x << 2) & 0x249249249249ull;
  } else if constexpr (NL == 4) {
    x = (x | x << 24) & 0x000000ff000000ffull;
    x = (x | x << 12) & 0x000f000f000f000full;
    x = (x | x << 6) & 0x0303030303030303ull;
    x = (x | x << 3) & 0x1111111111111111ull;
  }
  return x;
}
// Each step maps a | b to the steps of a and b or-ed, so the single bits check every mask.
template <int NL>
constexpr bool spread_bits_checked() {
  for (int i = 0; i < 16; ++i)
    if (spread_bits<NL>(uint64_t(1) << i) != uint64_t(1) << (NL * i)) return false;
  return spread_bits<NL>(0) == 0 && spread_bits<NL>(0x10000u) == 0;
}
static_assert(spread_bits_checked<1>() && spread_bits_checked<2>() && spread_bits_checked<3>() &&
              spread_bits_checked<4>());

// Chunk q of a block's 16 * NL pairs in pixel then light order: lane i is pair 16q + i, the
// block's pixel (16q + i) / NL and its light (16q + i) % NL (also as two halves of 64-bit
// lanes, the pixel in bytes of 16-bit counters); from[q][l]: the lanes of chunk q on light l.
template <int NL>
struct PairChunks {
  alignas(64) int32_t pixel[NL][16];
  alignas(64) int64_t light64[NL][2][8];
  alignas(64) int64_t pixel_bytes[NL][2][8];
  uint16_t from[NL][NL];
  constexpr PairChunks() : pixel{}, light64{}, pixel_bytes{}, from{} {
    for (int q = 0; q < NL; ++q)
      for (int i = 0; i < 16; ++i) {
        const int j = 16 * q + i;
        pixel[q][i] = j / NL;
        light64[q][i / 8][i % 8] = j % NL;
        pixel_bytes[q][i / 8][i % 8] = 2 * (j / NL);
        from[q][j % NL] = uint16_t(from[q][j % NL] | (1u << i));
      }
  }
};

// The codes of a block's 16 pixels for each light: the pairs that do not trace counted (and
// their counters set), the ones that trace returned per light in traced. Returns their union.
DHR_AVX512_TARGET inline __mmask16 classify_pairs_x16(const VisibilityRow& r, int nl, int x, __mmask16 cov,
                                                      uint16_t* counts, size_t npx, PairTally& tally,
                                                      __mmask16* traced) {
  const int w = r.w;
  __mmask16 any = 0;
  for (int l = 0; l < nl; ++l) {
    const size_t i = size_t(l) * size_t(w) + size_t(x);
    const __m512i code = _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(&r.code[i])));
    const __mmask16 range = _mm512_mask_cmpeq_epi32_mask(cov, code, _mm512_set1_epi32(kPairRange));
    const __mmask16 inside = _mm512_mask_cmpeq_epi32_mask(cov, code, _mm512_set1_epi32(kPairInside));
    const __mmask16 facing = _mm512_mask_cmpeq_epi32_mask(cov, code, _mm512_set1_epi32(kPairFacing));
    const __mmask16 rays = cov & __mmask16(~(range | inside | facing));
    const __m512i ok = _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(&r.ok[i])));
    const __mmask16 t = _mm512_mask_cmpneq_epi32_mask(rays, ok, _mm512_setzero_si512());
    const __mmask16 invalid = rays & __mmask16(~t);
    tally.range += uint64_t(__builtin_popcount(range));
    tally.facing += uint64_t(__builtin_popcount(facing));
    tally.inside += uint64_t(__builtin_popcount(inside));
    tally.invalid += uint64_t(__builtin_popcount(invalid));
    uint16_t* c = counts + size_t(l) * npx + size_t(x);
    for (unsigned m = inside; m; m &= m - 1) c[__builtin_ctz(m)] = 1;
    for (unsigned m = invalid; m; m &= m - 1) ++c[__builtin_ctz(m)];
    traced[l] = t;
    any |= t;
  }
  return any;
}

// Lists the traced pairs of a block of 16 pixels (from pixel x) whose traced lanes lie on NA
// <= kListPairsVectorLights lights, active[0] < active[1] < ...: in pixel then light order, the
// list's order (the other lights add no pair). Each of the NA chunks of 16 lanes is permuted
// from the lights' registers (one permute for the origins, NA for each direction plane),
// compressed by its traced lanes in a register and stored whole (a compressing store to memory
// is microcoded and slow on AMD's Zen 4); the counters' addresses likewise. What lies past the
// n-th entry is overwritten later or never read: pair_ray and pair_count have kRowPad entries
// past the most a row can list. Returns the new n.
template <int NA>
DHR_AVX512_TARGET int list_block_x16(VisibilityRow& r, int x, const int* active, const __mmask16* traced,
                                     uint16_t* counts, size_t npx, int n) {
  static constexpr PairChunks<NA> kChunks{};
  const size_t w = size_t(r.w);
  const __mmask16 live = lanes_below(r.w - x);
  uint64_t listed = 0;  // bit j: the block's pair j in pixel then light order traces
  for (int a = 0; a < NA; ++a) listed |= spread_bits<NA>(traced[active[a]]) << a;
  // The origins by pixel; the directions and tfar by light and pixel (the last light's arrays
  // end with the row: masked loads).
  const __m512 origin[3] = {_mm512_loadu_ps(&r.ox[size_t(x)]), _mm512_loadu_ps(&r.oy[size_t(x)]),
                            _mm512_loadu_ps(&r.oz[size_t(x)])};
  const float* const dir[4] = {r.dx.data(), r.dy.data(), r.dz.data(), r.tfar.data()};
  __m512 ray[4][NA];
  alignas(64) int64_t first_counter[8] = {};  // active light a's counter of pixel x
  for (int a = 0; a < NA; ++a) {
    const size_t l = size_t(active[a]);
    for (int c = 0; c < 4; ++c) ray[c][a] = _mm512_maskz_loadu_ps(live, dir[c] + l * w + size_t(x));
    first_counter[a] = int64_t(reinterpret_cast<uintptr_t>(counts + l * npx + size_t(x)));
  }
  const __m512i counter0 = _mm512_load_si512(first_counter);
  float* const out[7] = {r.pair_ray[0].data(), r.pair_ray[1].data(), r.pair_ray[2].data(), r.pair_ray[3].data(),
                         r.pair_ray[4].data(), r.pair_ray[5].data(), r.pair_ray[6].data()};
  for (int q = 0; q < NA; ++q) {
    const __mmask16 m = __mmask16(listed >> (16 * q));
    if (!m) continue;
    const __m512i pixel = _mm512_load_si512(kChunks.pixel[q]);
    for (int c = 0; c < 3; ++c) {
      const __m512 v = NA == 1 ? origin[c] : _mm512_permutexvar_ps(pixel, origin[c]);
      _mm512_storeu_ps(out[c] + n, _mm512_maskz_compress_ps(m, v));
    }
    for (int c = 0; c < 4; ++c) {
      __m512 v = ray[c][0];
      if constexpr (NA > 1) {
        v = _mm512_permutexvar_ps(pixel, v);
        for (int a = 1; a < NA; ++a) v = _mm512_mask_permutexvar_ps(v, kChunks.from[q][a], pixel, ray[c][a]);
      }
      _mm512_storeu_ps(out[3 + c] + n, _mm512_maskz_compress_ps(m, v));
    }
    __m512i counter[2];
    for (int half = 0; half < 2; ++half)
      counter[half] = _mm512_add_epi64(_mm512_permutexvar_epi64(_mm512_load_si512(kChunks.light64[q][half]), counter0),
                                       _mm512_load_si512(kChunks.pixel_bytes[q][half]));
    const int n_lo = __builtin_popcount(m & 0xffu);
    _mm512_storeu_si512(&r.pair_count[size_t(n)], _mm512_maskz_compress_epi64(__mmask8(m), counter[0]));
    _mm512_storeu_si512(&r.pair_count[size_t(n + n_lo)], _mm512_maskz_compress_epi64(__mmask8(m >> 8), counter[1]));
    n += __builtin_popcount(m);
  }
  return n;
}

DHR_AVX512_TARGET int list_pairs_x16(VisibilityRow& r, int nl, uint16_t* counts, size_t npx, PairTally& tally) {
  static_assert(kListPairsVectorLights == 4);
  const int w = r.w;
  int n = 0;
  __mmask16 traced[kListPairsMaxLights];
  int active[kListPairsMaxLights];
  for (int x = 0; x < w; x += 16) {
    const __mmask16 live = lanes_below(w - x);
    // Bytes past the row (and past the last light's row) are padding: read, never used.
    const __m128i covered = _mm_loadu_si128(reinterpret_cast<const __m128i*>(&r.covered[size_t(x)]));
    const __mmask16 cov = live & __mmask16(~_mm_movemask_epi8(_mm_cmpeq_epi8(covered, _mm_setzero_si128())));
    if (!cov) continue;
    const __mmask16 any = classify_pairs_x16(r, nl, x, cov, counts, npx, tally, traced);
    if (!any) continue;
    int na = 0;  // the lights with a traced lane in this block
    for (int l = 0; l < nl; ++l)
      if (traced[l]) active[na++] = l;
    switch (na) {
      case 1: n = list_block_x16<1>(r, x, active, traced, counts, npx, n); continue;
      case 2: n = list_block_x16<2>(r, x, active, traced, counts, npx, n); continue;
      case 3: n = list_block_x16<3>(r, x, active, traced, counts, npx, n); continue;
      case 4: n = list_block_x16<4>(r, x, active, traced, counts, npx, n); continue;
      default: break;
    }
    for (unsigned m = any; m; m &= m - 1) {  // more lights: pair by pair
      const int k = __builtin_ctz(m);
      const size_t px = size_t(x + k);
      for (int a = 0; a < na; ++a) {
        const int l = active[a];
        if ((traced[l] >> k) & 1u) list_pair(r, n++, px, size_t(l) * size_t(w) + px, counts + size_t(l) * npx + px);
      }
    }
  }
  return n;
}

DHR_AVX512_TARGET void distant_light_row_x16(VisibilityRow& r, const LightInfo& li, size_t base) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  const int w = r.w;
  const __m512 lt[3] = {_mm512_set1_ps(li.t.x), _mm512_set1_ps(li.t.y), _mm512_set1_ps(li.t.z)};
  const __m512 lb[3] = {_mm512_set1_ps(li.b.x), _mm512_set1_ps(li.b.y), _mm512_set1_ps(li.b.z)};
  const __m512 ld[3] = {_mm512_set1_ps(li.dir.x), _mm512_set1_ps(li.dir.y), _mm512_set1_ps(li.dir.z)};
  const __m512 facing_at = _mm512_set1_ps(li.soft ? -li.sin_alpha : 0.0f);
  const __m512 inf = _mm512_set1_ps(kInf);
  for (int x = 0; x < w; x += 16) {
    const int n = std::min(16, w - x);
    const __mmask16 live = __mmask16((1u << n) - 1u);
    const size_t i = base + size_t(x);
    const __m512 n_dot = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(_mm512_loadu_ps(&r.nx[size_t(x)]), ld[0]),
                                                     _mm512_mul_ps(_mm512_loadu_ps(&r.ny[size_t(x)]), ld[1])),
                                       _mm512_mul_ps(_mm512_loadu_ps(&r.nz[size_t(x)]), ld[2]));
    const __mmask16 facing = _mm512_cmp_ps_mask(n_dot, facing_at, _CMP_LE_OQ);
    alignas(16) uint8_t bytes[16];
    _mm_store_si128(reinterpret_cast<__m128i*>(bytes),
                    _mm512_cvtepi32_epi8(_mm512_maskz_mov_epi32(facing, _mm512_set1_epi32(kPairFacing))));
    std::copy(bytes, bytes + n, &r.code[i]);
    __m512 dir[3] = {ld[0], ld[1], ld[2]};
    if (li.soft)
      cone_x16(lt, lb, ld, _mm512_set1_ps(li.one_minus_cos), _mm512_loadu_ps(&r.u0[size_t(x)]),
               _mm512_loadu_ps(&r.u1[size_t(x)]), dir);
    _mm512_mask_storeu_ps(&r.dx[i], live, dir[0]);
    _mm512_mask_storeu_ps(&r.dy[i], live, dir[1]);
    _mm512_mask_storeu_ps(&r.dz[i], live, dir[2]);
    _mm512_mask_storeu_ps(&r.tfar[i], live, inf);
    const __mmask16 ok = rays_valid_x16(dir, inf, &r.origin_ok[size_t(x)]);
    _mm_store_si128(reinterpret_cast<__m128i*>(bytes),
                    _mm512_cvtepi32_epi8(_mm512_maskz_mov_epi32(ok, _mm512_set1_epi32(1))));
    std::copy(bytes, bytes + n, &r.ok[i]);
  }
}

// soft_pair_rays_x8 (core/trace/trace_avx2.cpp) in 16 lanes: the S rays of one (pixel, light) pair of
// a soft light with S > 1, 16 samples per packet of their own (a pixel's samples share the
// origin and point the same way: coherent packets). The hashes, uniforms, directions, tfar and
// validity are the cone loop's operations in the same order (same rays); an invalid ray counts
// as unoccluded without a trace; with batch.record the valid rays are kept in sample order.
DHR_AVX512_TARGET void soft_pair_rays_x16(const SoftPair& p, Batch<16>& batch, uint64_t& invalid) {
  const __m512i stream = _mm512_set1_epi64(int64_t(p.stream));
  const __m512i dim1 = _mm512_set1_epi64(1);
  const __m512i h = _mm512_set1_epi64(int64_t(p.h));
  const __m512i iota_lo = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
  const __m512i iota_hi = _mm512_setr_epi64(8, 9, 10, 11, 12, 13, 14, 15);
  const __m512i iota32 = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512 t[3] = {_mm512_set1_ps(p.t.x), _mm512_set1_ps(p.t.y), _mm512_set1_ps(p.t.z)};
  const __m512 b[3] = {_mm512_set1_ps(p.b.x), _mm512_set1_ps(p.b.y), _mm512_set1_ps(p.b.z)};
  const __m512 w[3] = {_mm512_set1_ps(p.w.x), _mm512_set1_ps(p.w.y), _mm512_set1_ps(p.w.z)};
  const __m512 oc[3] = {_mm512_set1_ps(p.oc.x), _mm512_set1_ps(p.oc.y), _mm512_set1_ps(p.oc.z)};
  const __m512 omc_max = _mm512_set1_ps(p.omc_max), r2 = _mm512_set1_ps(p.r2);
  const __m512 inf = _mm512_set1_ps(std::numeric_limits<float>::infinity());
  alignas(64) RTCRay16 pk;
  alignas(64) int valid[16];
  _mm512_store_ps(pk.org_x, _mm512_set1_ps(p.origin.x));
  _mm512_store_ps(pk.org_y, _mm512_set1_ps(p.origin.y));
  _mm512_store_ps(pk.org_z, _mm512_set1_ps(p.origin.z));
  _mm512_store_ps(pk.tnear, _mm512_setzero_ps());
  _mm512_store_ps(pk.time, _mm512_setzero_ps());
  for (int l = 0; l < 16; ++l) {
    pk.mask[l] = batch.mask;
    pk.id[l] = unsigned(l);
    pk.flags[l] = 0;
  }
  for (int k0 = 0; k0 < p.samples; k0 += 16) {
    const int live = std::min(16, p.samples - k0);
    __m512 u0, u1;
    if (p.lattice) {
      const __m512i samples = _mm512_add_epi32(_mm512_set1_epi32(k0), iota32);
      u0 = lattice_x16(samples, kLatticeA0, _mm512_set1_epi32(int32_t(p.shift0)));
      u1 = lattice_x16(samples, kLatticeA1, _mm512_set1_epi32(int32_t(p.shift1)));
    } else {
      // key = (sample << 32) | stream, as PixelRng::uniform2
      const __m512i first = _mm512_set1_epi64(int64_t(k0));
      const __m512i key_lo = _mm512_or_si512(_mm512_slli_epi64(_mm512_add_epi64(first, iota_lo), 32), stream);
      const __m512i key_hi = _mm512_or_si512(_mm512_slli_epi64(_mm512_add_epi64(first, iota_hi), 32), stream);
      const __m512i k_lo = mix64_x8(_mm512_xor_si512(h, key_lo)), k_hi = mix64_x8(_mm512_xor_si512(h, key_hi));
      u0 = uniform_x16(mix64_x8(k_lo), mix64_x8(k_hi));
      u1 = uniform_x16(mix64_x8(_mm512_xor_si512(k_lo, dim1)), mix64_x8(_mm512_xor_si512(k_hi, dim1)));
    }
    __m512 d[3];
    cone_x16(t, b, w, omc_max, u0, u1, d);
    const __m512 tfar = p.sphere ? sphere_tfar_x16(d, oc, r2) : inf;
    const __mmask16 live_mask = __mmask16((1u << live) - 1u);
    const __mmask16 ok = p.origin_ok ? __mmask16(directions_valid_x16(d, tfar) & live_mask) : __mmask16(0);
    const int n_invalid = live - popcount16(ok);
    invalid += uint64_t(n_invalid);
    *p.count = uint16_t(*p.count + n_invalid);
    if (ok == 0) continue;
    if (batch.record) {
      alignas(64) float dx[16], dy[16], dz[16], tf[16];
      _mm512_store_ps(dx, d[0]);
      _mm512_store_ps(dy, d[1]);
      _mm512_store_ps(dz, d[2]);
      _mm512_store_ps(tf, tfar);
      for (int l = 0; l < live; ++l)
        if (ok >> l & 1u) batch.push(p.origin, dx[l], dy[l], dz[l], tf[l], nullptr);
      continue;
    }
    // Lanes that do not trace get a harmless ray (Embree validates every lane's values).
    _mm512_store_ps(pk.dir_x, _mm512_mask_blend_ps(ok, _mm512_set1_ps(1.0f), d[0]));
    _mm512_store_ps(pk.dir_y, _mm512_maskz_mov_ps(ok, d[1]));
    _mm512_store_ps(pk.dir_z, _mm512_maskz_mov_ps(ok, d[2]));
    _mm512_store_ps(pk.tfar, _mm512_maskz_mov_ps(ok, tfar));
    _mm512_store_si512(valid, _mm512_maskz_mov_epi32(ok, _mm512_set1_epi32(-1)));
    rtcOccluded16(valid, batch.scene, &batch.ctx, &pk);
    // Embree sets tfar = -inf on an occluded ray; anything else reached (as Batch::flush).
    const uint32_t reached = _mm512_cmp_ps_mask(_mm512_load_ps(pk.tfar), _mm512_setzero_ps(), _CMP_NLT_UQ) & ok;
    *p.count = uint16_t(*p.count + popcount16(reached));
    batch.traced += uint64_t(popcount16(ok));
  }
}

DHR_AVX512_TARGET void trace_pairs_x16(const VisibilityRow& r, int n, Batch<16>& batch) {
  auto& pk = batch.packet;
  alignas(64) int valid[16];
  const __m512 zero = _mm512_setzero_ps();
  for (int k0 = 0; k0 < n; k0 += 16) {
    const int live = std::min(16, n - k0);
    const __mmask16 lm = __mmask16((1u << live) - 1u);
    float* const to[7] = {pk.org_x, pk.org_y, pk.org_z, pk.dir_x, pk.dir_y, pk.dir_z, pk.tfar};
    for (int c = 0; c < 7; ++c) _mm512_store_ps(to[c], _mm512_maskz_loadu_ps(lm, r.pair_ray[c].data() + k0));
    if (batch.record) {  // collect_visibility_rays: push() keeps the rays, traces nothing
      for (int l = 0; l < live; ++l)
        batch.push(glm::vec3(pk.org_x[l], pk.org_y[l], pk.org_z[l]), pk.dir_x[l], pk.dir_y[l], pk.dir_z[l], pk.tfar[l],
                   nullptr);
      continue;
    }
    _mm512_store_si512(valid, _mm512_maskz_mov_epi32(lm, _mm512_set1_epi32(-1)));
    rtcOccluded16(valid, batch.scene, &batch.ctx, &pk);
    // Embree sets tfar = -inf on an occluded ray; anything else reached (as Batch::flush).
    uint32_t reached = _mm512_cmp_ps_mask(_mm512_load_ps(pk.tfar), zero, _CMP_NLT_UQ) & lm;
    while (reached != 0) {
      uint16_t* count = r.pair_count[size_t(k0 + __builtin_ctz(reached))];
      *count = uint16_t(*count + 1);
      reached &= reached - 1u;
    }
    batch.traced += uint64_t(live);
  }
}

}  // namespace dhr::trace_detail
#endif  // DHR_TRACE_X86_KERNELS
