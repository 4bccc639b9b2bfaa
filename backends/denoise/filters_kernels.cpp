// The hot kernels of the SVGF-family filter (filters.h): one a-trous iteration over whole rows
// (atrous_rows) and the depth/normal-weighted spatial moments of a row span (moment_span),
// each with an 8-lane kernel cloned for AVX2 and the baseline and a 16-lane AVX-512 one
// chosen at run time; all give the same bits (filters_simd.h; tests/backends/test_denoisers.cpp,
// AtrousKernelSameBitsOnEveryVectorWidth, checks it).
//
// Cost at 1280x720 (tests/backends/bench_denoise.cpp): a-trous dominates (5 iterations x 24 taps per
// pixel). Centre values and sums of 8 pixels (16 with AVX-512) stay in registers across the
// 24 taps; the normal power is 7 squarings (sigma_n = 128 is compiled in; other powers of two
// loop). Where the CPU has AVX-512 the a-trous and spatial-moment kernels take 16 lanes: the
// taps unrolled around a 14-instruction exponential (atrous_block16_unrolled), the row ends 16
// at a time, the AO phi's sums in registers, the fast weights (FMAs and a degree-3
// exponential; the default, AtrousArgs::fast_weights), every pixel of a row in 16-lane blocks
// (the ends masked), each finished in registers, and the last iteration's variance left out.
// With the temporal part's rows in 16 lanes too, svgf_ao takes 1.83-1.92x the CPU time of one
// traced AO ray on a 2-vCPU Zen 4 (room, 1280x720; docs/performance.md, "Each stage against its
// floor"); what each step saved: `git show aec67ef:docs/performance.md`, "svgf_ao".
#include "backends/denoise/filters.h"
#include "backends/denoise/filters_simd.h"
#include "core/base/cpu_isa.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>
#if DHR_DENOISE_AVX512
#include <immintrin.h>
#endif

namespace dhr::denoise {
namespace {

// ---- AO phi of the a-trous weight: ipl = 1 / (sigma_l sqrt(var) + eps) at a valid pixel, 0 at
// an invalid one, var = the 3x3 Gaussian of the variance over valid pixels (sum k var / sum k
// valid). inv_valid_k (1 / sum k valid) is in [1, 4] at a valid pixel and 0 at an invalid one,
// so it tells which is which: no plane of valid flags is read.
template <class L>
DHR_ALWAYS_INLINE void inv_phi_l_lanes(const float* sum_kv, const float* inv_valid_k, float sigma_l, float eps,
                                       float* out) {
  using T = typename L::T;
  // 1/sqrt by the bit trick and two Newton steps (relative error < 1e-5); the floor keeps
  // the steps finite (sqrt(1e-20) = 1e-10 is far below eps).
  const T ivk = L::load(inv_valid_k);
  T v = L::load(sum_kv) * ivk;
  v = v < T{} + 1e-20f ? T{} + 1e-20f : v;
  T y;
  if constexpr (std::is_same_v<T, float>) {
    y = std::bit_cast<float>(int32_t(0x5f3759df) - (std::bit_cast<int32_t>(v) >> 1));
  } else if constexpr (std::is_same_v<T, VecF>) {
    y = (VecF)(int32_t(0x5f3759df) - ((VecI)v >> 1));
  } else {
    y = (VecF16)(int32_t(0x5f3759df) - ((VecI16)v >> 1));
  }
  y = y * (1.5f - 0.5f * v * y * y);
  y = y * (1.5f - 0.5f * v * y * y);
  const T ipl = 1.0f / (sigma_l * (v * y) + eps);
  L::store(out, ivk > T{} ? ipl : T{});
}

// ---- The a-trous rows (AtrousArgs, filters.h).

// Whether [x, x + n) of a cls row holds a pixel of class c (n <= 16 and cls values 0/1).
DHR_ALWAYS_INLINE bool block_has(const uint8_t* cls_row, int x, int n, uint8_t c) {
  if (n == 16) {
    uint64_t lo, hi;
    std::memcpy(&lo, cls_row + x, 8);
    std::memcpy(&hi, cls_row + x + 8, 8);
    return c ? (lo | hi) != 0 : (lo & hi) != 0x0101010101010101ull;
  }
  if (n == 8) {
    uint64_t lo;
    std::memcpy(&lo, cls_row + x, 8);
    return c ? lo != 0 : lo != 0x0101010101010101ull;
  }
  for (int i = 0; i < n; ++i)
    if (cls_row[x + i] == c) return true;
  return false;
}

struct AtrousTapPlanes {
  const float *zc, *ncx, *ncy, *ncz, *ipz, *ipl, *lc;  // centre row, indexed by x
  const float *zq, *nqx, *nqy, *nqz, *lq, *vq;         // neighbour row, indexed by x + off
  float *sw, *sl, *sv;                                 // accumulators, indexed by x
};

// The fast weights' tap (AtrousArgs::fast_weights), one lane type for all: t = -(|l_p - l_q|
// ipl log2(e) + |z_p - z_q| (ipz log2(e) inv_len)), the dot product and the sums by fused
// multiply-adds, the weight by fast_weight. atrous_block16_unrolled's fast taps do the same
// operations.
template <int K, class T>
DHR_ALWAYS_INLINE void fast_tap(T ncx, T ncy, T ncz, T nqx, T nqy, T nqz, T adz, T az, T adl, T iplg, float hk, int nsq,
                                T lq, T vq, T& sw, T& sl, T& sv) {
  const T d = fma_l(ncz, nqz, fma_l(ncy, nqy, ncx * nqx));
  const T wn = pow_2k<K>(d, nsq);
  const T t = -fma_l(adl, iplg, adz * az);
  const T wgt = fast_weight(hk * wn, t);
  sw = sw + wgt;
  sl = fma_l(wgt, lq, sl);
  sv = fma_l(wgt * wgt, vq, sv);
}

template <int K, class L, bool F>
DHR_ALWAYS_INLINE void atrous_tap(const AtrousTapPlanes& p, int x, int q, float hk, float inv_len, int nsq) {
  using T = typename L::T;
  if constexpr (F) {
    const T lq = L::load(p.lq + q);
    T sw = L::load(p.sw + x), sl = L::load(p.sl + x), sv = L::load(p.sv + x);
    fast_tap<K>(L::load(p.ncx + x), L::load(p.ncy + x), L::load(p.ncz + x), L::load(p.nqx + q), L::load(p.nqy + q),
                L::load(p.nqz + q), abs_f(L::load(p.zc + x) - L::load(p.zq + q)),
                (L::load(p.ipz + x) * kLog2e) * inv_len, abs_f(L::load(p.lc + x) - lq), L::load(p.ipl + x) * kLog2e, hk,
                nsq, lq, L::load(p.vq + q), sw, sl, sv);
    L::store(p.sw + x, sw);
    L::store(p.sl + x, sl);
    L::store(p.sv + x, sv);
    return;
  }
  const T d = L::load(p.ncx + x) * L::load(p.nqx + q) + L::load(p.ncy + x) * L::load(p.nqy + q) +
              L::load(p.ncz + x) * L::load(p.nqz + q);
  const T wn = pow_2k<K>(d, nsq);
  const T wz = abs_f(L::load(p.zc + x) - L::load(p.zq + q)) * L::load(p.ipz + x) * inv_len;
  const T lq = L::load(p.lq + q);
  const T wl = abs_f(L::load(p.lc + x) - lq) * L::load(p.ipl + x);
  const T wgt = (hk * wn) * exp_neg(-(wz + wl));
  L::store(p.sw + x, L::load(p.sw + x) + wgt);
  L::store(p.sl + x, L::load(p.sl + x) + wgt * lq);
  L::store(p.sv + x, L::load(p.sv + x) + wgt * wgt * L::load(p.vq + q));
}

// The same taps for a block of pixels [x, x + lanes) whose neighbours are all inside the row
// (x - r step >= 0, x + lanes - 1 + r step < width): centre values and sums stay in registers
// across the taps. Same operations in the same order as atrous_tap, so the same bits.
// ipl_row: the AO phi of row y, indexed by x.
template <int K, class L, bool F>
DHR_ALWAYS_INLINE void atrous_block(const AtrousArgs& a, int y, int x, const float* ipl_row, const float (*hk)[5],
                                    const float (*inv_len)[5], float* sw_out, float* sl_out, float* sv_out) {
  using T = typename L::T;
  const int r = a.radius, step = a.step, nsq = a.normal_squarings;
  const size_t c = size_t(y) * size_t(a.width) + size_t(x);
  const T zc = L::load(a.depth + c), ncx = L::load(a.nx + c), ncy = L::load(a.ny + c), ncz = L::load(a.nz + c);
  const T ipz = L::load(a.inv_phi_z + c), ipl = L::load(ipl_row + x), lc = L::load(a.v_in + c);
  const float hc = a.k1d[0] * a.k1d[0];
  T sw = T{} + hc;
  T sl = hc * lc;
  T sv = (hc * hc) * L::load(a.var_in + c);
  [[maybe_unused]] const T ipzl = ipz * kLog2e, iplg = ipl * kLog2e;  // the fast weights' (fast_tap)
  for (int ty = -r; ty <= r; ++ty) {
    const int qy = y + ty * step;
    if (qy < 0 || qy >= a.height) continue;
    const size_t qrow = size_t(qy) * size_t(a.width) + size_t(x);
    for (int tx = -r; tx <= r; ++tx) {
      if (tx == 0 && ty == 0) continue;
      const size_t q = qrow + size_t(tx * step);  // x + tx step >= 0 here
      if constexpr (F) {
        const T lq = L::load(a.v_in + q);
        fast_tap<K>(ncx, ncy, ncz, L::load(a.nx + q), L::load(a.ny + q), L::load(a.nz + q),
                    abs_f(zc - L::load(a.depth + q)), ipzl * inv_len[ty + 2][tx + 2], abs_f(lc - lq), iplg,
                    hk[ty + 2][tx + 2], nsq, lq, L::load(a.var_in + q), sw, sl, sv);
        continue;
      }
      const T d = ncx * L::load(a.nx + q) + ncy * L::load(a.ny + q) + ncz * L::load(a.nz + q);
      const T wn = pow_2k<K>(d, nsq);
      const T wz = abs_f(zc - L::load(a.depth + q)) * ipz * inv_len[ty + 2][tx + 2];
      const T lq = L::load(a.v_in + q);
      const T wl = abs_f(lc - lq) * ipl;
      const T wgt = (hk[ty + 2][tx + 2] * wn) * exp_neg(-(wz + wl));
      sw = sw + wgt;
      sl = sl + wgt * lq;
      sv = sv + wgt * wgt * L::load(a.var_in + q);
    }
  }
  L::store(sw_out, sw);
  L::store(sl_out, sl);
  L::store(sv_out, sv);
}

#if DHR_DENOISE_AVX512
// The same taps as atrous_block for a block of 8 pixels at x, for AVX2 without AVX-512
// (atrous_block16_unrolled's idea in 8 lanes): the taps unrolled (radius R known at compile
// time, so the kernel weights and 1/length are constants) and the exponential's clamps
// replaced by one mask. The bits are those of atrous_block, every product and sum the same IEEE
// operation in the same order; only exp_neg(-(wz + wl)) is reached differently, as in the
// 16-lane kernel: wz, wl >= 0, so the clamp at 0 never acts; t = -(s) 1.44269504 is
// s (-1.44269504); the clamp at -60 and the final "x < -60 ? 0" become one mask (s > 60) that
// zeroes the weight (exp_neg's (h wn) 0 is +0 there, h wn being finite and >= 0; the mask gives
// +0 whatever r holds in those lanes); the split into i and f, the polynomial and the exponent
// add are exp_neg's own operations.
template <int K, int R>
DHR_ALWAYS_INLINE DHR_DENOISE_TARGET_AVX2 void atrous_block8_unrolled(const AtrousArgs& a, int y, int x,
                                                                      const float* ipl_row, const float (*hk)[5],
                                                                      const float (*inv_len)[5], float* sw_out,
                                                                      float* sl_out, float* sv_out) {
  using L = VectorLane;
  using T = VecF;
  const int step = a.step, nsq = a.normal_squarings;
  const size_t c = size_t(y) * size_t(a.width) + size_t(x);
  const T zc = L::load(a.depth + c), ncx = L::load(a.nx + c), ncy = L::load(a.ny + c), ncz = L::load(a.nz + c);
  const T ipz = L::load(a.inv_phi_z + c), ipl = L::load(ipl_row + x), lc = L::load(a.v_in + c);
  const float hc = a.k1d[0] * a.k1d[0];
  T sw = T{} + hc;
  T sl = hc * lc;
  T sv = (hc * hc) * L::load(a.var_in + c);
#pragma GCC unroll 5
  for (int ty = -R; ty <= R; ++ty) {
    const int qy = y + ty * step;
    if (qy < 0 || qy >= a.height) continue;
    const size_t qrow = size_t(qy) * size_t(a.width) + size_t(x);
#pragma GCC unroll 5
    for (int tx = -R; tx <= R; ++tx) {
      if (tx == 0 && ty == 0) continue;
      const size_t q = qrow + size_t(tx * step);  // x + tx step >= 0 here
      const float hkv = hk[ty + 2][tx + 2], il = inv_len[ty + 2][tx + 2];
      const T d = ncx * L::load(a.nx + q) + ncy * L::load(a.ny + q) + ncz * L::load(a.nz + q);
      T wn = (T)_mm256_max_ps((__m256)d, _mm256_setzero_ps());  // d > 0 ? d : 0, then the squarings
      if constexpr (K >= 0) {
        for (int i = 0; i < K; ++i) wn = wn * wn;
      } else {
        for (int i = 0; i < nsq; ++i) wn = wn * wn;
      }
      const T wz = abs_f(zc - L::load(a.depth + q)) * ipz * il;
      const T lq = L::load(a.v_in + q);
      const T wl = abs_f(lc - lq) * ipl;
      const T s = wz + wl;
      const T t = s * -1.44269504f;
      const VecI i = __builtin_convertvector(t - 0.5f, VecI);
      const T f = t - __builtin_convertvector(i, T);
      const T p = exp2_poly(f);
      const T r = (T)((VecI)p + (VecI)((VecU)i << 23));
      const __m256 keep = _mm256_cmp_ps((__m256)s, _mm256_set1_ps(60.0f), _CMP_NGT_UQ);
      const T wgt = (T)_mm256_and_ps(keep, (__m256)((hkv * wn) * r));
      sw = sw + wgt;
      sl = sl + wgt * lq;
      sv = sv + wgt * wgt * L::load(a.var_in + q);
    }
  }
  L::store(sw_out, sw);
  L::store(sl_out, sl);
  L::store(sv_out, sv);
}

// The 8-pixel blocks of [xb, xm) of row y (the interior of atrous_row16_all's rows, for AVX2).
template <int K, int R>
__attribute__((noinline)) DHR_DENOISE_TARGET_AVX2 void atrous_blocks8(const AtrousArgs& a, int y, int xb, int xm,
                                                                      const uint8_t* cls, const float* ipl_row,
                                                                      const float (*hk)[5], const float (*inv_len)[5],
                                                                      float* sw, float* sl, float* sv) {
  const uint8_t ac = a.active_cls;
  for (; xb < xm; xb += kLanes)
    if (!cls || block_has(cls, xb, kLanes, ac))
      atrous_block8_unrolled<K, R>(a, y, xb, ipl_row, hk, inv_len, sw + xb, sl + xb, sv + xb);
}
#endif

#if DHR_DENOISE_AVX512
// The a-trous sums of 16 pixels: sum w, sum w l, sum w^2 var.
struct Sums16 {
  VecF16 sw, sl, sv;
};

// A plane's 16 values at q; with M only the lanes of m (the others +0), and q may then lie
// outside the plane: the address is computed modulo 2^64 and its lanes outside m are never
// read (a masked load does not touch them).
template <bool M>
DHR_ALWAYS_INLINE DHR_DENOISE_TARGET_AVX512 VecF16 load16(const float* plane, size_t q, [[maybe_unused]] __mmask16 m) {
  if constexpr (M)
    return (VecF16)_mm512_maskz_loadu_ps(
        m, reinterpret_cast<const void*>(reinterpret_cast<uintptr_t>(plane) + q * sizeof(float)));
  else
    return VectorLane16::load(plane + q);
}

// The same taps as atrous_block for a block of 16 pixels at x (AVX-512), written for
// throughput: the taps are unrolled (radius R known at compile time) and the exponential takes
// 14 instructions instead of 18. (Two blocks interleaved were tried and were no faster: their
// 20 centre values and sums do not fit the 32 registers beside the constants and spill.) The bits are those of atrous_block: every product and sum is
// the same IEEE operation in the same order; only these steps are done by other instructions
// with the same result:
//  - exp_neg(-(wz + wl)): wz, wl >= 0, so its clamp at 0 never acts and is left out;
//    t = -(s) 1.44269504 is s (-1.44269504) (rounding is symmetric); the clamp at -60 and the
//    final "x < -60 ? 0" become a mask (s > 60) that zeroes the weight (the masked product
//    (h wn) r gives the same +0); the rounding of t - 0.5 by truncation to an integer and back
//    is vrndscaleps (truncate), exact where it is used (|t| < 87); adding i to the exponent bits of p
//    (p in [0.7, 1.5), i >= -87) is p 2^i by vscalefps, exact in the normal range it stays in.
//  - max(0, d) is vmaxps(d, 0) (d > 0 ? d : 0, NaN to 0 as well).
//
// With F (AtrousArgs::fast_weights) the taps are fast_tap's operations: the fused multiply-adds
// as instructions, t's rounding to nearest as vrndscaleps (equal to fast_weight's shift for the
// |t| <= 86.57 that are kept), 2^i by vscalefps (exact, as the exponent add), the cut at
// kFastExpLo (and NaN) as a mask on the last product, and ipz log2(e) inv_len computed once per
// block for each of the kernel's distinct offset lengths (tx^2 + ty^2 = 1, 2, 4, 5, 8: the same
// products fast_tap makes per tap).
//
// With M (a block at the row's ends, atrous_row16_all) a tap's neighbours outside the row are
// left out: its loads are masked (lanes outside read nothing and hold +0) and so is its weight
// (exactly +0 there), so the sums of those lanes are those of the taps that remain, added in
// the same order (s + 0 = s, fma(0, 0, s) = s): the bits of the row-wise border taps.
//
// Without V (AtrousArgs::var_out null: the variance is not wanted) the sums of w^2 var are
// left out (sv stays 0). Returns the three sums of the 16 pixels.
template <int K, int R, bool F, bool M = false, bool V = true>
DHR_ALWAYS_INLINE DHR_DENOISE_TARGET_AVX512 Sums16 atrous_block16_unrolled(const AtrousArgs& a, int y, int x,
                                                                           const float* ipl_row, const float (*hk)[5],
                                                                           const float (*inv_len)[5]) {
  using L = VectorLane16;
  using T = VecF16;
  const int step = a.step, nsq = a.normal_squarings;
  // M: the lanes whose neighbour at column offset tx step lies in the row, by tx.
  [[maybe_unused]] __mmask16 in_row[5] = {0xffff, 0xffff, 0xffff, 0xffff, 0xffff};
  if constexpr (M) {
    for (int tx = -R; tx <= R; ++tx) {
      const int off = tx * step;
      const int lo = std::max(0, -off - x), hi = std::min(kLanes16, a.width - off - x);
      in_row[tx + 2] = hi > lo ? __mmask16(((1u << hi) - 1u) & ~((1u << lo) - 1u)) : __mmask16(0);
    }
  }

  const size_t c = size_t(y) * size_t(a.width) + size_t(x);
  const T zc = L::load(a.depth + c), ncx = L::load(a.nx + c), ncy = L::load(a.ny + c), ncz = L::load(a.nz + c);
  const T ipz = L::load(a.inv_phi_z + c), ipl = L::load(ipl_row + x), lc = L::load(a.v_in + c);
  const float hc = a.k1d[0] * a.k1d[0];
  T sw = T{} + hc;
  T sl = hc * lc;
  [[maybe_unused]] T sv = V ? (hc * hc) * L::load(a.var_in + c) : T{};
  const __m512 zero = _mm512_setzero_ps();
  [[maybe_unused]] const __m512 sixty = _mm512_set1_ps(60.0f);  // the exact weights' cut
  const __mmask16 all = 0xffff;  // the zero-masked forms: GCC 12 warns on the plain ones' undefined source
  // The fast weights' values per block (F only).
  [[maybe_unused]] const T iplg = ipl * kLog2e;
  [[maybe_unused]] constexpr int kLengthClass[9] = {-1, 0, 1, -1, 2, 3, -1, -1, 4};  // by tx^2 + ty^2
  [[maybe_unused]] __m512 az[5] = {zero, zero, zero, zero, zero};
  if constexpr (F) {
    const T ipzl = ipz * kLog2e;
    az[0] = (__m512)(ipzl * inv_len[2][3]);  // (1, 0)
    az[1] = (__m512)(ipzl * inv_len[3][3]);  // (1, 1)
    if constexpr (R == 2) {
      az[2] = (__m512)(ipzl * inv_len[2][4]);  // (2, 0)
      az[3] = (__m512)(ipzl * inv_len[3][4]);  // (2, 1)
      az[4] = (__m512)(ipzl * inv_len[4][4]);  // (2, 2)
    }
  }
  [[maybe_unused]] const __m512 lo = _mm512_set1_ps(kFastExpLo), c3 = _mm512_set1_ps(kFastExpC3),
                                c2 = _mm512_set1_ps(kFastExpC2), c1 = _mm512_set1_ps(kFastExpC1),
                                c0 = _mm512_set1_ps(kFastExpC0);
#pragma GCC unroll 5
  for (int ty = -R; ty <= R; ++ty) {
    const int qy = y + ty * step;
    if (qy < 0 || qy >= a.height) continue;
    const size_t qrow = size_t(qy) * size_t(a.width) + size_t(x);
#pragma GCC unroll 5
    for (int tx = -R; tx <= R; ++tx) {
      if (tx == 0 && ty == 0) continue;
      const size_t q = qrow + size_t(tx * step);  // x + tx step >= 0 here, unless M
      const __mmask16 m = in_row[tx + 2];
      if constexpr (M) {
        if (!m) continue;  // no lane has this neighbour: the tap adds nothing
      }
      const float hkv = hk[ty + 2][tx + 2];
      __m512 d;
      if constexpr (F) {
        d = _mm512_mul_ps((__m512)ncx, (__m512)load16<M>(a.nx, q, m));
        d = _mm512_fmadd_ps((__m512)ncy, (__m512)load16<M>(a.ny, q, m), d);
        d = _mm512_fmadd_ps((__m512)ncz, (__m512)load16<M>(a.nz, q, m), d);
      } else {
        d = (__m512)(ncx * load16<M>(a.nx, q, m) + ncy * load16<M>(a.ny, q, m) + ncz * load16<M>(a.nz, q, m));
      }
      T wn = (T)_mm512_maskz_max_ps(all, d, zero);  // then pow_2k's squarings
      if constexpr (K >= 0) {
        for (int i = 0; i < K; ++i) wn = wn * wn;
      } else {
        for (int i = 0; i < nsq; ++i) wn = wn * wn;
      }
      const T lq = load16<M>(a.v_in, q, m);
      if constexpr (F) {
        const T adz = abs_f(zc - load16<M>(a.depth, q, m));
        const T adl = abs_f(lc - lq);
        const __m512 t = _mm512_fnmsub_ps((__m512)adl, (__m512)iplg,
                                          _mm512_mul_ps((__m512)adz, az[kLengthClass[tx * tx + ty * ty]]));
        const __m512 fi = _mm512_maskz_roundscale_ps(all, t, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
        const __m512 f = _mm512_sub_ps(t, fi);
        const __m512 p = _mm512_fmadd_ps(_mm512_fmadd_ps(_mm512_fmadd_ps(c3, f, c2), f, c1), f, c0);
        const __m512 r = _mm512_maskz_scalef_ps(all, p, fi);
        const __mmask16 keep = _mm512_cmp_ps_mask(t, lo, _CMP_GE_OQ) & m;
        const __m512 wgt = _mm512_maskz_mul_ps(keep, (__m512)(hkv * wn), r);
        sw = sw + (T)wgt;
        sl = (T)_mm512_fmadd_ps(wgt, (__m512)lq, (__m512)sl);
        if constexpr (V)
          sv = (T)_mm512_fmadd_ps(_mm512_mul_ps(wgt, wgt), (__m512)load16<M>(a.var_in, q, m), (__m512)sv);
      } else {
        const T wz = abs_f(zc - load16<M>(a.depth, q, m)) * ipz * inv_len[ty + 2][tx + 2];
        const T wl = abs_f(lc - lq) * ipl;
        const T s = wz + wl;
        const T t = s * -1.44269504f;
        const __m512 fi = _mm512_maskz_roundscale_ps(all, (__m512)(t - 0.5f), _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC);
        const T f = t - (T)fi;
        T p = T{} + 9.6181291e-3f;
        p = p * f + 5.5504109e-2f;
        p = p * f + 2.4022651e-1f;
        p = p * f + 6.9314718e-1f;
        p = p * f + 1.0f;
        const __m512 r = _mm512_maskz_scalef_ps(all, (__m512)p, fi);
        const __mmask16 keep = _mm512_cmp_ps_mask((__m512)s, sixty, _CMP_NGT_UQ) & m;
        const T wgt = (T)_mm512_maskz_mul_ps(keep, (__m512)(hkv * wn), r);
        sw = sw + wgt;
        sl = sl + wgt * lq;
        if constexpr (V) sv = sv + wgt * wgt * load16<M>(a.var_in, q, m);
      }
    }
  }
  return {sw, sl, sv};
}

// The end of a row (the loop at the end of atrous_rows_impl) for the 16 pixels from index i,
// from their sums: the same IEEE operations per pixel (1 / sw, the products, the clamps as the
// same comparisons), so the same bits; the pixels a cls leaves out keep v_out and var_out and
// take to_u8 of v_out.
DHR_ALWAYS_INLINE DHR_DENOISE_TARGET_AVX512 void finish_block16(const AtrousArgs& a, size_t i, const Sums16& s) {
  using L = VectorLane16;
  using T = VecF16;
  const __mmask16 all = 0xffff;  // the zero-masked forms: see atrous_block16_unrolled
  const __m128i vb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a.valid + i));
  const __mmask16 valid =
      _mm512_test_epi32_mask(_mm512_maskz_cvtepu8_epi32(all, vb), _mm512_maskz_cvtepu8_epi32(all, vb));
  __mmask16 act = 0xffff;
  if (a.cls) {
    const __m128i cb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a.cls + i));
    act = _mm512_cmpeq_epi32_mask(_mm512_maskz_cvtepu8_epi32(all, cb), _mm512_set1_epi32(a.active_cls));
  }
  const T inv = T{} + 1.0f / s.sw;  // sw >= h_c > 0 at a valid pixel
  const T t = s.sl * inv;
  const T lo = T{}, hi = T{} + 1.0f;
  T v = t < lo ? lo : (hi < t ? hi : t);  // std::clamp(t, 0, 1)
  v = (T)_mm512_mask_blend_ps(valid, (__m512)L::load(a.v_in + i), (__m512)v);
  _mm512_mask_storeu_ps(a.v_out + i, act, (__m512)v);
  if (a.v_out2) _mm512_mask_storeu_ps(a.v_out2 + i, act, (__m512)v);
  if (a.v_out3) _mm512_mask_storeu_ps(a.v_out3 + i, act, (__m512)v);
  if (a.var_out) {
    const T q = s.sv * inv * inv;
    T var = lo < q ? q : lo;  // std::max(0, q)
    var = (T)_mm512_maskz_mov_ps(valid, (__m512)var);
    _mm512_mask_storeu_ps(a.var_out + i, act, (__m512)var);
    if (a.var_out2) _mm512_mask_storeu_ps(a.var_out2 + i, act, (__m512)var);
  }
  if (a.u8_out) {  // to_u8 (filters.h), of v_out as it is where a cls leaves the pixel out
    const T vo = (T)_mm512_mask_blend_ps(act, (__m512)L::load(a.v_out + i), (__m512)v);
    T f = vo * 255.0f + 0.5f;
    f = f >= lo ? f : lo;
    f = f <= T{} + 255.0f ? f : T{} + 255.0f;
    _mm_storeu_si128(reinterpret_cast<__m128i*>(a.u8_out + i),
                     _mm512_maskz_cvtepi32_epi8(all, _mm512_maskz_cvttps_epi32(all, (__m512)f)));
  }
}

// One a-trous iteration's row y (width >= 16), whole: its pixels in 16-pixel blocks, the row's
// end block at width - 16 (overlapping its neighbour, which is computed twice with the same
// bits); the blocks whose taps reach past either end of the row take the masked kernel (M). Each
// block is finished (finish_block16) from its sums in registers. A block without a pixel of
// a.active_cls (when cls is given) is not filtered, only given its 8-bit output. V: a.var_out
// is set (the variance is wanted).
template <int K, int R, bool F, bool V>
__attribute__((noinline)) DHR_DENOISE_TARGET_AVX512 void atrous_row16_all(const AtrousArgs& a, int y,
                                                                          const uint8_t* cls, const float* ipl_row,
                                                                          const float (*hk)[5],
                                                                          const float (*inv_len)[5]) {
  const int w = a.width, reach = R * a.step;
  const size_t row = size_t(y) * size_t(w);
  for (int xb = 0; xb < w; xb += kLanes16) {
    const int x = std::min(xb, w - kLanes16);
    Sums16 sums{};
    if (cls && !block_has(cls, x, kLanes16, a.active_cls)) {
      if (!a.u8_out) continue;  // nothing of this block changes
    } else if (x >= reach && x + kLanes16 + reach <= w) {
      sums = atrous_block16_unrolled<K, R, F, false, V>(a, y, x, ipl_row, hk, inv_len);
    } else {
      sums = atrous_block16_unrolled<K, R, F, true, V>(a, y, x, ipl_row, hk, inv_len);
    }
    finish_block16(a, row + size_t(x), sums);
  }
}
#endif

// The AO phi of row y into out (w floats), from var_in (see AtrousArgs::inv_phi_l). The 3x3
// sums are taken in the same order for every pixel (dy, then dx, from -1), starting from 0:
// in registers, a block of L's lanes at a time, for the pixels with both horizontal neighbours,
// one at a time (the same sums, the missing neighbours left out) at the row's two ends.
template <class L>
DHR_ALWAYS_INLINE void inv_phi_l_of_row(const AtrousArgs& a, int y, float* out) {
  using T = typename L::T;
  constexpr int n = sizeof(T) / sizeof(float);
  const int w = a.width, h = a.height;
  const size_t row = size_t(y) * size_t(w);
  if (!(a.sigma_l > 0.0f)) {
    for (int x = 0; x < w; ++x) out[x] = 0.0f;
    return;
  }
  const float* vr[3];
  for (int dy = -1; dy <= 1; ++dy) {
    const int qy = y + dy;
    vr[dy + 1] = qy < 0 || qy >= h ? nullptr : a.var_in + size_t(qy) * w;
  }
  auto k_of = [](int dx, int dy) { return (dx == 0 ? 0.5f : 0.25f) * (dy == 0 ? 0.5f : 0.25f); };
  auto one = [&](int x) {
    float s = 0.0f;
    for (int dy = -1; dy <= 1; ++dy) {
      if (!vr[dy + 1]) continue;
      for (int dx = -1; dx <= 1; ++dx)
        if (x + dx >= 0 && x + dx < w) s += k_of(dx, dy) * vr[dy + 1][x + dx];
    }
    out[x] = s;
  };
  int x = 0;
  if (w > 0) one(x++);
  for (; x + n <= w - 1; x += n) {
    T s = T{};
    for (int dy = -1; dy <= 1; ++dy) {
      if (!vr[dy + 1]) continue;
      for (int dx = -1; dx <= 1; ++dx) s = s + k_of(dx, dy) * L::load(vr[dy + 1] + x + dx);
    }
    L::store(out + x, s);
  }
  for (; x < w; ++x) one(x);
  x = 0;
  // inv_valid_k is read here alone, a row per row: fetch the next row's while this one is
  // computed (else each of its cache lines is a stall).
  const bool next = y + 1 < h;
  for (; x + n <= w; x += n) {
    if (next) __builtin_prefetch(a.inv_valid_k + row + size_t(w) + x);
    inv_phi_l_lanes<L>(out + x, a.inv_valid_k + row + x, a.sigma_l, a.eps_l, out + x);
  }
  for (; x + kLanes <= w; x += kLanes)
    inv_phi_l_lanes<VectorLane>(out + x, a.inv_valid_k + row + x, a.sigma_l, a.eps_l, out + x);
  for (; x < w; ++x) inv_phi_l_lanes<ScalarLane>(out + x, a.inv_valid_k + row + x, a.sigma_l, a.eps_l, out + x);
}

// Rows [y0, y1) of one a-trous iteration; acc holds 4 * width floats of scratch (need not be
// initialised). The interior blocks by Path's kernel: kPortable (atrous_block, 8 lanes), kAvx2
// (atrous_block8_unrolled) or kAvx512 (16 lanes where it can, the rest 8 at a time); the same
// bits on each.
enum AtrousPath { kPortable, kAvx2, kAvx512 };
template <int K, int Path, bool F>
DHR_ALWAYS_INLINE void atrous_rows_impl(const AtrousArgs& a, int y0, int y1, float* acc) {
  const int w = a.width, h = a.height, r = a.radius, step = a.step;
  float hk[5][5] = {}, inv_len[5][5] = {};
  for (int ty = -r; ty <= r; ++ty)
    for (int tx = -r; tx <= r; ++tx) {
      hk[ty + 2][tx + 2] = a.k1d[tx] * a.k1d[ty];
      inv_len[ty + 2][tx + 2] =
          (tx == 0 && ty == 0) ? 0.0f : 1.0f / (float(step) * std::sqrt(float(tx * tx + ty * ty)));
    }
  // The 16-lane kernel takes whole rows (atrous_row16_all, rows of 16 pixels or more). Otherwise
  // interior blocks [xl, xm) use atrous_block; the borders [0, xl) and [xm, w) the row-wise taps.
  const int xl = std::min(r * step, w);
  const int interior_end = std::max(xl, w - r * step);
  const int xm = xl + (interior_end - xl) / kLanes * kLanes;
  const uint8_t ac = a.active_cls;
  for (int y = y0; y < y1; ++y) {
    const size_t row = size_t(y) * size_t(w);
    const uint8_t* cls = a.cls ? a.cls + row : nullptr;
    if (cls && std::memchr(cls, ac, size_t(w)) == nullptr) {  // nothing to filter in this row
      if (a.u8_out)
        for (int x = 0; x < w; ++x) a.u8_out[row + x] = to_u8(a.v_out[row + x]);
      continue;
    }
    AtrousTapPlanes p;
    p.sw = acc;
    p.sl = acc + w;
    p.sv = acc + 2 * w;
    const float* ipl_row = a.inv_phi_l ? a.inv_phi_l + row : acc + 3 * w;
    if (!a.inv_phi_l)
      inv_phi_l_of_row<std::conditional_t<Path == kAvx512, VectorLane16, VectorLane>>(a, y, acc + 3 * w);
    int xb = xl;
#if DHR_DENOISE_AVX512
    if constexpr (Path == kAvx512) {
      if (w >= kLanes16) {  // the whole row, finished (shorter rows: the 8-lane blocks and taps below)
        const bool var = a.var_out != nullptr;
        if (r == 2)
          (var ? atrous_row16_all<K, 2, F, true> : atrous_row16_all<K, 2, F, false>)(a, y, cls, ipl_row, hk, inv_len);
        else
          (var ? atrous_row16_all<K, 1, F, true> : atrous_row16_all<K, 1, F, false>)(a, y, cls, ipl_row, hk, inv_len);
        continue;
      }
    }
    if constexpr (Path == kAvx2 && !F) {
      if (r == 2)
        atrous_blocks8<K, 2>(a, y, xb, xm, cls, ipl_row, hk, inv_len, p.sw, p.sl, p.sv);
      else
        atrous_blocks8<K, 1>(a, y, xb, xm, cls, ipl_row, hk, inv_len, p.sw, p.sl, p.sv);
      xb = xm;
    }
#endif
    // The interior's 8-pixel blocks, then the row's ends tap by tap.
    for (; xb < xm; xb += kLanes)
      if (!cls || block_has(cls, xb, kLanes, ac))
        atrous_block<K, VectorLane, F>(a, y, xb, ipl_row, hk, inv_len, p.sw + xb, p.sl + xb, p.sv + xb);
    const float hc = a.k1d[0] * a.k1d[0];
    for (int x = 0; x < w; ++x) {  // centre tap of the border pixels: weight h_c
      if (x == xl) x = xm;
      if (x >= w) break;
      p.sw[x] = hc;
      p.sl[x] = hc * a.v_in[row + x];
      p.sv[x] = (hc * hc) * a.var_in[row + x];
    }
    p.zc = a.depth + row;
    p.ncx = a.nx + row;
    p.ncy = a.ny + row;
    p.ncz = a.nz + row;
    p.ipz = a.inv_phi_z + row;
    p.ipl = ipl_row;
    p.lc = a.v_in + row;
    for (int ty = -r; ty <= r; ++ty) {
      const int qy = y + ty * step;
      if (qy < 0 || qy >= h) continue;
      const size_t qrow = size_t(qy) * size_t(w);
      p.zq = a.depth + qrow;
      p.nqx = a.nx + qrow;
      p.nqy = a.ny + qrow;
      p.nqz = a.nz + qrow;
      p.lq = a.v_in + qrow;
      p.vq = a.var_in + qrow;
      for (int tx = -r; tx <= r; ++tx) {
        if (tx == 0 && ty == 0) continue;
        const int off = tx * step;
        const float hkv = hk[ty + 2][tx + 2], il = inv_len[ty + 2][tx + 2];
        for (int part = 0; part < 2; ++part) {  // the two border ranges
          const int lo = std::max(part == 0 ? 0 : xm, -off), hi = std::min(part == 0 ? xl : w, w - off);
          int x = lo;
          for (; x + kLanes <= hi; x += kLanes)
            atrous_tap<K, VectorLane, F>(p, x, x + off, hkv, il, a.normal_squarings);
          for (; x < hi; ++x) atrous_tap<K, ScalarLane, F>(p, x, x + off, hkv, il, a.normal_squarings);
        }
      }
    }
    for (int x = 0; x < w; ++x) {
      const size_t i = row + x;
      if (cls && cls[x] != ac) {
        if (a.u8_out) a.u8_out[i] = to_u8(a.v_out[i]);
        continue;
      }
      float v, var;
      if (!a.valid[i]) {
        v = a.v_in[i];
        var = 0.0f;
      } else {
        const float inv = 1.0f / p.sw[x];  // sw >= h_c > 0 at a valid pixel
        v = std::clamp(p.sl[x] * inv, 0.0f, 1.0f);
        var = std::max(0.0f, p.sv[x] * inv * inv);
      }
      a.v_out[i] = v;
      if (a.var_out) a.var_out[i] = var;
      if (a.v_out2) a.v_out2[i] = v;
      if (a.v_out3) a.v_out3[i] = v;
      if (a.var_out && a.var_out2) a.var_out2[i] = var;
      if (a.u8_out) a.u8_out[i] = to_u8(v);
    }
  }
}

// One entry per path: the normal power compiled in or not, the fast weights or not.
template <int Path, bool F>
DHR_ALWAYS_INLINE void atrous_rows_path(const AtrousArgs& a, int y0, int y1, float* acc) {
  if (a.normal_squarings == kDefaultSquarings)
    atrous_rows_impl<kDefaultSquarings, Path, F>(a, y0, y1, acc);
  else
    atrous_rows_impl<-1, Path, F>(a, y0, y1, acc);
}

DHR_DENOISE_TARGETS
void atrous_rows_8(const AtrousArgs& a, int y0, int y1, float* acc) {
  if (a.fast_weights)
    atrous_rows_path<kPortable, true>(a, y0, y1, acc);
  else
    atrous_rows_path<kPortable, false>(a, y0, y1, acc);
}

#if DHR_DENOISE_AVX512
DHR_DENOISE_TARGET_AVX2
void atrous_rows_avx2(const AtrousArgs& a, int y0, int y1, float* acc) {
  atrous_rows_path<kAvx2, false>(a, y0, y1, acc);
}

// The fast weights on AVX2: the portable 8-lane blocks with FMA instructions.
DHR_DENOISE_TARGET_AVX2_FMA
void atrous_rows_avx2_fma(const AtrousArgs& a, int y0, int y1, float* acc) {
  atrous_rows_path<kPortable, true>(a, y0, y1, acc);
}

DHR_DENOISE_TARGET_AVX512
void atrous_rows_16(const AtrousArgs& a, int y0, int y1, float* acc) {
  if (a.fast_weights)
    atrous_rows_path<kAvx512, true>(a, y0, y1, acc);
  else
    atrous_rows_path<kAvx512, false>(a, y0, y1, acc);
}
#endif

// ---- The spatial moments (MomentArgs, filters.h).

template <int K, class L>
DHR_ALWAYS_INLINE void moment_tap(const MomentArgs& a, size_t row, size_t qrow, int x, int dx, float inv_len, float* a0,
                                  float* a1, float* a2) {
  using T = typename L::T;
  const size_t c = row + size_t(x), q = qrow + size_t(x + dx);
  const T d = L::load(a.nx + c) * L::load(a.nx + q) + L::load(a.ny + c) * L::load(a.ny + q) +
              L::load(a.nz + c) * L::load(a.nz + q);
  const T wn = pow_2k<K>(d, a.normal_squarings);
  const T wz = abs_f(L::load(a.depth + c) - L::load(a.depth + q)) * L::load(a.inv_phi_z + c) * inv_len;
  const T wgt = wn * exp_neg(-wz);
  const T v1 = L::load(a.m1 + q);
  const T v2 = a.m2 ? L::load(a.m2 + q) : v1 * v1;
  L::store(a0, L::load(a0) + wgt);
  L::store(a1, L::load(a1) + wgt * v1);
  L::store(a2, L::load(a2) + wgt * v2);
}

// acc: 3 * (xb - xa + 1) floats, zeroed by the caller: sum w, sum w m1, sum w m2. Wide: 16
// lanes at a time first (AVX-512).
template <int K, bool Wide>
DHR_ALWAYS_INLINE void moment_span_impl(const MomentArgs& a, int y, int xa, int xb, float* acc) {
  const int w = a.width, h = a.height, r = a.radius, n = xb - xa + 1;
  const size_t row = size_t(y) * size_t(w);
  for (int dy = -r; dy <= r; ++dy) {
    const int qy = y + dy;
    if (qy < 0 || qy >= h) continue;
    const size_t qrow = size_t(qy) * size_t(w);
    for (int dx = -r; dx <= r; ++dx) {
      const int lo = std::max(xa, -dx), hi = std::min(xb + 1, w - dx);  // x + dx in [0, w)
      if (lo >= hi) continue;
      const float inv_len = (dx == 0 && dy == 0) ? 0.0f : 1.0f / std::sqrt(float(dx * dx + dy * dy));
      int x = lo;
      if constexpr (Wide)
        for (; x + kLanes16 <= hi; x += kLanes16)
          moment_tap<K, VectorLane16>(a, row, qrow, x, dx, inv_len, acc + (x - xa), acc + n + (x - xa),
                                      acc + 2 * n + (x - xa));
      for (; x + kLanes <= hi; x += kLanes)
        moment_tap<K, VectorLane>(a, row, qrow, x, dx, inv_len, acc + (x - xa), acc + n + (x - xa),
                                  acc + 2 * n + (x - xa));
      for (; x < hi; ++x)
        moment_tap<K, ScalarLane>(a, row, qrow, x, dx, inv_len, acc + (x - xa), acc + n + (x - xa),
                                  acc + 2 * n + (x - xa));
    }
  }
}

DHR_DENOISE_TARGETS
void moment_span_8(const MomentArgs& a, int y, int xa, int xb, float* acc) {
  if (a.normal_squarings == kDefaultSquarings)
    moment_span_impl<kDefaultSquarings, false>(a, y, xa, xb, acc);
  else
    moment_span_impl<-1, false>(a, y, xa, xb, acc);
}

#if DHR_DENOISE_AVX512
DHR_DENOISE_TARGET_AVX512
void moment_span_16(const MomentArgs& a, int y, int xa, int xb, float* acc) {
  if (a.normal_squarings == kDefaultSquarings)
    moment_span_impl<kDefaultSquarings, true>(a, y, xa, xb, acc);
  else
    moment_span_impl<-1, true>(a, y, xa, xb, acc);
}
#endif

}  // namespace

namespace {
std::atomic<bool> g_portable_only{false};
}  // namespace

void force_portable_kernels(bool on) { g_portable_only.store(on, std::memory_order_relaxed); }

bool cpu_has_avx512() {
#if DHR_DENOISE_AVX512
  static const bool has = __builtin_cpu_supports("avx512f") && kernels_may_use(Isa::kAvx512);  // core/base/cpu_isa.h
  return has && !g_portable_only.load(std::memory_order_relaxed);
#else
  return false;
#endif
}

bool cpu_has_avx2() {
#if DHR_DENOISE_AVX512
  static const bool has = __builtin_cpu_supports("avx2") && kernels_may_use(Isa::kAvx2);
  return has && !g_portable_only.load(std::memory_order_relaxed);
#else
  return false;
#endif
}

void atrous_rows(const AtrousArgs& a, int y0, int y1, float* acc, bool fastest) {
#if DHR_DENOISE_AVX512
  if (fastest && cpu_has_avx512()) return atrous_rows_16(a, y0, y1, acc);
  if (fastest && cpu_has_avx2()) {
    if (!a.fast_weights) return atrous_rows_avx2(a, y0, y1, acc);
    static const bool has_fma = __builtin_cpu_supports("fma");
    if (has_fma) return atrous_rows_avx2_fma(a, y0, y1, acc);
  }
#else
  (void)fastest;
#endif
  atrous_rows_8(a, y0, y1, acc);
}

void moment_span(const MomentArgs& a, int y, int xa, int xb, float* acc, bool use_avx512) {
#if DHR_DENOISE_AVX512
  if (use_avx512 && cpu_has_avx512()) return moment_span_16(a, y, xa, xb, acc);
#else
  (void)use_avx512;
#endif
  moment_span_8(a, y, xa, xb, acc);
}

}  // namespace dhr::denoise
