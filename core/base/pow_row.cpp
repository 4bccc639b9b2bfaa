// std::pow over arrays with the C library's bits (core/base/pow_row.h has the argument).
#include "core/base/pow_row.h"

#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <limits>

#include "core/base/avx512.h"

namespace dhr {
namespace {

std::atomic<bool> g_portable_only{false};
std::atomic<uint64_t> g_lanes{0}, g_fallbacks{0};

// One element by std::pow, its two exact cases that FLIP's rows hold in numbers taken without
// the call: x^1 = x (libm's error bound puts its result within half an ulp of x) and +0 to a
// positive power is +0 (PowRow.* and Flip.PowfExactCasesAsSkipped check both against std::pow).
inline float pow_one(float x, float y) {
  if (y == 1.0f && x >= 0.0f && x <= std::numeric_limits<float>::max()) return x;
  if (std::bit_cast<uint32_t>(x) == 0 && y > 0.0f) return 0.0f;
  return std::pow(x, y);
}

#if DHR_AVX512_KERNELS

// 1/k!, k = 0..11: e^g's Taylor coefficients.
constexpr std::array<double, 12> kInvFactorial = [] {
  std::array<double, 12> f{};
  f[0] = 1.0;
  for (int k = 1; k < 12; ++k) f[size_t(k)] = f[size_t(k) - 1] / k;
  return f;
}();

// x^y of 8 lanes in double, and the lanes whose float rounding is certain to be libm's.
//
// log2 x = e + log2 m with x = 2^e m, m in [0.75, 1.5); log2 m = (2 / ln 2) atanh(s) with
// s = (m - 1) / (m + 1), |s| <= 0.2, by its series to s^17 (the next term is under 2^-46 of
// the sum). 2^t = 2^n e^g with n = round(t), g = (t - n) ln 2, |g| <= 0.347, by Taylor to g^11
// (the next term is under 2^-47). With the roundings of s, the sums and the products, the
// result's relative error stays under 2^-46 (1 + |t|), far below the 2^-33 the check below
// allows for the library. (Higher degrees cost time and change no output: a lane's value is
// either certain to round as the library's or replaced by it.)
DHR_AVX512_TARGET inline __m512d pow8(__m512d x, __m512d y, __mmask8 ok, __mmask8& certain) {
  const __m512d one = _mm512_set1_pd(1.0);
  const __m512d m = _mm512_getmant_pd(x, _MM_MANT_NORM_p75_1p5, _MM_MANT_SIGN_zero);
  __m512d e = _mm512_getexp_pd(x);
  e = _mm512_mask_add_pd(e, _mm512_cmp_pd_mask(m, one, _CMP_LT_OQ), e, one);  // m was halved
  const __m512d s = _mm512_div_pd(_mm512_sub_pd(m, one), _mm512_add_pd(m, one));
  const __m512d z = _mm512_mul_pd(s, s);
  __m512d p = _mm512_set1_pd(1.0 / 17.0);
  for (int k = 15; k >= 3; k -= 2) p = _mm512_fmadd_pd(p, z, _mm512_set1_pd(1.0 / k));
  p = _mm512_fmadd_pd(p, z, one);
  const __m512d log2x = _mm512_fmadd_pd(_mm512_mul_pd(s, p), _mm512_set1_pd(2.0 / 0.69314718055994530942), e);
  const __m512d t = _mm512_mul_pd(y, log2x);

  const __m512d n = _mm512_roundscale_pd(t, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
  const __m512d g = _mm512_mul_pd(_mm512_sub_pd(t, n), _mm512_set1_pd(0.69314718055994530942));
  __m512d q = _mm512_set1_pd(kInvFactorial[11]);
  for (int k = 10; k >= 0; --k) q = _mm512_fmadd_pd(q, g, _mm512_set1_pd(kInvFactorial[size_t(k)]));
  const __m512d r = _mm512_scalef_pd(q, n);

  // Distance from r to the nearest rounding midpoint of float: r's float rf has its midpoints
  // half an ulp above and below, the one below half as far where rf is a power of two (the
  // binade below has half the ulp). r - rf is exact in double.
  const __m512d rf = _mm512_cvtps_pd(_mm512_cvtpd_ps(r));
  const __m512d d = _mm512_sub_pd(r, rf);
  const __m512d half_up = _mm512_scalef_pd(one, _mm512_sub_pd(_mm512_getexp_pd(rf), _mm512_set1_pd(24.0)));
  const __mmask8 power_of_two =
      _mm512_cmp_pd_mask(_mm512_getmant_pd(rf, _MM_MANT_NORM_1_2, _MM_MANT_SIGN_zero), one, _CMP_EQ_OQ);
  const __m512d half_down = _mm512_mask_mul_pd(half_up, power_of_two, half_up, _mm512_set1_pd(0.5));
  const __m512d margin = _mm512_min_pd(_mm512_sub_pd(half_up, d), _mm512_add_pd(half_down, d));
  // Both errors, relative: the library's 1.27 |t| 2^-33 + 1.69 2^-34 doubled, and this
  // kernel's 2^-46 (1 + |t|), rounded up together to (2.6 |t| + 1.7) 2^-33 + 2^-46 (1 + |t|).
  const __m512d abs_mask = _mm512_castsi512_pd(_mm512_set1_epi64(0x7fffffffffffffffLL));
  const __m512d abs_t = _mm512_and_pd(t, abs_mask);
  const __m512d rel =
      _mm512_fmadd_pd(abs_t, _mm512_set1_pd(2.6 * 0x1p-33 + 0x1p-46), _mm512_set1_pd(1.7 * 0x1p-33 + 0x1p-46));
  __mmask8 good = ok & _mm512_cmp_pd_mask(abs_t, _mm512_set1_pd(120.0), _CMP_LT_OQ);
  good &= _mm512_cmp_pd_mask(margin, _mm512_mul_pd(r, rel), _CMP_GT_OQ);
  certain = good;
  return r;
}

// 16 lanes: the fast lanes' results and the mask of those left to std::pow.
DHR_AVX512_TARGET inline __m512 pow16(__m512 xf, __m512 yf, __mmask16& rest) {
  // Positive normal finite x and finite y, or x = +0 with y > 0 (result +0).
  const __mmask16 x_normal = _mm512_cmp_ps_mask(xf, _mm512_set1_ps(0x1p-126f), _CMP_GE_OQ) &
                             _mm512_cmp_ps_mask(xf, _mm512_set1_ps(INFINITY), _CMP_LT_OQ);
  const __m512 abs_y = _mm512_abs_ps(yf);
  const __mmask16 y_finite = _mm512_cmp_ps_mask(abs_y, _mm512_set1_ps(INFINITY), _CMP_LT_OQ);
  const __mmask16 x_pos_zero = _mm512_cmpeq_epi32_mask(_mm512_castps_si512(xf), _mm512_setzero_si512()) &
                               _mm512_cmp_ps_mask(yf, _mm512_setzero_ps(), _CMP_GT_OQ);
  const __mmask16 ok = x_normal & y_finite;
  __mmask8 c_lo, c_hi;
  const __m512d r_lo = pow8(_mm512_cvtps_pd(_mm512_castps512_ps256(xf)), _mm512_cvtps_pd(_mm512_castps512_ps256(yf)),
                            __mmask8(ok), c_lo);
  const __m512d r_hi = pow8(_mm512_cvtps_pd(_mm512_extractf32x8_ps(xf, 1)),
                            _mm512_cvtps_pd(_mm512_extractf32x8_ps(yf, 1)), __mmask8(ok >> 8), c_hi);
  const __m512 r = _mm512_insertf32x8(_mm512_castps256_ps512(_mm512_cvtpd_ps(r_lo)), _mm512_cvtpd_ps(r_hi), 1);
  const __mmask16 fast = __mmask16(c_lo | (unsigned(c_hi) << 8));
  rest = __mmask16(~(fast | x_pos_zero));
  return _mm512_maskz_mov_ps(fast, r);  // +0 in the zero lanes
}

template <bool kScalarY>
DHR_AVX512_TARGET void pow_row16(const float* x, const float* y, float y1, float* out, size_t n) {
  uint64_t fallbacks = 0;
  size_t i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m512 yf = kScalarY ? _mm512_set1_ps(y1) : _mm512_loadu_ps(y + i);
    __mmask16 rest;
    const __m512 r = pow16(_mm512_loadu_ps(x + i), yf, rest);
    if (rest) {
      alignas(64) float buf[16];
      _mm512_store_ps(buf, r);
      fallbacks += unsigned(__builtin_popcount(rest));
      for (unsigned m = rest; m; m &= m - 1) {
        const int l = __builtin_ctz(m);
        buf[l] = pow_one(x[i + size_t(l)], kScalarY ? y1 : y[i + size_t(l)]);
      }
      _mm512_storeu_ps(out + i, _mm512_load_ps(buf));
    } else {
      _mm512_storeu_ps(out + i, r);
    }
  }
  for (; i < n; ++i) out[i] = pow_one(x[i], kScalarY ? y1 : y[i]);
  g_lanes.fetch_add(n, std::memory_order_relaxed);
  g_fallbacks.fetch_add(fallbacks + (n % 16), std::memory_order_relaxed);
}

bool wide() { return cpu_has_avx512dq() && !g_portable_only.load(std::memory_order_relaxed); }

#endif  // DHR_AVX512_KERNELS

}  // namespace

void pow_row(const float* x, const float* y, float* out, size_t n) {
#if DHR_AVX512_KERNELS
  if (wide()) return pow_row16<false>(x, y, 0.0f, out, n);
#endif
  for (size_t i = 0; i < n; ++i) out[i] = pow_one(x[i], y[i]);
}

void pow_row(const float* x, float y, float* out, size_t n) {
#if DHR_AVX512_KERNELS
  if (wide()) return pow_row16<true>(x, nullptr, y, out, n);
#endif
  for (size_t i = 0; i < n; ++i) out[i] = pow_one(x[i], y);
}

PowRowCounts pow_row_counts() {
  return {g_lanes.load(std::memory_order_relaxed), g_fallbacks.load(std::memory_order_relaxed)};
}

void pow_row_portable_only(bool on) { g_portable_only.store(on, std::memory_order_relaxed); }

}  // namespace dhr
