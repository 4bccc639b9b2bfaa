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
// Around the taps, the passes are fused (FilterPipeline) and the guide is built 8 pixels at a
// time: temporal alone went from 34 to 26 CPU ms, the reset path from 9 to 4; the rest of a
// frame is memory-bound (the reprojection touches about 25 planes; on a cache-resident crop it
// is 5-7x faster per pixel). svgf_ao's light_history path (one 3x3 iteration where the history
// is long) takes a steady frame from about 140 to 40 CPU ms.
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
#if defined(__SSE__)
#include <xmmintrin.h>
#endif
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
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

// ---- The a-trous tap, on a whole row at once for one tap offset.
struct AtrousArgs {
  int width = 0, height = 0, step = 1, radius = 2, normal_squarings = 7;
  const float* k1d = nullptr;  // k1d[-radius..radius]
  const float *depth = nullptr, *nx = nullptr, *ny = nullptr, *nz = nullptr;
  const uint8_t* valid = nullptr;
  const float* inv_phi_z = nullptr;
  // The AO phi per pixel: given as a plane (inv_phi_l), or, when that is null, computed row by
  // row from var_in (3x3 Gaussian over valid pixels, inv_phi_l_lanes) with inv_valid_k, valid_f
  // and sigma_l (sigma_l = 0: no AO term, phi^-1 = 0). The a-trous taps read it at the centre
  // pixel only, so each row needs its own row alone (no extra pass over the image).
  const float* inv_phi_l = nullptr;
  const float *inv_valid_k = nullptr, *valid_f = nullptr;
  float sigma_l = 0.0f, eps_l = 1e-4f;
  const float *v_in = nullptr, *var_in = nullptr;
  float *v_out = nullptr, *var_out = nullptr;
  // Optional, all may be null. cls: pixels whose cls equals active_cls are filtered; the others
  // are left as they are in v_out / var_out (svgf_ao's light_history path: a pixel's result
  // never depends on which other pixels are filtered, nor on the vector width). Rows and vector
  // blocks without an active pixel are skipped.
  const uint8_t* cls = nullptr;
  uint8_t active_cls = 1;
  float *v_out2 = nullptr, *v_out3 = nullptr, *var_out2 = nullptr;  // copies of v_out / var_out
  uint8_t* u8_out = nullptr;  // the result in 0..255 (to_u8) of every pixel (inactive: of v_out as it is)
};

DHR_ALWAYS_INLINE uint8_t to_u8(float v01) {
  float v = v01 * 255.0f + 0.5f;
  v = v >= 0.0f ? v : 0.0f;  // also maps NaN to 0
  v = v <= 255.0f ? v : 255.0f;
  return uint8_t(v);
}

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
// ipl_row: the AO phi of row y, indexed by x.
template <int K, class L>
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

// The AO phi of row y into out (w floats), from var_in (see AtrousArgs::inv_phi_l). The 3x3
// sums are taken in the same order for every pixel (dy, then dx, from -1), starting from 0.
DHR_ALWAYS_INLINE void inv_phi_l_of_row(const AtrousArgs& a, int y, float* out) {
  const int w = a.width, h = a.height;
  const size_t row = size_t(y) * size_t(w);
  if (!(a.sigma_l > 0.0f)) {
    for (int x = 0; x < w; ++x) out[x] = 0.0f;
    return;
  }
  for (int x = 0; x < w; ++x) out[x] = 0.0f;
  for (int dy = -1; dy <= 1; ++dy) {
    const int qy = y + dy;
    if (qy < 0 || qy >= h) continue;
    const float* vq = a.var_in + size_t(qy) * w;
    for (int dx = -1; dx <= 1; ++dx) {
      const float k = (dx == 0 ? 0.5f : 0.25f) * (dy == 0 ? 0.5f : 0.25f);
      const int lo = std::max(0, -dx), hi = std::min(w, w - dx);
      for (int x = lo; x < hi; ++x) out[x] += k * vq[x + dx];
    }
  }
  int x = 0;
  for (; x + kLanes <= w; x += kLanes)
    inv_phi_l_lanes<VectorLane>(out + x, a.inv_valid_k + row + x, a.valid_f + row + x, a.sigma_l, a.eps_l, out + x);
  for (; x < w; ++x)
    inv_phi_l_lanes<ScalarLane>(out + x, a.inv_valid_k + row + x, a.valid_f + row + x, a.sigma_l, a.eps_l, out + x);
}

// Rows [y0, y1) of one a-trous iteration; acc holds 4 * width floats of scratch (need not be
// initialised). Wide: the interior is done 16 pixels at a time where it can (AVX-512), the
// rest 8 at a time.
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
    if (!a.inv_phi_l) inv_phi_l_of_row(a, y, acc + 3 * w);
    int xb = xl;
    if constexpr (Wide)
      for (; xb + kLanes16 <= xm; xb += kLanes16)
        if (!cls || block_has(cls, xb, kLanes16, ac))
          atrous_block<K, VectorLane16>(a, y, xb, ipl_row, hk, inv_len, p.sw + xb, p.sl + xb, p.sv + xb);
    for (; xb < xm; xb += kLanes)
      if (!cls || block_has(cls, xb, kLanes, ac))
        atrous_block<K, VectorLane>(a, y, xb, ipl_row, hk, inv_len, p.sw + xb, p.sl + xb, p.sv + xb);
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
          for (; x + kLanes <= hi; x += kLanes) atrous_tap<K, VectorLane>(p, x, x + off, hkv, il, a.normal_squarings);
          for (; x < hi; ++x) atrous_tap<K, ScalarLane>(p, x, x + off, hkv, il, a.normal_squarings);
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
      a.var_out[i] = var;
      if (a.v_out2) a.v_out2[i] = v;
      if (a.v_out3) a.v_out3[i] = v;
      if (a.var_out2) a.var_out2[i] = var;
      if (a.u8_out) a.u8_out[i] = to_u8(v);
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
  std::vector<float> valid_f;  // 1 at a valid pixel, else 0
  std::vector<uint32_t> id;
  std::vector<uint8_t> valid;

  void resize(int w, int h) {
    width = w;
    height = h;
    const size_t n = size_t(w) * size_t(h);
    for (auto* v : {&depth, &nx, &ny, &nz, &valid_f}) v->assign(n, 0.0f);
    id.assign(n, kBackgroundId);
    valid.assign(n, 0);
  }
};

// sqrt lane by lane (IEEE: correctly rounded, the bits of std::sqrt).
DHR_ALWAYS_INLINE VecF sqrt_lanes(VecF v) {
#if defined(__SSE__)
  __m128 lo, hi;
  std::memcpy(&lo, &v, 16);
  std::memcpy(&hi, reinterpret_cast<const char*>(&v) + 16, 16);
  lo = _mm_sqrt_ps(lo);
  hi = _mm_sqrt_ps(hi);
  std::memcpy(&v, &lo, 16);
  std::memcpy(reinterpret_cast<char*>(&v) + 16, &hi, 16);
  return v;
#else
  for (int l = 0; l < kLanes; ++l) v[l] = std::sqrt(v[l]);
  return v;
#endif
}

struct GuideRowArgs {
  const float* z;
  const glm::vec3* n;
  const uint32_t* id;
  Guide* out;
};

// One row of the guide: pixels [0, w) of row `row` (offset of the row's first pixel).
// 8 pixels at a time with the same IEEE operations as the scalar tail: "finite and in range"
// is tested by the range comparisons alone (NaN fails them, inf is out of range).
DHR_DENOISE_TARGETS
static void guide_row(const GuideRowArgs& a, size_t row, int w) {
  Guide& o = *a.out;
  int x = 0;
  for (; x + kLanes <= w; x += kLanes) {
    const size_t i = row + size_t(x);
    VecF z, nx, ny, nz;
    VecU id;
    std::memcpy(&z, a.z + i, sizeof z);
    std::memcpy(&id, a.id + i, sizeof id);
    for (int l = 0; l < kLanes; ++l) {
      nx[l] = a.n[i + size_t(l)].x;
      ny[l] = a.n[i + size_t(l)].y;
      nz[l] = a.n[i + size_t(l)].z;
    }
    const VecF len2 = nx * nx + ny * ny + nz * nz;
    const VecI ok = (id != VecU{}) & (z > VecF{}) & (z < splat(1e30f)) & (len2 >= splat(0.25f)) & (len2 <= splat(4.0f));
    const VecF inv_len = ok ? splat(1.0f) / sqrt_lanes(len2) : VecF{};
    const VecF zo = ok ? z : VecF{};
    const VecF nxo = ok ? nx * inv_len : VecF{}, nyo = ok ? ny * inv_len : VecF{}, nzo = ok ? nz * inv_len : VecF{};
    const VecU ido = ok ? id : VecU{};
    const VecF vf = ok ? splat(1.0f) : VecF{};
    std::memcpy(o.depth.data() + i, &zo, sizeof zo);
    std::memcpy(o.nx.data() + i, &nxo, sizeof nxo);
    std::memcpy(o.ny.data() + i, &nyo, sizeof nyo);
    std::memcpy(o.nz.data() + i, &nzo, sizeof nzo);
    std::memcpy(o.id.data() + i, &ido, sizeof ido);
    std::memcpy(o.valid_f.data() + i, &vf, sizeof vf);
    for (int l = 0; l < kLanes; ++l) o.valid[i + size_t(l)] = uint8_t(ok[l] & 1);
  }
  for (; x < w; ++x) {
    const size_t i = row + size_t(x);
    const float z = a.z[i];
    const glm::vec3 n = a.n[i];
    const float len2 = n.x * n.x + n.y * n.y + n.z * n.z;
    const bool ok = a.id[i] != kBackgroundId && z > 0.0f && z < 1e30f && len2 >= 0.25f && len2 <= 4.0f;
    const float inv_len = ok ? 1.0f / std::sqrt(len2) : 0.0f;
    o.valid[i] = ok ? 1 : 0;
    o.valid_f[i] = ok ? 1.0f : 0.0f;
    o.depth[i] = ok ? z : 0.0f;
    o.nx[i] = ok ? n.x * inv_len : 0.0f;
    o.ny[i] = ok ? n.y * inv_len : 0.0f;
    o.nz[i] = ok ? n.z * inv_len : 0.0f;
    o.id[i] = ok ? a.id[i] : kBackgroundId;
  }
}

inline void build_guide(const GBuffer& g, Guide& out) {
  const int w = g.width(), h = g.height();
  if (!g.normal.same_size(w, h) || !g.object_id.same_size(w, h) || !g.motion.same_size(w, h))
    fail("denoiser: G-buffer planes differ in size (depth {}x{}, normal {}x{}, object_id {}x{}, motion {}x{})",
         w, h, g.normal.width(), g.normal.height(), g.object_id.width(), g.object_id.height(),
         g.motion.width(), g.motion.height());
  if (out.width != w || out.height != h) out.resize(w, h);
  const GuideRowArgs a{g.depth.data(), g.normal.data(), g.object_id.data(), &out};
  parallel_rows(h, [&](int y) { guide_row(a, size_t(y) * size_t(w), w); });
}

// The per-pixel planes of the spatial filter that depend on the guide alone, for row y:
//  inv_phi_z = 1 / (sigma_z max(|grad z|, 1e-3 z)) (floored at 1e-30 before the inverse,
//    capped at 1e30 after), 0 at invalid pixels or with sigma_z = 0. |grad z| = |dz/dx| +
//    |dz/dy|, each the smaller one-sided difference to a valid neighbour (0 without one). SVGF
//    uses the screen-space derivative fwidth(z); taking the smaller side keeps a depth
//    discontinuity from inflating the tolerance of the pixels right at the edge (which would
//    let the filter bleed across it). Floor: 1e-3 of the depth (a fronto-parallel plane has no
//    gradient), and 1e-30 so that 1/phi stays finite and 0 * (1/phi) is never NaN.
//  inv_valid_k = 1 / (mass of the 3x3 Gaussian (1/4 1/2 1/4)^2 over the valid pixels), 0 at
//    invalid pixels (the variance prefilter of the a-trous passes). The masses are multiples
//    of 1/16 up to 1: exact in any order.
struct GuideSpatialArgs {
  const Guide* g;
  float sigma_z;
  float *inv_phi_z, *inv_valid_k;
};

template <class T>
DHR_ALWAYS_INLINE T min_lanes(T a, T b) {  // std::min(a, b) = b < a ? b : a, lane by lane
  return b < a ? b : a;
}

DHR_DENOISE_TARGETS
static void guide_spatial_row(const GuideSpatialArgs& a, int y) {
  const Guide& g = *a.g;
  const int w = g.width, h = g.height;
  const size_t row = size_t(y) * size_t(w);
  const float* z = g.depth.data() + row;
  const float* vf = g.valid_f.data() + row;
  const float* zu = y > 0 ? z - w : nullptr;
  const float* vu = y > 0 ? vf - w : nullptr;
  const float* zd = y + 1 < h ? z + w : nullptr;
  const float* vd = y + 1 < h ? vf + w : nullptr;
  float* ipz = a.inv_phi_z + row;
  float* ivk = a.inv_valid_k + row;
  const float sz = a.sigma_z;
  auto scalar = [&](int x) {
    const float zc = z[x];
    auto side = [&](const float* zr, const float* vr, int xx) {
      if (!zr || xx < 0 || xx >= w) return INFINITY;
      return vr[xx] != 0.0f ? std::fabs(zr[xx] - zc) : INFINITY;
    };
    const float gx = std::min(side(z, vf, x - 1), side(z, vf, x + 1));
    const float gy = std::min(side(zu, vu, x), side(zd, vd, x));
    const float grad = (gx < INFINITY ? gx : 0.0f) + (gy < INFINITY ? gy : 0.0f);
    const float phi = std::max(sz * std::max(grad, 1e-3f * zc), 1e-30f);
    const bool ok = vf[x] != 0.0f;
    ipz[x] = (ok && sz > 0.0f) ? std::min(1.0f / phi, 1e30f) : 0.0f;
    float sk = 0.0f;
    for (int dy = -1; dy <= 1; ++dy) {
      const float* vr = dy < 0 ? vu : (dy > 0 ? vd : vf);
      if (!vr) continue;
      for (int dx = -1; dx <= 1; ++dx) {
        const int xx = x + dx;
        if (xx < 0 || xx >= w) continue;
        sk += (dx == 0 ? 0.5f : 0.25f) * (dy == 0 ? 0.5f : 0.25f) * vr[xx];
      }
    }
    ivk[x] = ok ? 1.0f / sk : 0.0f;  // sk >= 0.25 when the centre is valid
  };
  if (w < kLanes + 2) {
    for (int x = 0; x < w; ++x) scalar(x);
    return;
  }
  scalar(0);
  const VecF inf = splat(INFINITY), zero{};
  auto ld = [](const float* p) {
    VecF v;
    std::memcpy(&v, p, sizeof v);
    return v;
  };
  int x = 1;
  for (; x + kLanes <= w - 1; x += kLanes) {
    const VecF zc = ld(z + x), vc = ld(vf + x);
    const VecF vl = ld(vf + x - 1), vr = ld(vf + x + 1);
    const VecF sl = vl != zero ? abs_f(ld(z + x - 1) - zc) : inf;
    const VecF sr = vr != zero ? abs_f(ld(z + x + 1) - zc) : inf;
    VecF su = inf, sd = inf;
    VecF sk_u = zero, sk_d = zero;
    if (zu) {
      const VecF v = ld(vu + x);
      su = v != zero ? abs_f(ld(zu + x) - zc) : inf;
      sk_u = (0.25f * 0.25f) * ld(vu + x - 1) + (0.5f * 0.25f) * v + (0.25f * 0.25f) * ld(vu + x + 1);
    }
    if (zd) {
      const VecF v = ld(vd + x);
      sd = v != zero ? abs_f(ld(zd + x) - zc) : inf;
      sk_d = (0.25f * 0.25f) * ld(vd + x - 1) + (0.5f * 0.25f) * v + (0.25f * 0.25f) * ld(vd + x + 1);
    }
    const VecF gx = min_lanes(sl, sr), gy = min_lanes(su, sd);
    const VecF grad = (gx < inf ? gx : zero) + (gy < inf ? gy : zero);
    const VecF t = splat(1e-3f) * zc;
    const VecF m = grad < t ? t : grad;
    VecF phi = sz * m;
    phi = phi < splat(1e-30f) ? splat(1e-30f) : phi;
    const VecF inv = splat(1.0f) / phi;
    const VecI ok = vc != zero;
    const VecI use = sz > 0.0f ? ok : VecI{};
    const VecF ipz_v = use ? (splat(1e30f) < inv ? splat(1e30f) : inv) : zero;
    const VecF sk = sk_u + ((0.25f * 0.5f) * vl + (0.5f * 0.5f) * vc + (0.25f * 0.5f) * vr) + sk_d;
    const VecF ivk_v = ok ? splat(1.0f) / sk : zero;
    std::memcpy(ipz + x, &ipz_v, sizeof ipz_v);
    std::memcpy(ivk + x, &ivk_v, sizeof ivk_v);
  }
  for (; x < w; ++x) scalar(x);
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
  // svgf_ao's lightweight path (DHR-S 3.3, last paragraph): pixels with at least this many
  // frames of history get one 3x3 a-trous iteration instead of `iterations`; 0 = off.
  int light_history = 0;
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

// One frame: guide -> temporal accumulation (or the rescaled input) -> variance -> a-trous
// iterations -> 8 bits. Passes are fused where that saves a trip through memory: the guide's
// second pass also makes the depth phi and the valid-mass planes of the spatial filter, the
// accumulation also rescales the input, writes the temporal variance (and the output of the
// temporal-only denoiser), the a-trous rows compute their own AO phi, and the last iteration
// writes the 8-bit output. The first iteration's output is written straight into the value
// history when it is fed back. None of this changes a bit of the result (the operations per
// pixel are those of the unfused passes, in the same order).
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
    if (out.width() != w || out.height() != h) out.resize(w, h);  // every pixel is written below
    if (w == 0 || h == 0) return;
    if (!in.history_valid || w != w_ || h != h_) history_ok_ = false;
    if (w != w_ || h != h_) allocate(w, h);
    const bool spatial = s_.iterations > 0;
    build_guide(in.gbuf, guide_[cur_]);
    if (spatial) {
      GuideSpatialArgs ga{&guide_[cur_], s_.sigma_z, inv_phi_z_.data(), inv_valid_k_.data()};
      parallel_rows(h, [&](int y) { guide_spatial_row(ga, y); });
    }
    if (s_.temporal)
      accumulate(in, spatial ? nullptr : out.data());
    else
      sanitize_input(in, spatial ? nullptr : out.data());
    if (spatial) {
      spatial_variance();
      atrous_iterations(out.data());
    }
    history_ok_ = s_.temporal;
    cur_ ^= 1;
  }

  const FilterSettings& settings() const { return s_; }

 private:
  void allocate(int w, int h) {
    w_ = w;
    h_ = h;
    const size_t n = size_t(w) * size_t(h);
    for (auto* v : {&input_, &value_, &var_, &inv_phi_z_, &inv_valid_k_, &work_v_[0], &work_v_[1], &work_var_[0],
                    &work_var_[1], &hv_[0], &hv_[1], &hm1_[0], &hm1_[1], &hm2_[0], &hm2_[1], &hist_[0], &hist_[1],
                    &hk_[0], &hk_[1]})
      v->assign(n, 0.0f);
    cls_.assign(n, 0);
    span_lo_.assign(size_t(h), 0);
    span_hi_.assign(size_t(h), -1);
    guide_[0].resize(w, h);
    guide_[1].resize(w, h);
    history_ok_ = false;
  }

  bool light() const { return s_.temporal && s_.light_history > 0 && s_.iterations > 0; }
  bool feedback() const { return s_.temporal && s_.feedback_filtered && s_.iterations > 0; }

  // Without temporal accumulation: input to [0, 1] (values above full_scale count as
  // full_scale); every valid pixel takes the spatial variance path (no history), its
  // "temporal" variance max(0, m1^2 - m1^2) being 0. out: the 8-bit output when nothing follows.
  void sanitize_input(const DenoiseInput& in, uint8_t* out) {
    const int fs = in.full_scale;
    const float inv = 1.0f / float(fs);
    const int w = w_;
    const Guide& g = guide_[cur_];
    parallel_rows(h_, [&](int y) {
      const size_t row = size_t(y) * w;
      const uint8_t* src = in.noisy.data() + row;
      float* dst = input_.data() + row;
      int xa = w, xb = -1;
      for (int x = 0; x < w; ++x) {
        const int v = src[x] > fs ? fs : src[x];
        dst[x] = float(v) * inv;
        var_[row + x] = 0.0f;
        if (g.valid[row + x]) {
          xa = std::min(xa, x);
          xb = x;
        }
        if (out) out[row + x] = to_u8(dst[x]);
      }
      span_lo_[size_t(y)] = xa;
      span_hi_[size_t(y)] = xb;
    });
  }

  // Temporal accumulation (SVGF section 4.1): reproject through the motion vector, bilinear
  // over the 2x2 previous taps that pass the depth, normal and object-id tests, renormalised;
  // EMA with weight max(alpha, 1/history) (a plain mean while the history is short). Also:
  // the input rescaled to [0, 1] on the way in; with a spatial filter, the temporal variance
  // (m2 - m1^2) k per pixel, the span of each row that needs the spatial estimate (history
  // shorter than min_history) and the light_history class; without one, the 8-bit output.
  void accumulate(const DenoiseInput& in, uint8_t* out) {
    const int w = w_, h = h_;
    const ImageVec2& motion = in.gbuf.motion;
    const int fs = in.full_scale;
    const float inv_fs = 1.0f / float(fs);
    const Guide& g = guide_[cur_];
    const Guide& gp = guide_[cur_ ^ 1];
    const float* pv = hv_[cur_ ^ 1].data();
    const float* pm1 = hm1_[cur_ ^ 1].data();
    const float* pm2 = hm2_[cur_ ^ 1].data();
    const float* ph = hist_[cur_ ^ 1].data();
    const float* pk = hk_[cur_ ^ 1].data();
    // With the first iteration fed back, the accumulated value goes to value_ and the first
    // a-trous iteration writes the history; otherwise straight into the history.
    float* nv = feedback() ? value_.data() : hv_[cur_].data();
    float* nm1 = hm1_[cur_].data();
    float* nm2 = hm2_[cur_].data();
    float* nh = hist_[cur_].data();
    float* nk = hk_[cur_].data();
    const bool have_history = history_ok_;
    const float cap = float(s_.history_cap);
    const bool spatial = s_.iterations > 0, lt = light();
    const float min_h = float(s_.min_history), light_h = float(s_.light_history);
    const float tol = s_.depth_tolerance, nthr = s_.normal_threshold, alpha = s_.alpha;
    const float wmax = float(w) + 1.0f, hmax = float(h) + 1.0f;
    // Plain pointers: the compiler cannot keep a vector's data pointer in a register across
    // the byte stores below (a uint8_t store may alias anything).
    const glm::vec2* const mo = motion.data();
    const uint8_t* const noisy = in.noisy.data();
    const uint8_t *const cvalid = g.valid.data(), *const pvalid = gp.valid.data();
    const uint32_t *const cid = g.id.data(), *const pid = gp.id.data();
    const float *const cz = g.depth.data(), *const pz = gp.depth.data();
    const float *const cnx = g.nx.data(), *const cny = g.ny.data(), *const cnz = g.nz.data();
    const float *const pnx = gp.nx.data(), *const pny = gp.ny.data(), *const pnz = gp.nz.data();
    float* const var = var_.data();
    uint8_t* const cls = cls_.data();
    int* const span_lo = span_lo_.data();
    int* const span_hi = span_hi_.data();
    parallel_rows(h, [=](int y) {
      // Locals, not the closure's members: those live in memory that the byte stores below
      // might alias, so the compiler would reload every pointer for every pixel.
      const glm::vec2* const mo_l = mo;
      const uint8_t *const cvalid_l = cvalid, *const pvalid_l = pvalid;
      const uint32_t *const cid_l = cid, *const pid_l = pid;
      const float *const cz_l = cz, *const pz_l = pz, *const cnx_l = cnx, *const cny_l = cny, *const cnz_l = cnz;
      const float *const pnx_l = pnx, *const pny_l = pny, *const pnz_l = pnz;
      const float *const pv_l = pv, *const pm1_l = pm1, *const pm2_l = pm2, *const ph_l = ph, *const pk_l = pk;
      float *const nv_l = nv, *const nm1_l = nm1, *const nm2_l = nm2, *const nh_l = nh, *const nk_l = nk;
      float* const var_l = var;
      uint8_t *const cls_l = cls, *const out_l = out;
      const int w_l = w, h_l = h, fs_l = fs;
      const float inv_fs_l = inv_fs, tol_l = tol, nthr_l = nthr, alpha_l = alpha, cap_l = cap, min_h_l = min_h,
                  light_h_l = light_h, wmax_l = wmax, hmax_l = hmax;
      const bool hist_l = have_history, spatial_l = spatial, lt_l = lt;
      const size_t row = size_t(y) * w_l;
      const uint8_t* src = noisy + row;
      int xa = w_l, xb = -1;
      // The blend and the EMA of one pixel, from the (renormalised) sums of its accepted taps.
      auto finish = [&](int x, float len, float pval, float p1, float p2, float pkk) {
        const size_t i = row + x;
        const int iv = src[x] > fs_l ? fs_l : src[x];
        const float c = float(iv) * inv_fs_l;
        const bool valid = cvalid_l[i] != 0;
        float v, m1, m2, kk;
        if (len > 0.0f) {
          len = std::min(len + 1.0f, cap_l);
          const float a = std::max(alpha_l, 1.0f / len);
          v = pval + a * (c - pval);
          m1 = p1 + a * (c - p1);
          m2 = p2 + a * (c * c - p2);
          kk = (1.0f - a) * (1.0f - a) * pkk + a * a;
        } else {
          len = valid ? 1.0f : 0.0f;
          v = c;
          m1 = c;
          m2 = c * c;
          kk = 1.0f;
        }
        nv_l[i] = v;
        nm1_l[i] = m1;
        nm2_l[i] = m2;
        nk_l[i] = kk;
        nh_l[i] = len;
        if (spatial_l) {
          var_l[i] = valid ? std::max(0.0f, m2 - m1 * m1) * kk : 0.0f;
          if (valid && len < min_h_l) {
            xa = std::min(xa, x);
            xb = x;
          }
          if (lt_l) cls_l[i] = valid && len < light_h_l ? 1 : 0;
        } else {
          out_l[i] = to_u8(v);
        }
      };
      // Reprojection of one pixel: the sums of its accepted taps, renormalised.
      auto reproject = [&](int x, float& len, float& pval, float& p1, float& p2, float& pkk) {
        const size_t i = row + x;
        const glm::vec2 m = mo_l[i];
        // Previous pixel centre of this surface point, in pixel-index coordinates. The range
        // tests also reject NaN and inf.
        const float px = float(x) + m.x, py = float(y) + m.y;
        if (!(px > -2.0f && py > -2.0f && px < wmax_l && py < hmax_l)) return;
        // floor by truncation: px, py > -2 here (std::floor is a libm call without SSE4.1)
        const int x0 = int(px + 2.0f) - 2, y0 = int(py + 2.0f) - 2;
        const float fx = px - float(x0), fy = py - float(y0);
        const float bw[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
        const uint32_t idc = cid_l[i];
        const float zc = cz_l[i], ztol = tol_l * zc;
        const float ncx = cnx_l[i], ncy = cny_l[i], ncz = cnz_l[i];
        float sw = 0.0f;
        for (int k = 0; k < 4; ++k) {
          const int xx = x0 + (k & 1), yy = y0 + (k >> 1);
          if (xx < 0 || yy < 0 || xx >= w_l || yy >= h_l || bw[k] <= 0.0f) continue;
          const size_t j = size_t(yy) * w_l + xx;
          if (!pvalid_l[j] || pid_l[j] != idc || ph_l[j] <= 0.0f) continue;
          if (std::fabs(pz_l[j] - zc) > ztol) continue;
          const float d = pnx_l[j] * ncx + pny_l[j] * ncy + pnz_l[j] * ncz;
          if (d < nthr_l) continue;
          sw += bw[k];
          pval += bw[k] * pv_l[j];
          p1 += bw[k] * pm1_l[j];
          p2 += bw[k] * pm2_l[j];
          len += bw[k] * ph_l[j];
          pkk += bw[k] * pk_l[j];
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
      };
      for (int x = 0; x < w_l; ++x) {
        float len = 0.0f, pval = 0.0f, p1 = 0.0f, p2 = 0.0f, pkk = 0.0f;
        if (hist_l && cvalid_l[row + x]) reproject(x, len, pval, p1, p2, pkk);
        finish(x, len, pval, p1, p2, pkk);
      }
      span_lo[y] = xa;
      span_hi[y] = xb;
    });
  }

  // Per-pixel variance of the AO signal: from the temporal moments (written by accumulate)
  // where the history has at least min_history frames, else spatially from the moments in a
  // (2r+1)^2 window weighted by depth and normal only (DHR-S section 3.3: no luminance term),
  // boosted by 4/h as SVGF does for young pixels. Without temporal accumulation (atrous) every
  // pixel takes the spatial path with h = 1 and the moments of the current frame.
  void spatial_variance() {
    const int w = w_, h = h_;
    const Guide& g = guide_[cur_];
    const float* hl = s_.temporal ? hist_[cur_].data() : nullptr;  // null: no history (h = 0)
    const float* kf = s_.temporal ? hk_[cur_].data() : nullptr;     // null: k = 1 (one frame)
    const float* m1 = s_.temporal ? hm1_[cur_].data() : input_.data();
    const float* m2 = s_.temporal ? hm2_[cur_].data() : nullptr;  // null: m2 = input^2
    const float min_h = float(s_.min_history);
    MomentArgs margs;
    margs.width = w;
    margs.height = h;
    margs.radius = s_.variance_radius;
    margs.normal_squarings = normal_squarings();
    margs.depth = g.depth.data();
    margs.nx = g.nx.data();
    margs.ny = g.ny.data();
    margs.nz = g.nz.data();
    margs.inv_phi_z = inv_phi_z_.data();
    margs.m1 = m1;
    margs.m2 = m2;
    tbb::parallel_for(
        tbb::blocked_range<int>(0, h, 4),
        [&](const tbb::blocked_range<int>& range) {
          std::vector<float> acc;
          for (int y = range.begin(); y < range.end(); ++y) {
            const int xa = span_lo_[size_t(y)], xb = span_hi_[size_t(y)];
            if (xb < xa) continue;
            const int n = xb - xa + 1;
            acc.assign(size_t(n) * 3, 0.0f);
            moment_span(margs, y, xa, xb, acc.data());
            const float* a0 = acc.data();
            const float* a1 = a0 + n;
            const float* a2 = a1 + n;
            const size_t row = size_t(y) * w;
            for (int x = xa; x <= xb; ++x) {
              const size_t i = row + x;
              const float hh0 = hl ? hl[i] : 0.0f;
              if (!g.valid[i] || hh0 >= min_h) continue;
              const float sw_ = a0[x - xa];
              if (!(sw_ > 0.0f)) continue;  // keeps the temporal estimate
              const float mean = a1[x - xa] / sw_;
              const float mean2 = a2[x - xa] / sw_;
              const float hh = std::max(hh0, 1.0f);
              var_[i] = std::max(0.0f, mean2 - mean * mean) * (4.0f / hh) * (kf ? kf[i] : 1.0f);
            }
          }
        },
        tbb::simple_partitioner());  // blocks independent of threads and timing (see parallel_rows)
  }

  // The a-trous iterations (SVGF section 4.3, Dammertz et al. 2010): iteration i has step 2^i.
  // The values ping-pong between the work planes; the first iteration writes the value history
  // when it is fed back (feedback "first_iteration"), the last one the 8-bit output.
  //
  // light_history (svgf_ao, DHR-S 3.3 last paragraph): pixels whose history is at least
  // light_history frames long (cls_ 0, with the invalid ones) get the first iteration with the
  // 3x3 kernel and keep its result; the others (cls_ 1) get every iteration with the configured
  // kernel. The first iteration runs twice over the image, each run filtering only its own
  // pixels (and skipping blocks without one); it writes its result into every plane a later
  // iteration may write, so a later iteration need only write the pixels it filters.
  void atrous_iterations(uint8_t* out) {
    const int n_it = s_.iterations;
    const bool lt = light();
    float* hv = hv_[cur_].data();
    float* w0 = work_v_[0].data();
    float* w1 = work_v_[1].data();
    float* wv0 = work_var_[0].data();
    float* wv1 = work_var_[1].data();
    const float* v_in = !s_.temporal ? input_.data() : (feedback() ? value_.data() : hv);
    float* v0 = feedback() ? hv : w0;  // the first iteration's output
    AtrousArgs a = atrous_args(1, s_.kernel_radius);
    a.v_in = v_in;
    a.var_in = var_.data();
    a.v_out = v0;
    a.var_out = wv0;
    if (lt && n_it > 1) {  // later iterations write only their own pixels
      a.v_out2 = v0 == hv ? w0 : w1;
      a.v_out3 = v0 == hv ? w1 : nullptr;
      a.var_out2 = wv1;
    }
    if (lt && s_.kernel_radius != 1) {
      AtrousArgs a3 = a;  // the long-history pixels: 3x3
      a3.radius = 1;
      a3.k1d = kK3 + 1;
      a3.cls = cls_.data();
      a3.active_cls = 0;
      atrous_pass(a3);
      a.cls = cls_.data();
      a.active_cls = 1;
    }
    a.u8_out = n_it == 1 ? out : nullptr;
    atrous_pass(a);
    const float* v = v0;
    const float* var = wv0;
    for (int it = 1; it < n_it; ++it) {
      AtrousArgs b = atrous_args(1 << it, s_.kernel_radius);
      float* v_out = v == w0 ? w1 : w0;
      float* var_out = var == wv0 ? wv1 : wv0;
      b.v_in = v;
      b.var_in = var;
      b.v_out = v_out;
      b.var_out = var_out;
      if (lt) {
        b.cls = cls_.data();
        b.active_cls = 1;
      }
      b.u8_out = it + 1 == n_it ? out : nullptr;
      atrous_pass(b);
      v = v_out;
      var = var_out;
    }
  }

  static constexpr float kB3[5] = {1.0f / 16, 1.0f / 4, 3.0f / 8, 1.0f / 4, 1.0f / 16};
  static constexpr float kK3[3] = {0.25f, 0.5f, 0.25f};

  // One edge-aware a-trous iteration: kernel h (B3-spline 5x5 or 3x3) at step `step`, weight
  //   w = h * exp(-|z_p - z_q| / (sigma_z |grad z_p| step |offset|) - |l_p - l_q| / (sigma_l sqrt(g3x3(var_p)) + eps))
  //         * max(0, n_p . n_q)^sigma_n,
  // value = sum w l_q / sum w, variance = sum w^2 var_q / (sum w)^2. The variance is
  // prefiltered with a 3x3 Gaussian over valid pixels (SVGF) inside the rows (AtrousArgs).
  AtrousArgs atrous_args(int step, int radius) const {
    const Guide& g = guide_[cur_];
    AtrousArgs a;
    a.width = w_;
    a.height = h_;
    a.step = step;
    a.radius = radius;
    a.normal_squarings = normal_squarings();
    a.k1d = radius == 2 ? kB3 + 2 : kK3 + 1;
    a.depth = g.depth.data();
    a.nx = g.nx.data();
    a.ny = g.ny.data();
    a.nz = g.nz.data();
    a.valid = g.valid.data();
    a.inv_phi_z = inv_phi_z_.data();
    a.inv_valid_k = inv_valid_k_.data();
    a.valid_f = g.valid_f.data();
    a.sigma_l = s_.sigma_l;
    a.eps_l = kEpsL;
    return a;
  }

  void atrous_pass(const AtrousArgs& a) const {
    const int w = w_;
    tbb::parallel_for(
        tbb::blocked_range<int>(0, h_, 4),
        [&](const tbb::blocked_range<int>& range) {
          // Scratch, fully written before it is read: no need to clear it.
          const auto acc = std::make_unique_for_overwrite<float[]>(size_t(w) * 4);
          atrous_rows(a, range.begin(), range.end(), acc.get());
        },
        tbb::simple_partitioner());  // blocks independent of threads and timing (see parallel_rows)
  }

  int normal_squarings() const { return std::countr_zero(unsigned(s_.sigma_n)); }

  FilterSettings s_;
  int w_ = -1, h_ = -1;
  int cur_ = 0;               // index of this frame's history/guide planes; cur_ ^ 1 = previous
  bool history_ok_ = false;   // the previous planes hold a usable frame
  Guide guide_[2];
  // input_: the rescaled input (spatial-only denoiser); value_: the accumulated value when the
  // first a-trous iteration is fed back into hv_.
  std::vector<float> input_, value_, var_, inv_phi_z_, inv_valid_k_;
  std::vector<float> work_v_[2], work_var_[2];
  // History: value, moments, length, and the variance factor k of the accumulated value (the
  // variance of the EMA of independent samples is k times that of one sample).
  std::vector<float> hv_[2], hm1_[2], hm2_[2], hist_[2], hk_[2];
  std::vector<uint8_t> cls_;            // light_history: 1 = filtered by every iteration
  std::vector<int> span_lo_, span_hi_;  // per row: the pixels that need the spatial variance
};

}  // namespace dhr::denoise
