// The lane types and the bit-exact vector maths shared by filters.cpp, filters_kernels.cpp and
// filters_accumulate.cpp (the SVGF-family filter, see filters.h). Included by those files only.
//
// Every pass is a parallel loop over rows whose rows are computed independently (no
// reductions across threads), so results are bit-identical for any thread count. The hot loops
// (a-trous taps, spatial moments, variance prefilter, guide) are explicit 8-wide vectors with
// scalar tails doing the same operations, cloned for AVX2 and the baseline (same bits on both);
// exp and 1/sqrt are the polynomial / Newton versions in this file and filters_kernels.cpp,
// identical on every machine; invalid neighbours are removed by their zero normal (weight
// exactly 0) rather than by a test.
#pragma once

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace dhr::denoise {

// The hot loops are written once over a "lane" type: ScalarLane (float) or VectorLane
// (VecF, 8 floats, GCC/Clang vector extensions). Explicit vectors because the compiler will
// not if-convert the clamps below under the default -ftrapping-math, so the loops would stay
// scalar. Lane for lane the operations are those of the scalar version (no FMA on either
// target), so a pixel gets the same bits whether it falls in a vector block or in a scalar
// tail, and whichever instruction set the kernel is cloned for (DHR_DENOISE_TARGETS: AVX2 where
// the CPU has it, else the baseline; same results).
// -Wpsabi off for the rest of the including file (only the filters*.cpp files):
// the 32-byte vectors only reach always-inlined helpers, so no call ever passes one, but GCC
// reports it at the end of the translation unit, after any diagnostic pop.
#pragma GCC diagnostic ignored "-Wpsabi"

#define DHR_ALWAYS_INLINE __attribute__((always_inline)) inline
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__AVX2__) && \
    !defined(__SANITIZE_ADDRESS__)
#define DHR_DENOISE_TARGETS __attribute__((target_clones("avx2", "default")))
// The a-trous rows and spatial moments also have a 16-wide AVX-512 version, chosen at run time
// (atrous_rows, moment_span).
// AVX-512F brings its own FMA instructions, which GCC contracts a * b + c into by default: its
// -ffp-contract=fast is the default for C++ even under -std=c++20 (the ISO-mode "off" applies
// to C only; checked with GCC 12). fp-contract=off keeps every product and sum rounded
// separately, so the 16-wide kernel gives the bits of the 8-wide and scalar ones. The AVX2 and
// baseline targets have no FMA instructions, so nothing can be contracted there.
#define DHR_DENOISE_AVX512 1
#define DHR_DENOISE_TARGET_AVX512 __attribute__((target("avx512f"), optimize("fp-contract=off")))
// The a-trous interior's unrolled 8-lane kernel for AVX2 CPUs (atrous_rows); AVX2 alone brings no
// FMA instructions, so nothing is contracted.
#define DHR_DENOISE_TARGET_AVX2 __attribute__((target("avx2")))
// The fast weights' rows (AtrousArgs::fast_weights) on AVX2 CPUs with FMA: the 8-lane kernel
// with its fused multiply-adds as instructions; fp-contract=off, so only those are fused.
#define DHR_DENOISE_TARGET_AVX2_FMA __attribute__((target("avx2,fma"), optimize("fp-contract=off")))
#else
#define DHR_DENOISE_TARGETS
#define DHR_DENOISE_AVX512 0
#endif

constexpr int kLanes = 8;
using VecF = float __attribute__((vector_size(4 * kLanes)));
using VecI = int32_t __attribute__((vector_size(4 * kLanes)));
using VecU = uint32_t __attribute__((vector_size(4 * kLanes)));
// 16 lanes: one AVX-512 register (only the a-trous interior blocks and the spatial moments use it).
constexpr int kLanes16 = 16;
using VecF16 = float __attribute__((vector_size(4 * kLanes16)));
using VecI16 = int32_t __attribute__((vector_size(4 * kLanes16)));
using VecU16 = uint32_t __attribute__((vector_size(4 * kLanes16)));

DHR_ALWAYS_INLINE VecF splat(float v) { return VecF{} + v; }

// 2^f for f in [-0.5, 0.5]: the degree-4 Taylor polynomial exp_neg uses (float or any vector of
// floats; the same operations on each).
template <class V>
DHR_ALWAYS_INLINE V exp2_poly(V f) {
  V p = V{} + 9.6181291e-3f;  // the constant itself (0 + c = c)
  p = p * f + 5.5504109e-2f;
  p = p * f + 2.4022651e-1f;
  p = p * f + 6.9314718e-1f;
  return p * f + 1.0f;
}

// e^x for x <= 0 (larger x is clamped to 0), relative error below 5e-5 (plenty for filter
// weights); exactly 0 below -60 (e^-60 < 1e-26: a weight that small changes nothing). Split
// x log2(e) = i + f with i rounded to nearest, f in [-0.5, 0.5]; 2^f by its degree-4 Taylor
// polynomial; 2^i added to the exponent bits.
DHR_ALWAYS_INLINE float exp_neg(float x) {
  const float xc = x < -60.0f ? -60.0f : (x > 0.0f ? 0.0f : x);
  const float t = xc * 1.44269504f;
  const int32_t i = int32_t(t - 0.5f);  // t - 0.5 < 0: truncation rounds t to nearest
  const float f = t - float(i);
  const float p = exp2_poly(f);
  const float r = std::bit_cast<float>(std::bit_cast<int32_t>(p) + int32_t(uint32_t(i) << 23));
  return x < -60.0f ? 0.0f : r;
}
// The same, lane by lane, for a vector V of floats (VI, VU: its int32 and uint32 twins).
template <class V, class VI, class VU>
DHR_ALWAYS_INLINE V exp_neg_lanes(V x) {
  const V lo = V{} - 60.0f, zero = V{};
  V xc = x < lo ? lo : x;
  xc = xc > zero ? zero : xc;
  const V t = xc * 1.44269504f;
  const VI i = __builtin_convertvector(t - 0.5f, VI);
  const V f = t - __builtin_convertvector(i, V);
  const V p = exp2_poly(f);
  const V r = (V)((VI)p + (VI)((VU)i << 23));
  return x < lo ? zero : r;
}
DHR_ALWAYS_INLINE VecF exp_neg(VecF x) { return exp_neg_lanes<VecF, VecI, VecU>(x); }
DHR_ALWAYS_INLINE VecF16 exp_neg(VecF16 x) { return exp_neg_lanes<VecF16, VecI16, VecU16>(x); }

// ---- The a-trous taps' fast weights (FilterSettings::fast_weights; docs/performance.md,
// "svgf_ao's fast weights"). e^-s = 2^t with t = -s log2(e) computed by the caller; t = i + f
// with i = t rounded to nearest (even), f in [-0.5, 0.5]; 2^f by the degree-3 polynomial
// closest to it in relative error on that interval (7.5e-5, as small as the degree-4 Taylor
// polynomial of exp_neg), evaluated by fused multiply-adds; 2^i added to the exponent bits.
// Exactly 0 for t < kFastExpLo (s > 60, as exp_neg) and for a NaN t. Every lane type gives the
// same bits: the rounding to nearest is exact for |t| < 2^22 (the 1.5 2^23 shift), a fused
// multiply-add is one rounding on every machine, and p 2^i stays normal (p >= 0.7, i >= -87).
constexpr float kFastExpLo = -86.5617f;  // -60 log2(e), rounded up: every t kept has i >= -87
constexpr float kFastExpC0 = 0.99992808f, kFastExpC1 = 0.69326099f, kFastExpC2 = 0.24261096f, kFastExpC3 = 0.055171501f;
constexpr float kLog2e = 1.44269504f;
constexpr float kRoundShift = 12582912.0f;  // 1.5 2^23: (t + it) - it is t rounded to an integer

// a b + c with one rounding, lane by lane (an FMA instruction where the target has one).
DHR_ALWAYS_INLINE float fma_l(float a, float b, float c) { return __builtin_fmaf(a, b, c); }
template <class V>
DHR_ALWAYS_INLINE V fma_l(V a, V b, V c) {
  V r;
  for (int i = 0; i < int(sizeof(V) / sizeof(float)); ++i) r[i] = __builtin_fmaf(a[i], b[i], c[i]);
  return r;
}

// 2^f for f in [-0.5, 0.5], the fast weights' polynomial.
template <class V>
DHR_ALWAYS_INLINE V fast_exp2_poly(V f) {
  const V c3 = V{} + kFastExpC3, c2 = V{} + kFastExpC2, c1 = V{} + kFastExpC1, c0 = V{} + kFastExpC0;
  return fma_l(fma_l(fma_l(c3, f, c2), f, c1), f, c0);
}

// hw 2^t (hw = h wn, finite and >= 0), 0 where t < kFastExpLo or t is NaN.
DHR_ALWAYS_INLINE float fast_weight(float hw, float t) {
  if (!(t >= kFastExpLo)) return 0.0f;
  const float fi = (t + kRoundShift) - kRoundShift;
  const float p = fast_exp2_poly(t - fi);
  return hw * std::bit_cast<float>(std::bit_cast<uint32_t>(p) + (uint32_t(int32_t(fi)) << 23));
}
template <class V, class VI, class VU>
DHR_ALWAYS_INLINE V fast_weight_lanes(V hw, V t) {
  const V fi = (t + kRoundShift) - kRoundShift;
  const V p = fast_exp2_poly(t - fi);
  // In unsigned lanes: a lane the cut drops may hold any exponent (its sum wraps, unused).
  const V r = (V)((VU)p + ((VU) __builtin_convertvector(fi, VI) << 23));
  return t >= V{} + kFastExpLo ? hw * r : V{};
}
DHR_ALWAYS_INLINE VecF fast_weight(VecF hw, VecF t) { return fast_weight_lanes<VecF, VecI, VecU>(hw, t); }
DHR_ALWAYS_INLINE VecF16 fast_weight(VecF16 hw, VecF16 t) { return fast_weight_lanes<VecF16, VecI16, VecU16>(hw, t); }

DHR_ALWAYS_INLINE float abs_f(float v) { return std::fabs(v); }
DHR_ALWAYS_INLINE VecF abs_f(VecF v) { return (VecF)((VecI)v & 0x7fffffff); }
DHR_ALWAYS_INLINE VecF16 abs_f(VecF16 v) { return (VecF16)((VecI16)v & 0x7fffffff); }
DHR_ALWAYS_INLINE float max0(float v) { return v > 0.0f ? v : 0.0f; }
DHR_ALWAYS_INLINE VecF max0(VecF v) { return v > splat(0.0f) ? v : splat(0.0f); }
DHR_ALWAYS_INLINE VecF16 max0(VecF16 v) { return v > VecF16{} ? v : VecF16{}; }

// max(0, d)^(2^k) by k squarings (the normal weight, sigma_n = 2^k). K >= 0: k = K known at
// compile time (the loop unrolls); K = -1: k at run time.
template <int K, class T>
DHR_ALWAYS_INLINE T pow_2k(T d, int k) {
  d = max0(d);
  if constexpr (K >= 0) {
    for (int i = 0; i < K; ++i) d = d * d;
  } else {
    for (int i = 0; i < k; ++i) d = d * d;
  }
  return d;
}
constexpr int kDefaultSquarings = 7;  // sigma_n = 128

struct ScalarLane {
  using T = float;
  static DHR_ALWAYS_INLINE float load(const float* p) { return *p; }
  static DHR_ALWAYS_INLINE void store(float* p, float v) { *p = v; }
};
struct VectorLane {
  using T = VecF;
  static DHR_ALWAYS_INLINE VecF load(const float* p) {
    VecF v;
    std::memcpy(&v, p, sizeof v);
    return v;
  }
  static DHR_ALWAYS_INLINE void store(float* p, VecF v) { std::memcpy(p, &v, sizeof v); }
};
struct VectorLane16 {
  using T = VecF16;
  static DHR_ALWAYS_INLINE VecF16 load(const float* p) {
    VecF16 v;
    std::memcpy(&v, p, sizeof v);
    return v;
  }
  static DHR_ALWAYS_INLINE void store(float* p, VecF16 v) { std::memcpy(p, &v, sizeof v); }
};

}  // namespace dhr::denoise
