// Shared kernels of the SVGF-family denoisers (svgf_ao, atrous, single_iteration, temporal):
// G-buffer sanitising, temporal accumulation with reprojection, moment-based and spatial
// variance estimates, and the edge-aware a-trous wavelet pass. After Schied et al. 2017,
// "Spatiotemporal Variance-Guided Filtering" (SVGF), as modified for ambient occlusion in the
// DHR-S paper, section 3.3 (see svgf_ao.cpp for how that modification is read).
//
// Everything works on float32 planes in [0, 1] (1 = unoccluded / fully visible). Each pass is
// a parallel loop over rows whose rows are computed independently (no reductions across
// threads), so results are bit-identical for any thread count. The hot loops (a-trous taps,
// spatial moments, variance prefilter) are explicit 8-wide vectors with scalar tails doing the
// same operations, cloned for AVX2 and the baseline (same bits on both); exp and 1/sqrt are
// the polynomial / Newton versions below, identical on every machine; invalid neighbours are
// removed by their zero normal (weight exactly 0) rather than by a test.
//
// Cost at 1280x720 (tests/bench_denoise.cpp): a-trous dominates (5 iterations x 24 taps per
// pixel). Centre values and sums of 8 pixels (16 with AVX-512) stay in registers across the
// 24 taps; the normal power is 7 squarings (sigma_n = 128 is compiled in; other powers of two
// loop). Where the CPU has AVX-512 the a-trous and spatial-moment kernels take 16 lanes
// (picked at run time; the same bits as 8 lanes, tests/test_denoisers.cpp checks it): svgf_ao
// went from 189 to 131 CPU ms per frame on a 2-vCPU Zen 5 (room, 1280x720; bench_denoise).
//
// Internal to backends/denoise/: not a public API.
#pragma once

#include "core/backend.h"
#include "core/error.h"
#include "core/gbuffer.h"
#include "core/image.h"
#include "core/params.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <utility>
#include <vector>

namespace dhr::denoise {

// ---------------------------------------------------------------- scalar helpers

// The hot loops are written once over a "lane" type: ScalarLane (float) or VectorLane
// (VecF, 8 floats, GCC/Clang vector extensions). Explicit vectors because the compiler will
// not if-convert the clamps below under the default -ftrapping-math, so the loops would stay
// scalar. Lane for lane the operations are those of the scalar version (no FMA on either
// target), so a pixel gets the same bits whether it falls in a vector block or in a scalar
// tail, and whichever instruction set the kernel is cloned for (DHR_DENOISE_TARGETS: AVX2 where
// the CPU has it, else the baseline; same results).
// -Wpsabi off for the rest of the including file (only the denoise backends include this):
// the 32-byte vectors only reach always-inlined helpers, so no call ever passes one, but GCC
// reports it at the end of the translation unit, after any diagnostic pop.
#pragma GCC diagnostic ignored "-Wpsabi"

#define DHR_ALWAYS_INLINE __attribute__((always_inline)) inline
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__AVX2__) && \
    !defined(__SANITIZE_ADDRESS__)
#define DHR_DENOISE_TARGETS __attribute__((target_clones("avx2", "default")))
// The a-trous rows and spatial moments also have a 16-wide AVX-512 version, chosen at run time
// (atrous_rows, moment_span).
// AVX-512F brings its own FMA instructions, which GCC would contract a * b + c into under its
// default -ffp-contract=fast: fp-contract=off keeps every product and sum rounded separately,
// so the 16-wide kernel gives the bits of the 8-wide and scalar ones.
#define DHR_DENOISE_AVX512 1
#define DHR_DENOISE_TARGET_AVX512 __attribute__((target("avx512f"), optimize("fp-contract=off")))
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

// e^x for x <= 0 (larger x is clamped to 0), relative error below 5e-5 (plenty for filter
// weights); exactly 0 below -60 (e^-60 < 1e-26: a weight that small changes nothing). Split
// x log2(e) = i + f with i rounded to nearest, f in [-0.5, 0.5]; 2^f by its degree-4 Taylor
// polynomial; 2^i added to the exponent bits.
DHR_ALWAYS_INLINE float exp_neg(float x) {
  const float xc = x < -60.0f ? -60.0f : (x > 0.0f ? 0.0f : x);
  const float t = xc * 1.44269504f;
  const int32_t i = int32_t(t - 0.5f);  // t - 0.5 < 0: truncation rounds t to nearest
  const float f = t - float(i);
  float p = 9.6181291e-3f;
  p = p * f + 5.5504109e-2f;
  p = p * f + 2.4022651e-1f;
  p = p * f + 6.9314718e-1f;
  p = p * f + 1.0f;
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
  V p = V{} + 9.6181291e-3f;
  p = p * f + 5.5504109e-2f;
  p = p * f + 2.4022651e-1f;
  p = p * f + 6.9314718e-1f;
  p = p * f + 1.0f;
  const V r = (V)((VI)p + (VI)((VU)i << 23));
  return x < lo ? zero : r;
}
DHR_ALWAYS_INLINE VecF exp_neg(VecF x) { return exp_neg_lanes<VecF, VecI, VecU>(x); }
DHR_ALWAYS_INLINE VecF16 exp_neg(VecF16 x) { return exp_neg_lanes<VecF16, VecI16, VecU16>(x); }

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

// ---- The a-trous tap, on a whole row at once for one tap offset.
struct AtrousArgs {
  int width = 0, height = 0, step = 1, radius = 2, normal_squarings = 7;
  const float* k1d = nullptr;  // k1d[-radius..radius]
  const float *depth = nullptr, *nx = nullptr, *ny = nullptr, *nz = nullptr;
  const uint8_t* valid = nullptr;
  const float *inv_phi_z = nullptr, *inv_phi_l = nullptr;
  const float *v_in = nullptr, *var_in = nullptr;
  float *v_out = nullptr, *var_out = nullptr;
};

struct AtrousTapPlanes {
  const float *zc, *ncx, *ncy, *ncz, *ipz, *ipl, *lc;  // centre row, indexed by x
  const float *zq, *nqx, *nqy, *nqz, *lq, *vq;         // neighbour row, indexed by x + off
  float *sw, *sl, *sv;                                  // accumulators, indexed by x
};

template <int K, class L>
DHR_ALWAYS_INLINE void atrous_tap(const AtrousTapPlanes& p, int x, int q, float hk, float inv_len, int nsq) {
  using T = typename L::T;
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
template <int K, class L>
DHR_ALWAYS_INLINE void atrous_block(const AtrousArgs& a, int y, int x, const float (*hk)[5], const float (*inv_len)[5],
                                    float* sw_out, float* sl_out, float* sv_out) {
  using T = typename L::T;
  const int r = a.radius, step = a.step, nsq = a.normal_squarings;
  const size_t c = size_t(y) * size_t(a.width) + size_t(x);
  const T zc = L::load(a.depth + c), ncx = L::load(a.nx + c), ncy = L::load(a.ny + c), ncz = L::load(a.nz + c);
  const T ipz = L::load(a.inv_phi_z + c), ipl = L::load(a.inv_phi_l + c), lc = L::load(a.v_in + c);
  const float hc = a.k1d[0] * a.k1d[0];
  T sw = T{} + hc;
  T sl = hc * lc;
  T sv = (hc * hc) * L::load(a.var_in + c);
  for (int ty = -r; ty <= r; ++ty) {
    const int qy = y + ty * step;
    if (qy < 0 || qy >= a.height) continue;
    const size_t qrow = size_t(qy) * size_t(a.width) + size_t(x);
    for (int tx = -r; tx <= r; ++tx) {
      if (tx == 0 && ty == 0) continue;
      const size_t q = qrow + size_t(tx * step);  // x + tx step >= 0 here
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

// Rows [y0, y1) of one a-trous iteration; acc holds 3 * width floats of scratch. Wide: the
// interior is done 16 pixels at a time where it can (AVX-512), the rest 8 at a time.
template <int K, bool Wide>
DHR_ALWAYS_INLINE void atrous_rows_impl(const AtrousArgs& a, int y0, int y1, float* acc) {
  const int w = a.width, h = a.height, r = a.radius, step = a.step;
  float hk[5][5] = {}, inv_len[5][5] = {};
  for (int ty = -r; ty <= r; ++ty)
    for (int tx = -r; tx <= r; ++tx) {
      hk[ty + 2][tx + 2] = a.k1d[tx] * a.k1d[ty];
      inv_len[ty + 2][tx + 2] =
          (tx == 0 && ty == 0) ? 0.0f : 1.0f / (float(step) * std::sqrt(float(tx * tx + ty * ty)));
    }
  // Interior blocks [xl, xm) use atrous_block; the borders [0, xl) and [xm, w) the row-wise taps.
  const int xl = std::min(r * step, w);
  const int interior_end = std::max(xl, w - r * step);
  const int xm = xl + (interior_end - xl) / kLanes * kLanes;
  for (int y = y0; y < y1; ++y) {
    const size_t row = size_t(y) * size_t(w);
    AtrousTapPlanes p;
    p.sw = acc;
    p.sl = acc + w;
    p.sv = acc + 2 * w;
    int xb = xl;
    if constexpr (Wide)
      for (; xb + kLanes16 <= xm; xb += kLanes16)
        atrous_block<K, VectorLane16>(a, y, xb, hk, inv_len, p.sw + xb, p.sl + xb, p.sv + xb);
    for (; xb < xm; xb += kLanes)
      atrous_block<K, VectorLane>(a, y, xb, hk, inv_len, p.sw + xb, p.sl + xb, p.sv + xb);
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
    p.ipl = a.inv_phi_l + row;
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
          for (; x + kLanes <= hi; x += kLanes) atrous_tap<K, VectorLane>(p, x, x + off, hkv, il, a.normal_squarings);
          for (; x < hi; ++x) atrous_tap<K, ScalarLane>(p, x, x + off, hkv, il, a.normal_squarings);
        }
      }
    }
    for (int x = 0; x < w; ++x) {
      const size_t i = row + x;
      if (!a.valid[i]) {
        a.v_out[i] = a.v_in[i];
        a.var_out[i] = 0.0f;
        continue;
      }
      const float inv = 1.0f / p.sw[x];  // sw >= h_c > 0 at a valid pixel
      a.v_out[i] = std::clamp(p.sl[x] * inv, 0.0f, 1.0f);
      a.var_out[i] = std::max(0.0f, p.sv[x] * inv * inv);
    }
  }
}

DHR_DENOISE_TARGETS
static void atrous_rows_8(const AtrousArgs& a, int y0, int y1, float* acc) {
  if (a.normal_squarings == kDefaultSquarings)
    atrous_rows_impl<kDefaultSquarings, false>(a, y0, y1, acc);
  else
    atrous_rows_impl<-1, false>(a, y0, y1, acc);
}

#if DHR_DENOISE_AVX512
DHR_DENOISE_TARGET_AVX512
static void atrous_rows_16(const AtrousArgs& a, int y0, int y1, float* acc) {
  if (a.normal_squarings == kDefaultSquarings)
    atrous_rows_impl<kDefaultSquarings, true>(a, y0, y1, acc);
  else
    atrous_rows_impl<-1, true>(a, y0, y1, acc);
}
#endif

// The a-trous rows with the widest vectors the CPU has (same bits either way: see
// DHR_DENOISE_TARGET_AVX512). use_avx512 = false forces the 8-wide kernel (tests compare them).
inline bool cpu_has_avx512() {
#if DHR_DENOISE_AVX512
  static const bool has = __builtin_cpu_supports("avx512f");
  return has;
#else
  return false;
#endif
}

inline void atrous_rows(const AtrousArgs& a, int y0, int y1, float* acc, bool use_avx512 = true) {
#if DHR_DENOISE_AVX512
  if (use_avx512 && cpu_has_avx512()) return atrous_rows_16(a, y0, y1, acc);
#else
  (void)use_avx512;
#endif
  atrous_rows_8(a, y0, y1, acc);
}

// ---- AO phi of the a-trous weight: ipl = valid / (sigma_l sqrt(var) + eps), var = the 3x3
// Gaussian of the variance over valid pixels (sum k var / sum k valid).
template <class L>
DHR_ALWAYS_INLINE void inv_phi_l_lanes(const float* sum_kv, const float* inv_valid_k, const float* valid_f, float sigma_l,
                                       float eps, float* out) {
  using T = typename L::T;
  // 1/sqrt by the bit trick and two Newton steps (relative error < 1e-5); the floor keeps
  // the steps finite (sqrt(1e-20) = 1e-10 is far below eps).
  T v = L::load(sum_kv) * L::load(inv_valid_k);
  v = v < T{} + 1e-20f ? T{} + 1e-20f : v;
  T y;
  if constexpr (std::is_same_v<T, float>) {
    y = std::bit_cast<float>(int32_t(0x5f3759df) - (std::bit_cast<int32_t>(v) >> 1));
  } else {
    y = (VecF)(int32_t(0x5f3759df) - ((VecI)v >> 1));
  }
  y = y * (1.5f - 0.5f * v * y * y);
  y = y * (1.5f - 0.5f * v * y * y);
  L::store(out, L::load(valid_f) / (sigma_l * (v * y) + eps));
}

DHR_DENOISE_TARGETS
static void inv_phi_l_row(const float* sum_kv, const float* inv_valid_k, const float* valid_f, float sigma_l, float eps,
                          int w, float* out) {
  int x = 0;
  for (; x + kLanes <= w; x += kLanes)
    inv_phi_l_lanes<VectorLane>(sum_kv + x, inv_valid_k + x, valid_f + x, sigma_l, eps, out + x);
  for (; x < w; ++x) inv_phi_l_lanes<ScalarLane>(sum_kv + x, inv_valid_k + x, valid_f + x, sigma_l, eps, out + x);
}

// ---- The spatial moments of one row span [xa, xb] in a (2r+1)^2 window, weighted by depth
// and normal only (DHR-S 3.3).
struct MomentArgs {
  int width = 0, height = 0, radius = 3, normal_squarings = 7;
  const float *depth = nullptr, *nx = nullptr, *ny = nullptr, *nz = nullptr, *inv_phi_z = nullptr;
  const float* m1 = nullptr;
  const float* m2 = nullptr;  // null: m2 = m1^2 (one frame)
};

template <int K, class L>
DHR_ALWAYS_INLINE void moment_tap(const MomentArgs& a, size_t row, size_t qrow, int x, int dx, float inv_len,
                                  float* a0, float* a1, float* a2) {
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
        moment_tap<K, VectorLane>(a, row, qrow, x, dx, inv_len, acc + (x - xa), acc + n + (x - xa), acc + 2 * n + (x - xa));
      for (; x < hi; ++x)
        moment_tap<K, ScalarLane>(a, row, qrow, x, dx, inv_len, acc + (x - xa), acc + n + (x - xa), acc + 2 * n + (x - xa));
    }
  }
}

inline uint8_t to_u8(float v01) {
  float v = v01 * 255.0f + 0.5f;
  v = v >= 0.0f ? v : 0.0f;  // also maps NaN to 0
  v = v <= 255.0f ? v : 255.0f;
  return uint8_t(v);
}

// Row blocks come from tbb::simple_partitioner: it splits [0, height) by halving down to the
// grain, so the blocks depend on the height alone, never on the thread count or on timing.
// (Kernels that carry state across the rows of a block, like atrous_rows' accumulators, gave
// different roundings under the default auto_partitioner from one call to the next.)
template <class Body>
void parallel_rows(int height, Body&& body) {
  tbb::parallel_for(
      tbb::blocked_range<int>(0, height, 4),
      [&](const tbb::blocked_range<int>& r) {
        for (int y = r.begin(); y < r.end(); ++y) body(y);
      },
      tbb::simple_partitioner());
}

DHR_DENOISE_TARGETS
static void moment_span_8(const MomentArgs& a, int y, int xa, int xb, float* acc) {
  if (a.normal_squarings == kDefaultSquarings)
    moment_span_impl<kDefaultSquarings, false>(a, y, xa, xb, acc);
  else
    moment_span_impl<-1, false>(a, y, xa, xb, acc);
}

#if DHR_DENOISE_AVX512
DHR_DENOISE_TARGET_AVX512
static void moment_span_16(const MomentArgs& a, int y, int xa, int xb, float* acc) {
  if (a.normal_squarings == kDefaultSquarings)
    moment_span_impl<kDefaultSquarings, true>(a, y, xa, xb, acc);
  else
    moment_span_impl<-1, true>(a, y, xa, xb, acc);
}
#endif

// The spatial moments with the widest vectors the CPU has (same bits either way).
inline void moment_span(const MomentArgs& a, int y, int xa, int xb, float* acc, bool use_avx512 = true) {
#if DHR_DENOISE_AVX512
  if (use_avx512 && cpu_has_avx512()) return moment_span_16(a, y, xa, xb, acc);
#else
  (void)use_avx512;
#endif
  moment_span_8(a, y, xa, xb, acc);
}

// ---------------------------------------------------------------- the guide (G-buffer planes)

// The G-buffer as float planes, sanitised: a pixel is valid when it shows an object (id not
// kBackgroundId), its depth is finite and in (0, 1e30) and its normal is finite and of
// length 0.5..2 (renormalised). Invalid pixels get depth 0, normal (0, 0, 0) and id
// kBackgroundId, so a weight computed from them is 0 and nothing NaN ever enters a filter.
struct Guide {
  int width = 0;
  int height = 0;
  std::vector<float> depth, nx, ny, nz;
  std::vector<float> depth_grad;  // |dz/dx| + |dz/dy|, one-sided (smaller side): see build
  std::vector<uint32_t> id;
  std::vector<uint8_t> valid;

  void resize(int w, int h) {
    width = w;
    height = h;
    const size_t n = size_t(w) * size_t(h);
    for (auto* v : {&depth, &nx, &ny, &nz, &depth_grad}) v->assign(n, 0.0f);
    id.assign(n, kBackgroundId);
    valid.assign(n, 0);
  }
};

inline void build_guide(const GBuffer& g, Guide& out) {
  const int w = g.width(), h = g.height();
  if (!g.normal.same_size(w, h) || !g.object_id.same_size(w, h) || !g.motion.same_size(w, h))
    fail("denoiser: G-buffer planes differ in size (depth {}x{}, normal {}x{}, object_id {}x{}, motion {}x{})",
         w, h, g.normal.width(), g.normal.height(), g.object_id.width(), g.object_id.height(),
         g.motion.width(), g.motion.height());
  if (out.width != w || out.height != h) out.resize(w, h);
  parallel_rows(h, [&](int y) {
    for (int x = 0; x < w; ++x) {
      const size_t i = size_t(y) * w + x;
      const float z = g.depth[i];
      const glm::vec3 n = g.normal[i];
      const float len2 = n.x * n.x + n.y * n.y + n.z * n.z;
      const bool ok = g.object_id[i] != kBackgroundId && std::isfinite(z) && z > 0.0f && z < 1e30f &&
                      std::isfinite(len2) && len2 >= 0.25f && len2 <= 4.0f;
      const float inv_len = ok ? 1.0f / std::sqrt(len2) : 0.0f;
      out.valid[i] = ok ? 1 : 0;
      out.depth[i] = ok ? z : 0.0f;
      out.nx[i] = n.x * inv_len;  // inv_len is 0 when !ok: no NaN survives (n finite checked)
      out.ny[i] = n.y * inv_len;
      out.nz[i] = n.z * inv_len;
      if (!ok) out.nx[i] = out.ny[i] = out.nz[i] = 0.0f;
      out.id[i] = ok ? g.object_id[i] : kBackgroundId;
    }
  });
  // Depth gradient per pixel: in x and in y, the smaller one-sided difference to a valid
  // neighbour. SVGF uses the screen-space derivative fwidth(z); taking the smaller side keeps
  // a depth discontinuity from inflating the tolerance of the pixels right at the edge (which
  // would let the filter bleed across it).
  parallel_rows(h, [&](int y) {
    for (int x = 0; x < w; ++x) {
      const size_t i = size_t(y) * w + x;
      if (!out.valid[i]) continue;
      const float z = out.depth[i];
      auto side = [&](int xx, int yy) {
        if (xx < 0 || yy < 0 || xx >= w || yy >= h) return INFINITY;
        const size_t j = size_t(yy) * w + xx;
        return out.valid[j] ? std::fabs(out.depth[j] - z) : INFINITY;
      };
      const float gx = std::min(side(x - 1, y), side(x + 1, y));
      const float gy = std::min(side(x, y - 1), side(x, y + 1));
      out.depth_grad[i] = (std::isfinite(gx) ? gx : 0.0f) + (std::isfinite(gy) ? gy : 0.0f);
    }
  });
}

// ---------------------------------------------------------------- settings and parameters

struct FilterSettings {
  bool temporal = true;         // accumulate over frames (svgf_ao, single_iteration, temporal)
  int iterations = 5;           // a-trous iterations; 0 = no spatial filter (temporal)
  int kernel_radius = 2;        // 2: 5x5 B3-spline kernel; 1: 3x3 (1/4, 1/2, 1/4)
  float alpha = 0.2f;           // EMA weight of the new frame (value and moments)
  int history_cap = 32;         // history length is capped here (frames)
  float depth_tolerance = 0.1f;  // reprojection: |z_prev - z| <= tol * z
  float normal_threshold = 0.9f;  // reprojection: dot(n_prev, n) >= threshold
  float sigma_l = 4.0f;         // AO edge-stopping: |l_p - l_q| / (sigma_l sqrt(var) + eps); 0 = off
  int sigma_n = 128;            // normal edge-stopping: max(0, n_p . n_q)^sigma_n, a power of two
  float sigma_z = 1.0f;         // depth edge-stopping: |z_p - z_q| / (sigma_z |grad z| |offset|); 0 = off
  int variance_radius = 3;      // spatial variance window (2r + 1)^2 where history is short
  int min_history = 4;          // below this many frames the variance is estimated spatially
  bool feedback_filtered = true;  // history keeps the first a-trous iteration's output (SVGF)
};

inline std::vector<ParamSpec> temporal_param_specs() {
  return {
      ParamSpec::real("alpha", 0.2, 0.01, 1.0,
                      "weight of the new frame in the exponential moving average (value and moments)"),
      ParamSpec::integer("history_cap", 32, 1, 1024, "history length cap in frames (1/alpha reached earlier wins)"),
      ParamSpec::real("depth_tolerance", 0.1, 0.001, 1.0,
                      "reprojection: a previous tap is accepted when |z_prev - z| <= tolerance * z"),
      ParamSpec::real("normal_threshold", 0.9, -1.0, 1.0,
                      "reprojection: a previous tap is accepted when dot(n_prev, n) >= threshold"),
  };
}

inline std::vector<ParamSpec> spatial_param_specs(int default_iterations, int default_radius) {
  return {
      ParamSpec::integer("iterations", default_iterations, 1, 10, "a-trous iterations (step 2^i)"),
      ParamSpec::integer("kernel_radius", default_radius, 1, 2, "1: 3x3 kernel (1/4 1/2 1/4), 2: 5x5 B3-spline"),
      ParamSpec::real("sigma_l", 4.0, 0.0, 1000.0,
                      "AO edge-stopping: weight exp(-|l_p - l_q| / (sigma_l sqrt(var) + 1e-4)); 0 turns it off"),
      ParamSpec::integer("sigma_n", 128, 1, 1024,
                         "normal edge-stopping power: max(0, n_p . n_q)^sigma_n; a power of two (1, 2, 4, ..., 1024)"),
      ParamSpec::real("sigma_z", 1.0, 0.0, 1000.0,
                      "depth edge-stopping: exp(-|z_p - z_q| / (sigma_z |grad z| |offset|)); 0 turns it off"),
      ParamSpec::integer("variance_radius", 3, 1, 5,
                         "window radius of the spatial variance estimate (3: 7x7) used where history is short"),
  };
}

inline void read_temporal_params(const Params& p, FilterSettings& s) {
  s.alpha = float(p.get_float("alpha"));
  s.history_cap = p.get_int("history_cap");
  s.depth_tolerance = float(p.get_float("depth_tolerance"));
  s.normal_threshold = float(p.get_float("normal_threshold"));
}

// with_iterations = false for single_iteration, which has no "iterations" key.
inline void read_spatial_params(const Params& p, FilterSettings& s, bool with_iterations = true) {
  if (with_iterations) s.iterations = p.get_int("iterations");
  s.kernel_radius = p.get_int("kernel_radius");
  s.sigma_l = float(p.get_float("sigma_l"));
  s.sigma_n = p.get_int("sigma_n");
  if (!std::has_single_bit(unsigned(s.sigma_n)))
    fail("denoiser parameter sigma_n = {} must be a power of two (1, 2, 4, ..., 1024): the normal weight is "
         "computed by repeated squaring", s.sigma_n);
  s.sigma_z = float(p.get_float("sigma_z"));
  s.variance_radius = p.get_int("variance_radius");
}

// ---------------------------------------------------------------- the pipeline

// One frame: sanitise -> (temporal accumulation) -> variance -> a-trous iterations -> 8 bits.
class FilterPipeline {
 public:
  static constexpr float kEpsL = 1e-4f;  // added to sigma_l sqrt(var) (AO units, 1 = 1.0)

  explicit FilterPipeline(const FilterSettings& s) : s_(s) {}

  void reset() { history_ok_ = false; }

  void run(const DenoiseInput& in, ImageU8& out) {
    const int w = in.noisy.width(), h = in.noisy.height();
    if (in.full_scale < 1)
      fail("denoiser: full_scale {} is invalid (must be >= 1: the value that means 1.0)", in.full_scale);
    if (in.gbuf.width() != w || in.gbuf.height() != h)
      fail("denoiser: noisy image is {}x{} but the G-buffer is {}x{} (they must match)", w, h,
           in.gbuf.width(), in.gbuf.height());
    out.resize(w, h);
    if (w == 0 || h == 0) return;
    if (!in.history_valid || w != w_ || h != h_) history_ok_ = false;
    if (w != w_ || h != h_) allocate(w, h);
    build_guide(in.gbuf, guide_[cur_]);
    sanitize_input(in);
    if (s_.temporal)
      accumulate(in.gbuf.motion);
    else {
      std::fill(hist_[cur_].begin(), hist_[cur_].end(), 0.0f);  // every pixel: no history
      value_ = input_;
    }
    if (s_.iterations > 0) {
      estimate_variance();
      compute_valid_k();
    }

    // a-trous iterations, ping-ponging value/variance between the work planes.
    const float* v = value_.data();
    const float* var = var_.data();
    for (int it = 0; it < s_.iterations; ++it) {
      float* v_out = (it % 2 == 0) ? work_v_[0].data() : work_v_[1].data();
      float* var_out = (it % 2 == 0) ? work_var_[0].data() : work_var_[1].data();
      atrous_pass(v, var, 1 << it, v_out, var_out);
      if (it == 0 && s_.temporal && s_.feedback_filtered) {
        const Guide& g = guide_[cur_];
        auto& hv = hv_[cur_];
        parallel_rows(h, [&](int y) {
          for (int x = 0; x < w; ++x) {
            const size_t i = size_t(y) * w + x;
            if (g.valid[i]) hv[i] = v_out[i];
          }
        });
      }
      v = v_out;
      var = var_out;
    }
    const Guide& g = guide_[cur_];
    parallel_rows(h, [&](int y) {
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * w + x;
        out[i] = to_u8(g.valid[i] ? v[i] : input_[i]);
      }
    });
    history_ok_ = s_.temporal;
    cur_ ^= 1;
  }

  const FilterSettings& settings() const { return s_; }

 private:
  void allocate(int w, int h) {
    w_ = w;
    h_ = h;
    const size_t n = size_t(w) * size_t(h);
    for (auto* v : {&input_, &value_, &var_, &inv_phi_z_, &inv_phi_l_, &inv_valid_k_, &valid_f_, &work_v_[0],
                    &work_v_[1], &work_var_[0], &work_var_[1], &hv_[0], &hv_[1], &hm1_[0], &hm1_[1],
                    &hm2_[0], &hm2_[1], &hist_[0], &hist_[1], &hk_[0], &hk_[1]})
      v->assign(n, 0.0f);
    guide_[0].resize(w, h);
    guide_[1].resize(w, h);
    history_ok_ = false;
  }

  // Input to [0, 1]; values above full_scale count as full_scale.
  void sanitize_input(const DenoiseInput& in) {
    const int fs = in.full_scale;
    const float inv = 1.0f / float(fs);
    const int w = w_;
    parallel_rows(h_, [&](int y) {
      const uint8_t* src = in.noisy.data() + size_t(y) * w;
      float* dst = input_.data() + size_t(y) * w;
      for (int x = 0; x < w; ++x) {
        const int v = src[x] > fs ? fs : src[x];
        dst[x] = float(v) * inv;
      }
    });
  }

  // Temporal accumulation (SVGF section 4.1): reproject through the motion vector, bilinear
  // over the 2x2 previous taps that pass the depth, normal and object-id tests, renormalised;
  // EMA with weight max(alpha, 1/history) (a plain mean while the history is short).
  void accumulate(const ImageVec2& motion) {
    const int w = w_, h = h_;
    const Guide& g = guide_[cur_];
    const Guide& gp = guide_[cur_ ^ 1];
    const auto& pv = hv_[cur_ ^ 1];
    const auto& pm1 = hm1_[cur_ ^ 1];
    const auto& pm2 = hm2_[cur_ ^ 1];
    const auto& ph = hist_[cur_ ^ 1];
    const auto& pk = hk_[cur_ ^ 1];
    auto& nv = hv_[cur_];
    auto& nm1 = hm1_[cur_];
    auto& nm2 = hm2_[cur_];
    auto& nh = hist_[cur_];
    auto& nk = hk_[cur_];
    const bool have_history = history_ok_;
    const float cap = float(s_.history_cap);
    parallel_rows(h, [&](int y) {
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * w + x;
        const float c = input_[i];
        float len = 0.0f, pval = 0.0f, p1 = 0.0f, p2 = 0.0f, pkk = 0.0f;
        if (have_history && g.valid[i]) {
          const glm::vec2 m = motion[i];
          // Previous pixel centre of this surface point, in pixel-index coordinates.
          const float px = float(x) + m.x, py = float(y) + m.y;
          if (std::isfinite(px) && std::isfinite(py) && px > -2.0f && py > -2.0f && px < float(w) + 1.0f &&
              py < float(h) + 1.0f) {
            // floor by truncation: px, py > -2 here (std::floor is a libm call without SSE4.1)
            const int x0 = int(px + 2.0f) - 2, y0 = int(py + 2.0f) - 2;
            const float fx = px - float(x0), fy = py - float(y0);
            const float bw[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
            float sw = 0.0f;
            for (int k = 0; k < 4; ++k) {
              const int xx = x0 + (k & 1), yy = y0 + (k >> 1);
              if (xx < 0 || yy < 0 || xx >= w || yy >= h || bw[k] <= 0.0f) continue;
              const size_t j = size_t(yy) * w + xx;
              if (!gp.valid[j] || gp.id[j] != g.id[i] || ph[j] <= 0.0f) continue;
              if (std::fabs(gp.depth[j] - g.depth[i]) > s_.depth_tolerance * g.depth[i]) continue;
              const float d = gp.nx[j] * g.nx[i] + gp.ny[j] * g.ny[i] + gp.nz[j] * g.nz[i];
              if (d < s_.normal_threshold) continue;
              sw += bw[k];
              pval += bw[k] * pv[j];
              p1 += bw[k] * pm1[j];
              p2 += bw[k] * pm2[j];
              len += bw[k] * ph[j];
              pkk += bw[k] * pk[j];
            }
            if (sw >= 0.01f) {
              const float inv = 1.0f / sw;
              pval *= inv;
              p1 *= inv;
              p2 *= inv;
              len *= inv;
              pkk *= inv;
            } else {
              len = 0.0f;  // disoccluded: no usable history
            }
          }
        }
        if (len > 0.0f) {
          len = std::min(len + 1.0f, cap);
          const float a = std::max(s_.alpha, 1.0f / len);
          nv[i] = pval + a * (c - pval);
          nm1[i] = p1 + a * (c - p1);
          nm2[i] = p2 + a * (c * c - p2);
          nk[i] = (1.0f - a) * (1.0f - a) * pkk + a * a;
        } else {
          len = g.valid[i] ? 1.0f : 0.0f;
          nv[i] = c;
          nm1[i] = c;
          nm2[i] = c * c;
          nk[i] = 1.0f;
        }
        nh[i] = len;
        value_[i] = nv[i];
      }
    });
  }

  // Per-pixel variance of the AO signal: from the temporal moments where the history has at
  // least min_history frames, else spatially from the moments in a (2r+1)^2 window weighted by
  // depth and normal only (DHR-S section 3.3: no luminance term), boosted by 4/h as SVGF does
  // for young pixels. Without temporal accumulation (atrous) every pixel takes the spatial
  // path with h = 1 and the moments of the current frame.
  void estimate_variance() {
    const int w = w_, h = h_;
    const Guide& g = guide_[cur_];
    const auto& hl = hist_[cur_];
    const float* kf = s_.temporal ? hk_[cur_].data() : nullptr;  // null: k = 1 (one frame)
    const float* m1 = s_.temporal ? hm1_[cur_].data() : input_.data();
    const float* m2 = s_.temporal ? hm2_[cur_].data() : nullptr;  // null: m2 = input^2
    const int r = s_.variance_radius;
    const float min_h = float(s_.min_history);
    // Depth phi per pixel, shared with the a-trous passes.
    parallel_rows(h, [&](int y) {
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * w + x;
        // Floor: 1e-3 of the depth (a fronto-parallel plane has no gradient), and 1e-30 so
        // that 1/phi stays finite and 0 * (1/phi) is never NaN.
        const float phi = std::max(s_.sigma_z * std::max(g.depth_grad[i], 1e-3f * g.depth[i]), 1e-30f);
        inv_phi_z_[i] = (g.valid[i] && s_.sigma_z > 0.0f) ? std::min(1.0f / phi, 1e30f) : 0.0f;
      }
    });
    MomentArgs margs;
    margs.width = w;
    margs.height = h;
    margs.radius = r;
    margs.normal_squarings = normal_squarings();
    margs.depth = g.depth.data();
    margs.nx = g.nx.data();
    margs.ny = g.ny.data();
    margs.nz = g.nz.data();
    margs.inv_phi_z = inv_phi_z_.data();
    margs.m1 = m1;
    margs.m2 = m2;
    parallel_rows(h, [&](int y) {
      const size_t row = size_t(y) * w;
      int xa = w, xb = -1;  // the span of this row that needs the spatial estimate
      for (int x = 0; x < w; ++x) {
        const size_t i = row + x;
        const float mm1 = m1[i];
        const float mm2 = m2 ? m2[i] : mm1 * mm1;
        var_[i] = g.valid[i] ? std::max(0.0f, mm2 - mm1 * mm1) * (kf ? kf[i] : 1.0f) : 0.0f;
        if (g.valid[i] && hl[i] < min_h) {
          xa = std::min(xa, x);
          xb = std::max(xb, x);
        }
      }
      if (xb < xa) return;
      const int n = xb - xa + 1;
      std::vector<float> acc(size_t(n) * 3, 0.0f);
      moment_span(margs, y, xa, xb, acc.data());
      const float* a0 = acc.data();
      const float* a1 = a0 + n;
      const float* a2 = a1 + n;
      for (int x = xa; x <= xb; ++x) {
        const size_t i = row + x;
        if (!g.valid[i] || hl[i] >= min_h) continue;
        const float sw_ = a0[x - xa];
        if (!(sw_ > 0.0f)) continue;  // keeps the temporal estimate
        const float mean = a1[x - xa] / sw_;
        const float mean2 = a2[x - xa] / sw_;
        const float hh = std::max(hl[i], 1.0f);
        var_[i] = std::max(0.0f, mean2 - mean * mean) * (4.0f / hh) * (kf ? kf[i] : 1.0f);
      }
    });
  }

  // One edge-aware a-trous iteration (SVGF section 4.3, Dammertz et al. 2010): kernel h
  // (B3-spline 5x5 or 3x3) at step `step`, weight
  //   w = h * exp(-|z_p - z_q| / (sigma_z |grad z_p| step |offset|) - |l_p - l_q| / (sigma_l sqrt(g3x3(var_p)) + eps))
  //         * max(0, n_p . n_q)^sigma_n,
  // value = sum w l_q / sum w, variance = sum w^2 var_q / (sum w)^2.
  void atrous_pass(const float* v_in, const float* var_in, int step, float* v_out, float* var_out) {
    const int w = w_, h = h_;
    const Guide& g = guide_[cur_];
    // Variance prefiltered with a 3x3 Gaussian over valid pixels (SVGF), turned into the
    // AO phi per pixel. var_in is 0 at invalid pixels; valid_k_ holds the kernel mass of the
    // valid ones.
    if (s_.sigma_l > 0.0f) {
      parallel_rows(h, [&](int y) {
        const size_t row = size_t(y) * w;
        float* sv = inv_phi_l_.data() + row;
        for (int x = 0; x < w; ++x) sv[x] = 0.0f;
        for (int dy = -1; dy <= 1; ++dy) {
          const int qy = y + dy;
          if (qy < 0 || qy >= h) continue;
          const float* vq = var_in + size_t(qy) * w;
          for (int dx = -1; dx <= 1; ++dx) {
            const float k = (dx == 0 ? 0.5f : 0.25f) * (dy == 0 ? 0.5f : 0.25f);
            const int lo = std::max(0, -dx), hi = std::min(w, w - dx);
            for (int x = lo; x < hi; ++x) sv[x] += k * vq[x + dx];
          }
        }
        inv_phi_l_row(sv, inv_valid_k_.data() + row, valid_f_.data() + row, s_.sigma_l, kEpsL, w, sv);
      });
    } else {
      std::fill(inv_phi_l_.begin(), inv_phi_l_.end(), 0.0f);
    }
    static constexpr float kB3[5] = {1.0f / 16, 1.0f / 4, 3.0f / 8, 1.0f / 4, 1.0f / 16};
    static constexpr float k3[3] = {0.25f, 0.5f, 0.25f};
    AtrousArgs a;
    a.width = w;
    a.height = h;
    a.step = step;
    a.radius = s_.kernel_radius;
    a.normal_squarings = normal_squarings();
    a.k1d = a.radius == 2 ? kB3 + 2 : k3 + 1;
    a.depth = g.depth.data();
    a.nx = g.nx.data();
    a.ny = g.ny.data();
    a.nz = g.nz.data();
    a.valid = g.valid.data();
    a.inv_phi_z = inv_phi_z_.data();
    a.inv_phi_l = inv_phi_l_.data();
    a.v_in = v_in;
    a.var_in = var_in;
    a.v_out = v_out;
    a.var_out = var_out;
    tbb::parallel_for(
        tbb::blocked_range<int>(0, h, 4),
        [&](const tbb::blocked_range<int>& range) {
          std::vector<float> acc(size_t(w) * 3);
          atrous_rows(a, range.begin(), range.end(), acc.data());
        },
        tbb::simple_partitioner());  // blocks independent of threads and timing (see parallel_rows)
  }

  int normal_squarings() const { return std::countr_zero(unsigned(s_.sigma_n)); }

  // Kernel mass of the valid pixels in each 3x3 window (for the variance prefilter).
  void compute_valid_k() {
    const int w = w_, h = h_;
    const Guide& g = guide_[cur_];
    parallel_rows(h, [&](int y) {
      for (int x = 0; x < w; ++x) {
        float sk = 0.0f;
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const int xx = x + dx, yy = y + dy;
            if (xx < 0 || yy < 0 || xx >= w || yy >= h || !g.valid[size_t(yy) * w + xx]) continue;
            sk += (dx == 0 ? 0.5f : 0.25f) * (dy == 0 ? 0.5f : 0.25f);
          }
        const size_t i = size_t(y) * w + x;
        inv_valid_k_[i] = g.valid[i] ? 1.0f / sk : 0.0f;  // sk >= 0.25 when the centre is valid
        valid_f_[i] = g.valid[i] ? 1.0f : 0.0f;
      }
    });
  }

  FilterSettings s_;
  int w_ = -1, h_ = -1;
  int cur_ = 0;               // index of this frame's history/guide planes; cur_ ^ 1 = previous
  bool history_ok_ = false;   // the previous planes hold a usable frame
  Guide guide_[2];
  std::vector<float> input_, value_, var_, inv_phi_z_, inv_phi_l_, inv_valid_k_, valid_f_;
  std::vector<float> work_v_[2], work_var_[2];
  // History: value, moments, length, and the variance factor k of the accumulated value (the
  // variance of the EMA of independent samples is k times that of one sample).
  std::vector<float> hv_[2], hm1_[2], hm2_[2], hist_[2], hk_[2];
};

}  // namespace dhr::denoise
