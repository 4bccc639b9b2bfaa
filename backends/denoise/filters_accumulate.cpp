// The temporal accumulation's rows (FilterPipeline::accumulate in filters.cpp, whose
// reproject and finish lambdas say what each step is) with vectors: 16 pixels at a time with
// AVX-512 (accumulate_row16), 8 with AVX2 (accumulate_row8), chosen at run time; the same bits
// as the scalar loop (tests/backends/test_denoisers.cpp, Denoisers.SameBitsWithPortableKernels). The two
// are one algorithm in two instruction sets, step for step.
#include "backends/denoise/filters.h"
#include "backends/denoise/filters_simd.h"

#include <algorithm>
#include <bit>
#include <cstdint>
#if DHR_DENOISE_AVX512
#include <immintrin.h>
#endif

namespace dhr::denoise {
namespace {

#if DHR_DENOISE_AVX512
// Pixels [0, w - w % 16) of row y of FilterPipeline::accumulate (its reprojection and finish,
// which say what each step is), 16 at a time with AVX-512: the same IEEE operations per pixel
// in the same order, so the same bits. A previous tap that the scalar code skips ("continue")
// is left out of the sums by a mask (not adding it is what skipping does); the tests "x > t"
// that skip become "!(x > t)" masks (NaN kept as there); the taps are read by masked gathers
// (no address outside the image is read). xa, xb: the span of pixels that need the spatial variance.
__attribute__((noinline)) DHR_DENOISE_TARGET_AVX512 int accumulate_row16(const AccumulateArgs& a, int y, int& xa,
                                                                         int& xb) {
  using V = __m512;
  using VI = __m512i;
  const int w = a.w;
  const size_t row = size_t(y) * size_t(w);
  const __mmask16 all = 0xffff;
  const V zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.0f);
  const VI lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const VI even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
  const VI odd = _mm512_add_epi32(even, _mm512_set1_epi32(1));
  int x = 0;
  for (; x + 16 <= w; x += 16) {
    const size_t i = row + size_t(x);
    const __mmask16 valid = _mm512_test_epi32_mask(
        _mm512_maskz_cvtepu8_epi32(all, _mm_loadu_si128(reinterpret_cast<const __m128i*>(a.cvalid + i))),
        _mm512_set1_epi32(0xff));
    V len = zero, pval = zero, p1 = zero, p2 = zero, pkk = zero;
    __mmask16 called = a.hist ? valid : __mmask16(0);  // lanes whose reproject runs
    if (called) {
      const float* m = reinterpret_cast<const float*>(a.mo + i);
      const V m_lo = _mm512_loadu_ps(m), m_hi = _mm512_loadu_ps(m + 16);
      const V mx = _mm512_permutex2var_ps(m_lo, even, m_hi), my = _mm512_permutex2var_ps(m_lo, odd, m_hi);
      const VI xi = _mm512_add_epi32(_mm512_set1_epi32(x), lane);
      const V px = _mm512_add_ps(_mm512_maskz_cvtepi32_ps(all, xi), mx);
      const V py = _mm512_add_ps(_mm512_set1_ps(float(y)), my);
      const V m2f = _mm512_set1_ps(-2.0f);
      const __mmask16 inr = called & _mm512_cmp_ps_mask(px, m2f, _CMP_GT_OQ) & _mm512_cmp_ps_mask(py, m2f, _CMP_GT_OQ) &
                            _mm512_cmp_ps_mask(px, _mm512_set1_ps(a.wmax), _CMP_LT_OQ) &
                            _mm512_cmp_ps_mask(py, _mm512_set1_ps(a.hmax), _CMP_LT_OQ);
      const V two = _mm512_set1_ps(2.0f);
      const VI x0 = _mm512_sub_epi32(_mm512_maskz_cvttps_epi32(inr, _mm512_add_ps(px, two)), _mm512_set1_epi32(2));
      const VI y0 = _mm512_sub_epi32(_mm512_maskz_cvttps_epi32(inr, _mm512_add_ps(py, two)), _mm512_set1_epi32(2));
      const V fx = _mm512_sub_ps(px, _mm512_maskz_cvtepi32_ps(all, x0));
      const V fy = _mm512_sub_ps(py, _mm512_maskz_cvtepi32_ps(all, y0));
      const V gx = _mm512_sub_ps(one, fx), gy = _mm512_sub_ps(one, fy);
      const V bw[4] = {_mm512_mul_ps(gx, gy), _mm512_mul_ps(fx, gy), _mm512_mul_ps(gx, fy), _mm512_mul_ps(fx, fy)};
      const VI idc = _mm512_loadu_si512(a.cid + i);
      const V zc = _mm512_loadu_ps(a.cz + i);
      const V ztol = _mm512_mul_ps(_mm512_set1_ps(a.tol), zc);
      const V ncx = _mm512_loadu_ps(a.cnx + i), ncy = _mm512_loadu_ps(a.cny + i), ncz = _mm512_loadu_ps(a.cnz + i);
      const V nthr = _mm512_set1_ps(a.nthr);
      V sw = zero;
      for (int k = 0; k < 4; ++k) {
        const VI xx = _mm512_add_epi32(x0, _mm512_set1_epi32(k & 1));
        const VI yy = _mm512_add_epi32(y0, _mm512_set1_epi32(k >> 1));
        __mmask16 mk =
            inr & _mm512_cmpge_epi32_mask(xx, _mm512_setzero_si512()) &
            _mm512_cmpge_epi32_mask(yy, _mm512_setzero_si512()) & _mm512_cmplt_epi32_mask(xx, _mm512_set1_epi32(w)) &
            _mm512_cmplt_epi32_mask(yy, _mm512_set1_epi32(a.h)) & _mm512_cmp_ps_mask(bw[k], zero, _CMP_NLE_UQ);
        if (!mk) continue;
        const VI j = _mm512_add_epi32(_mm512_mullo_epi32(yy, _mm512_set1_epi32(w)), xx);
        // Where the lanes' taps lie side by side (lane 0's tap j0, lane l's j0 + l: the motion's
        // integer part the same across the 16 pixels, as it mostly is), one masked load reads
        // what the gather would (the same values; masked-off lanes read nothing, zero as there).
        const int j0 = _mm512_cvtsi512_si32(j);
        const bool side_by_side =
            (mk & 1u) && (_mm512_cmpeq_epi32_mask(j, _mm512_add_epi32(_mm512_set1_epi32(j0), lane)) & mk) == mk;
        auto gather = [&](const float* base, __mmask16 mm) {
          return side_by_side ? _mm512_maskz_loadu_ps(mm, base + j0) : _mm512_mask_i32gather_ps(zero, mm, j, base, 4);
        };
        // "pvalid and pid == idc" is "pid == idc" alone: an invalid pixel has id kBackgroundId
        // (0) and a valid one another id (guide_row), and this pixel is valid.
        const VI pid = side_by_side ? _mm512_maskz_loadu_epi32(mk, a.pid + j0)
                                    : _mm512_mask_i32gather_epi32(_mm512_setzero_si512(), mk, j, a.pid, 4);
        mk &= _mm512_cmpeq_epi32_mask(pid, idc);
        const V phj = gather(a.ph, mk);
        mk &= _mm512_cmp_ps_mask(phj, zero, _CMP_NLE_UQ);
        const V pzj = gather(a.pz, mk);
        mk &= _mm512_cmp_ps_mask(_mm512_abs_ps(_mm512_sub_ps(pzj, zc)), ztol, _CMP_NGT_UQ);
        const V d =
            _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(gather(a.pnx, mk), ncx), _mm512_mul_ps(gather(a.pny, mk), ncy)),
                          _mm512_mul_ps(gather(a.pnz, mk), ncz));
        mk &= _mm512_cmp_ps_mask(d, nthr, _CMP_NLT_UQ);
        if (!mk) continue;
        const V b = bw[k];
        sw = _mm512_mask_add_ps(sw, mk, sw, b);
        pval = _mm512_mask_add_ps(pval, mk, pval, _mm512_mul_ps(b, gather(a.pv, mk)));
        p1 = _mm512_mask_add_ps(p1, mk, p1, _mm512_mul_ps(b, gather(a.pm1, mk)));
        p2 = _mm512_mask_add_ps(p2, mk, p2, _mm512_mul_ps(b, gather(a.pm2, mk)));
        len = _mm512_mask_add_ps(len, mk, len, _mm512_mul_ps(b, phj));
        pkk = _mm512_mask_add_ps(pkk, mk, pkk, _mm512_mul_ps(b, gather(a.pk, mk)));
      }
      // sw >= 0.01: renormalise; else (and where the pixel was out of range) no history.
      const __mmask16 ok = inr & _mm512_cmp_ps_mask(sw, _mm512_set1_ps(0.01f), _CMP_GE_OQ);
      const V inv = _mm512_div_ps(one, sw);
      pval = _mm512_mask_mul_ps(pval, ok, pval, inv);
      p1 = _mm512_mask_mul_ps(p1, ok, p1, inv);
      p2 = _mm512_mask_mul_ps(p2, ok, p2, inv);
      len = _mm512_maskz_mul_ps(ok, len, inv);
      pkk = _mm512_mask_mul_ps(pkk, ok, pkk, inv);
    }
    // finish
    const VI ivi = _mm512_maskz_min_epi32(
        all, _mm512_maskz_cvtepu8_epi32(all, _mm_loadu_si128(reinterpret_cast<const __m128i*>(a.noisy + i))),
        _mm512_set1_epi32(a.fs));  // src > fs ? fs : src
    const V c = _mm512_mul_ps(_mm512_maskz_cvtepi32_ps(all, ivi), _mm512_set1_ps(a.inv_fs));
    const __mmask16 has = _mm512_cmp_ps_mask(len, zero, _CMP_GT_OQ);
    V lh = _mm512_add_ps(len, one);
    const V capv = _mm512_set1_ps(a.cap);
    lh = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(capv, lh, _CMP_LT_OQ), lh, capv);  // std::min(len + 1, cap)
    const V rl = _mm512_div_ps(one, lh), alv = _mm512_set1_ps(a.alpha);
    const V al = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(alv, rl, _CMP_LT_OQ), alv, rl);  // std::max(alpha, 1 / len)
    const V cc = _mm512_mul_ps(c, c);
    const V om = _mm512_sub_ps(one, al);
    V v = _mm512_add_ps(pval, _mm512_mul_ps(al, _mm512_sub_ps(c, pval)));
    V m1 = _mm512_add_ps(p1, _mm512_mul_ps(al, _mm512_sub_ps(c, p1)));
    V m2 = _mm512_add_ps(p2, _mm512_mul_ps(al, _mm512_sub_ps(cc, p2)));
    V kk = _mm512_add_ps(_mm512_mul_ps(_mm512_mul_ps(om, om), pkk), _mm512_mul_ps(al, al));
    const V len_new = _mm512_mask_blend_ps(has, _mm512_mask_blend_ps(valid, zero, one), lh);
    v = _mm512_mask_blend_ps(has, c, v);
    m1 = _mm512_mask_blend_ps(has, c, m1);
    m2 = _mm512_mask_blend_ps(has, cc, m2);
    kk = _mm512_mask_blend_ps(has, one, kk);
    _mm512_storeu_ps(a.nv + i, v);
    _mm512_storeu_ps(a.nm1 + i, m1);
    _mm512_storeu_ps(a.nm2 + i, m2);
    _mm512_storeu_ps(a.nk + i, kk);
    _mm512_storeu_ps(a.nh + i, len_new);
    if (a.spatial) {
      const V dm = _mm512_sub_ps(m2, _mm512_mul_ps(m1, m1));
      const V mx0 = _mm512_maskz_mov_ps(_mm512_cmp_ps_mask(zero, dm, _CMP_LT_OQ), dm);  // std::max(0, dm)
      _mm512_storeu_ps(a.var + i, _mm512_maskz_mul_ps(valid, mx0, kk));
      const __mmask16 young = valid & _mm512_cmp_ps_mask(len_new, _mm512_set1_ps(a.min_h), _CMP_LT_OQ);
      if (young) {
        xa = std::min(xa, x + int(std::countr_zero(unsigned(young))));
        xb = x + 31 - int(std::countl_zero(unsigned(young)));
      }
      if (a.lt) {
        const __mmask16 lc = valid & _mm512_cmp_ps_mask(len_new, _mm512_set1_ps(a.light_h), _CMP_LT_OQ);
        _mm_storeu_si128(reinterpret_cast<__m128i*>(a.cls + i),
                         _mm512_maskz_cvtepi32_epi8(all, _mm512_maskz_mov_epi32(lc, _mm512_set1_epi32(1))));
      }
    } else {  // to_u8 (filters.h)
      V f = _mm512_add_ps(_mm512_mul_ps(v, _mm512_set1_ps(255.0f)), _mm512_set1_ps(0.5f));
      f = _mm512_maskz_mov_ps(_mm512_cmp_ps_mask(f, zero, _CMP_GE_OQ), f);
      const V f255 = _mm512_set1_ps(255.0f);
      f = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(f, f255, _CMP_LE_OQ), f255, f);
      _mm_storeu_si128(reinterpret_cast<__m128i*>(a.out + i),
                       _mm512_maskz_cvtepi32_epi8(all, _mm512_maskz_cvttps_epi32(all, f)));
    }
  }
  return x;
}

// accumulate_row8's helpers (lambdas would not take the function's target).
DHR_ALWAYS_INLINE DHR_DENOISE_TARGET_AVX2 __m256i bytes8(const uint8_t* p) {  // 8 bytes to 8 int32 lanes
  return _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p)));
}
DHR_ALWAYS_INLINE DHR_DENOISE_TARGET_AVX2 void store_bytes8(uint8_t* p, __m256i v) {  // lanes in 0..255 to bytes
  const __m128i w16 = _mm_packus_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
  _mm_storel_epi64(reinterpret_cast<__m128i*>(p), _mm_packus_epi16(w16, w16));
}
DHR_ALWAYS_INLINE DHR_DENOISE_TARGET_AVX2 __m256 blend(__m256 if_clear, __m256 if_set, __m256 m) {
  return _mm256_blendv_ps(if_clear, if_set, m);
}
DHR_ALWAYS_INLINE DHR_DENOISE_TARGET_AVX2 __m256 gather8(const float* base, __m256i j, __m256 m) {
  return _mm256_mask_i32gather_ps(_mm256_setzero_ps(), base, j, m, 4);
}
// gather8, or one masked load where the lanes' taps lie side by side (see accumulate_row16).
DHR_ALWAYS_INLINE DHR_DENOISE_TARGET_AVX2 __m256 taps8(const float* base, __m256i j, int j0, bool side_by_side,
                                                       __m256 m) {
  return side_by_side ? _mm256_maskload_ps(base + j0, _mm256_castps_si256(m)) : gather8(base, j, m);
}

// The same rows 8 pixels at a time with AVX2, for CPUs without AVX-512 (accumulate_row16's
// twin, step for step): the masks are vectors of all-ones lanes, a masked add is a blend of
// the sum, the gathers take the same masks (a lane left out reads nothing).
__attribute__((noinline)) DHR_DENOISE_TARGET_AVX2 int accumulate_row8(const AccumulateArgs& a, int y, int& xa,
                                                                      int& xb) {
  using V = __m256;
  using VI = __m256i;
  const int w = a.w;
  const size_t row = size_t(y) * size_t(w);
  const V zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f);
  const VI izero = _mm256_setzero_si256();
  const VI lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  int x = 0;
  for (; x + 8 <= w; x += 8) {
    const size_t i = row + size_t(x);
    const V valid =
        _mm256_castsi256_ps(_mm256_xor_si256(_mm256_cmpeq_epi32(bytes8(a.cvalid + i), izero), _mm256_set1_epi32(-1)));
    V len = zero, pval = zero, p1 = zero, p2 = zero, pkk = zero;
    const V called = a.hist ? valid : zero;  // lanes whose reproject runs
    if (_mm256_movemask_ps(called)) {
      const float* m = reinterpret_cast<const float*>(a.mo + i);
      const V m_lo = _mm256_loadu_ps(m), m_hi = _mm256_loadu_ps(m + 8);
      const V mx = _mm256_castpd_ps(
          _mm256_permute4x64_pd(_mm256_castps_pd(_mm256_shuffle_ps(m_lo, m_hi, _MM_SHUFFLE(2, 0, 2, 0))), 0xd8));
      const V my = _mm256_castpd_ps(
          _mm256_permute4x64_pd(_mm256_castps_pd(_mm256_shuffle_ps(m_lo, m_hi, _MM_SHUFFLE(3, 1, 3, 1))), 0xd8));
      const VI xi = _mm256_add_epi32(_mm256_set1_epi32(x), lane);
      const V px = _mm256_add_ps(_mm256_cvtepi32_ps(xi), mx);
      const V py = _mm256_add_ps(_mm256_set1_ps(float(y)), my);
      const V m2f = _mm256_set1_ps(-2.0f);
      const V inr = _mm256_and_ps(
          _mm256_and_ps(_mm256_and_ps(called, _mm256_cmp_ps(px, m2f, _CMP_GT_OQ)), _mm256_cmp_ps(py, m2f, _CMP_GT_OQ)),
          _mm256_and_ps(_mm256_cmp_ps(px, _mm256_set1_ps(a.wmax), _CMP_LT_OQ),
                        _mm256_cmp_ps(py, _mm256_set1_ps(a.hmax), _CMP_LT_OQ)));
      const VI inr_i = _mm256_castps_si256(inr);
      const V two = _mm256_set1_ps(2.0f);
      const VI x0 =
          _mm256_and_si256(inr_i, _mm256_sub_epi32(_mm256_cvttps_epi32(_mm256_add_ps(px, two)), _mm256_set1_epi32(2)));
      const VI y0 =
          _mm256_and_si256(inr_i, _mm256_sub_epi32(_mm256_cvttps_epi32(_mm256_add_ps(py, two)), _mm256_set1_epi32(2)));
      const V fx = _mm256_sub_ps(px, _mm256_cvtepi32_ps(x0));
      const V fy = _mm256_sub_ps(py, _mm256_cvtepi32_ps(y0));
      const V gx = _mm256_sub_ps(one, fx), gy = _mm256_sub_ps(one, fy);
      const V bw[4] = {_mm256_mul_ps(gx, gy), _mm256_mul_ps(fx, gy), _mm256_mul_ps(gx, fy), _mm256_mul_ps(fx, fy)};
      const VI idc = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(a.cid + i));
      const V zc = _mm256_loadu_ps(a.cz + i);
      const V ztol = _mm256_mul_ps(_mm256_set1_ps(a.tol), zc);
      const V ncx = _mm256_loadu_ps(a.cnx + i), ncy = _mm256_loadu_ps(a.cny + i), ncz = _mm256_loadu_ps(a.cnz + i);
      const V nthr = _mm256_set1_ps(a.nthr);
      const V abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
      V sw = zero;
      for (int k = 0; k < 4; ++k) {
        const VI xx = _mm256_add_epi32(x0, _mm256_set1_epi32(k & 1));
        const VI yy = _mm256_add_epi32(y0, _mm256_set1_epi32(k >> 1));
        const VI in_image = _mm256_and_si256(_mm256_and_si256(_mm256_cmpgt_epi32(xx, _mm256_set1_epi32(-1)),
                                                              _mm256_cmpgt_epi32(yy, _mm256_set1_epi32(-1))),
                                             _mm256_and_si256(_mm256_cmpgt_epi32(_mm256_set1_epi32(w), xx),
                                                              _mm256_cmpgt_epi32(_mm256_set1_epi32(a.h), yy)));
        V mk =
            _mm256_and_ps(_mm256_and_ps(inr, _mm256_castsi256_ps(in_image)), _mm256_cmp_ps(bw[k], zero, _CMP_NLE_UQ));
        if (!_mm256_movemask_ps(mk)) continue;
        const VI j = _mm256_add_epi32(_mm256_mullo_epi32(yy, _mm256_set1_epi32(w)), xx);
        // Taps side by side: masked loads instead of gathers (accumulate_row16).
        const int j0 = _mm256_cvtsi256_si32(j);
        const int mk_bits = _mm256_movemask_ps(mk);
        const bool side =
            (mk_bits & 1) &&
            (_mm256_movemask_ps(_mm256_and_ps(mk, _mm256_castsi256_ps(_mm256_cmpeq_epi32(
                                                      j, _mm256_add_epi32(_mm256_set1_epi32(j0), lane))))) == mk_bits);
        // "pvalid and pid == idc" is "pid == idc" alone (accumulate_row16).
        const VI pidj = side ? _mm256_maskload_epi32(reinterpret_cast<const int*>(a.pid) + j0, _mm256_castps_si256(mk))
                             : _mm256_mask_i32gather_epi32(izero, reinterpret_cast<const int*>(a.pid), j,
                                                           _mm256_castps_si256(mk), 4);
        mk = _mm256_and_ps(mk, _mm256_castsi256_ps(_mm256_cmpeq_epi32(pidj, idc)));
        const V phj = taps8(a.ph, j, j0, side, mk);
        mk = _mm256_and_ps(mk, _mm256_cmp_ps(phj, zero, _CMP_NLE_UQ));
        const V pzj = taps8(a.pz, j, j0, side, mk);
        mk = _mm256_and_ps(mk, _mm256_cmp_ps(_mm256_and_ps(_mm256_sub_ps(pzj, zc), abs_mask), ztol, _CMP_NGT_UQ));
        const V d = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(taps8(a.pnx, j, j0, side, mk), ncx),
                                                _mm256_mul_ps(taps8(a.pny, j, j0, side, mk), ncy)),
                                  _mm256_mul_ps(taps8(a.pnz, j, j0, side, mk), ncz));
        mk = _mm256_and_ps(mk, _mm256_cmp_ps(d, nthr, _CMP_NLT_UQ));
        if (!_mm256_movemask_ps(mk)) continue;
        const V b = bw[k];
        sw = blend(sw, _mm256_add_ps(sw, b), mk);
        pval = blend(pval, _mm256_add_ps(pval, _mm256_mul_ps(b, taps8(a.pv, j, j0, side, mk))), mk);
        p1 = blend(p1, _mm256_add_ps(p1, _mm256_mul_ps(b, taps8(a.pm1, j, j0, side, mk))), mk);
        p2 = blend(p2, _mm256_add_ps(p2, _mm256_mul_ps(b, taps8(a.pm2, j, j0, side, mk))), mk);
        len = blend(len, _mm256_add_ps(len, _mm256_mul_ps(b, phj)), mk);
        pkk = blend(pkk, _mm256_add_ps(pkk, _mm256_mul_ps(b, taps8(a.pk, j, j0, side, mk))), mk);
      }
      // sw >= 0.01: renormalise; else (and where the pixel was out of range) no history.
      const V ok = _mm256_and_ps(inr, _mm256_cmp_ps(sw, _mm256_set1_ps(0.01f), _CMP_GE_OQ));
      const V inv = _mm256_div_ps(one, sw);
      pval = blend(pval, _mm256_mul_ps(pval, inv), ok);
      p1 = blend(p1, _mm256_mul_ps(p1, inv), ok);
      p2 = blend(p2, _mm256_mul_ps(p2, inv), ok);
      len = _mm256_and_ps(ok, _mm256_mul_ps(len, inv));
      pkk = blend(pkk, _mm256_mul_ps(pkk, inv), ok);
    }
    // finish
    const VI ivi = _mm256_min_epi32(bytes8(a.noisy + i), _mm256_set1_epi32(a.fs));  // src > fs ? fs : src
    const V c = _mm256_mul_ps(_mm256_cvtepi32_ps(ivi), _mm256_set1_ps(a.inv_fs));
    const V has = _mm256_cmp_ps(len, zero, _CMP_GT_OQ);
    V lh = _mm256_add_ps(len, one);
    const V capv = _mm256_set1_ps(a.cap);
    lh = blend(lh, capv, _mm256_cmp_ps(capv, lh, _CMP_LT_OQ));  // std::min(len + 1, cap)
    const V rl = _mm256_div_ps(one, lh), alv = _mm256_set1_ps(a.alpha);
    const V al = blend(alv, rl, _mm256_cmp_ps(alv, rl, _CMP_LT_OQ));  // std::max(alpha, 1 / len)
    const V cc = _mm256_mul_ps(c, c);
    const V om = _mm256_sub_ps(one, al);
    V v = _mm256_add_ps(pval, _mm256_mul_ps(al, _mm256_sub_ps(c, pval)));
    V m1 = _mm256_add_ps(p1, _mm256_mul_ps(al, _mm256_sub_ps(c, p1)));
    V m2 = _mm256_add_ps(p2, _mm256_mul_ps(al, _mm256_sub_ps(cc, p2)));
    V kk = _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(om, om), pkk), _mm256_mul_ps(al, al));
    const V len_new = blend(_mm256_and_ps(valid, one), lh, has);
    v = blend(c, v, has);
    m1 = blend(c, m1, has);
    m2 = blend(cc, m2, has);
    kk = blend(one, kk, has);
    _mm256_storeu_ps(a.nv + i, v);
    _mm256_storeu_ps(a.nm1 + i, m1);
    _mm256_storeu_ps(a.nm2 + i, m2);
    _mm256_storeu_ps(a.nk + i, kk);
    _mm256_storeu_ps(a.nh + i, len_new);
    if (a.spatial) {
      const V dm = _mm256_sub_ps(m2, _mm256_mul_ps(m1, m1));
      const V mx0 = _mm256_and_ps(_mm256_cmp_ps(zero, dm, _CMP_LT_OQ), dm);  // std::max(0, dm)
      _mm256_storeu_ps(a.var + i, _mm256_and_ps(valid, _mm256_mul_ps(mx0, kk)));
      const unsigned young = unsigned(
          _mm256_movemask_ps(_mm256_and_ps(valid, _mm256_cmp_ps(len_new, _mm256_set1_ps(a.min_h), _CMP_LT_OQ))));
      if (young) {
        xa = std::min(xa, x + int(std::countr_zero(young)));
        xb = x + 31 - int(std::countl_zero(young));
      }
      if (a.lt) {
        const V lc = _mm256_and_ps(valid, _mm256_cmp_ps(len_new, _mm256_set1_ps(a.light_h), _CMP_LT_OQ));
        store_bytes8(a.cls + i, _mm256_and_si256(_mm256_castps_si256(lc), _mm256_set1_epi32(1)));
      }
    } else {  // to_u8 (filters.h)
      V f = _mm256_add_ps(_mm256_mul_ps(v, _mm256_set1_ps(255.0f)), _mm256_set1_ps(0.5f));
      f = _mm256_and_ps(_mm256_cmp_ps(f, zero, _CMP_GE_OQ), f);
      const V f255 = _mm256_set1_ps(255.0f);
      f = blend(f255, f, _mm256_cmp_ps(f, f255, _CMP_LE_OQ));
      store_bytes8(a.out + i, _mm256_cvttps_epi32(f));
    }
  }
  return x;
}
#endif

}  // namespace

int accumulate_row_vector(const AccumulateArgs& a, int y, int& xa, int& xb) {
#if DHR_DENOISE_AVX512
  if (cpu_has_avx512()) return accumulate_row16(a, y, xa, xb);
  if (cpu_has_avx2()) return accumulate_row8(a, y, xa, xb);
#else
  (void)a, (void)y, (void)xa, (void)xb;
#endif
  return 0;
}

}  // namespace dhr::denoise
